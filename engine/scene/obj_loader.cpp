// Wavefront OBJ meshes through tinyobjloader. OBJ indexes positions, normals
// and texture coordinates separately; a renderer wants one index per vertex,
// so every distinct (position, normal, uv) triple becomes one output vertex.
// All groups and objects are merged into a single mesh; materials (.mtl) are
// ignored because the scene file assigns materials per shape.
#include "engine/core/error.h"
#include "engine/scene/shape.h"

#include <tiny_obj_loader.h>

#include <charconv>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <sstream>
#include <unordered_map>

namespace fg {

namespace {

struct CornerKey {
    int position, normal, uv;
    bool operator==(const CornerKey&) const = default;
};

struct CornerKeyHash {
    std::size_t operator()(const CornerKey& k) const {
        std::size_t h = static_cast<std::size_t>(static_cast<std::uint32_t>(k.position));
        h = h * 0x9E3779B97F4A7C15ull ^ static_cast<std::uint32_t>(k.normal);
        h = h * 0x9E3779B97F4A7C15ull ^ static_cast<std::uint32_t>(k.uv);
        return h ^ (h >> 29);
    }
};

// tinyobjloader reads a coordinate it cannot parse ("nan", "inf", "x") as 0, so
// vertex positions are checked on the text: each must be a finite number, and
// finite as a float too (it stores them as float: 1e39 would become inf).
void checkVertexPositions(const std::string& text, const std::string& path) {
    std::size_t start = 0;
    int line = 0;
    int vertex = 0;
    while (start < text.size()) {
        std::size_t end = text.find('\n', start);
        if (end == std::string::npos) end = text.size();
        ++line;
        std::istringstream words(text.substr(start, end - start));
        start = end + 1;
        std::string keyword;
        if (!(words >> keyword) || keyword != "v") continue;
        ++vertex;
        std::string word;
        for (int axis = 0; axis < 3 && words >> word; ++axis) {
            const char* first = word.data() + (word.front() == '+' ? 1 : 0);
            const char* last = word.data() + word.size();
            double value = 0.0;
            const auto [stop, error] = std::from_chars(first, last, value);
            if (error != std::errc() || stop != last || !std::isfinite(value) ||
                std::abs(value) > std::numeric_limits<float>::max()) {
                throw InputError(path, line, "vertex " + std::to_string(vertex) + " has a coordinate '" + word +
                                                 "' that is not a finite number");
            }
        }
    }
}

std::string firstLine(const std::string& text) {
    std::string line = text.substr(0, text.find('\n'));
    while (!line.empty() && (line.back() == '\r' || line.back() == ' ')) line.pop_back();
    return line;
}

}  // namespace

TriangleMesh loadObjMesh(const std::string& path) {
    std::error_code ec;
    if (!std::filesystem::is_regular_file(path, ec)) throw InputError(path, 0, "OBJ file not found");

    std::ifstream in(path, std::ios::binary);
    if (!in) throw InputError(path, 0, "cannot open OBJ file");
    std::ostringstream buffer;
    buffer << in.rdbuf();
    if (in.bad()) throw InputError(path, 0, "cannot read OBJ file");
    const std::string text = buffer.str();
    checkVertexPositions(text, path);

    tinyobj::ObjReaderConfig config;
    config.triangulate = true;
    config.vertex_color = false;
    tinyobj::ObjReader reader;
    // Materials (.mtl) are not read: the scene file assigns them.
    if (!reader.ParseFromString(text, "", config)) {
        const std::string why = firstLine(reader.Error());
        throw InputError(path, 0, "cannot parse OBJ file" + (why.empty() ? std::string() : ": " + why));
    }
    const tinyobj::attrib_t& attrib = reader.GetAttrib();
    const std::size_t positionCount = attrib.vertices.size() / 3;
    const std::size_t normalCount = attrib.normals.size() / 3;
    const std::size_t uvCount = attrib.texcoords.size() / 2;

    // Normals (uvs) are kept only if every face corner has one; a half-specified
    // attribute cannot be interpolated meaningfully.
    bool allNormals = true, allUvs = true;
    std::size_t cornerCount = 0;
    for (const tinyobj::shape_t& shape : reader.GetShapes()) {
        for (const tinyobj::index_t& idx : shape.mesh.indices) {
            if (idx.vertex_index < 0 || static_cast<std::size_t>(idx.vertex_index) >= positionCount) {
                throw InputError(path, 0, "face refers to a vertex that does not exist");
            }
            allNormals = allNormals && idx.normal_index >= 0 && static_cast<std::size_t>(idx.normal_index) < normalCount;
            allUvs = allUvs && idx.texcoord_index >= 0 && static_cast<std::size_t>(idx.texcoord_index) < uvCount;
            ++cornerCount;
        }
    }
    if (cornerCount == 0) throw InputError(path, 0, "OBJ file contains no faces");

    TriangleMesh mesh;
    mesh.indices.reserve(cornerCount);
    std::unordered_map<CornerKey, std::uint32_t, CornerKeyHash> vertexOf;
    for (const tinyobj::shape_t& shape : reader.GetShapes()) {
        std::size_t offset = 0;
        for (const unsigned char faceSize : shape.mesh.num_face_vertices) {
            if (faceSize != 3) throw InputError(path, 0, "face with " + std::to_string(faceSize) + " vertices after triangulation");
            for (std::size_t c = 0; c < 3; ++c) {
                const tinyobj::index_t& idx = shape.mesh.indices[offset + c];
                const CornerKey key{idx.vertex_index, allNormals ? idx.normal_index : -1, allUvs ? idx.texcoord_index : -1};
                auto [it, inserted] = vertexOf.try_emplace(key, static_cast<std::uint32_t>(mesh.positions.size()));
                if (inserted) {
                    const auto v = static_cast<std::size_t>(key.position);
                    mesh.positions.emplace_back(attrib.vertices[3 * v], attrib.vertices[3 * v + 1], attrib.vertices[3 * v + 2]);
                    if (allNormals) {
                        const auto n = static_cast<std::size_t>(key.normal);
                        const Vec3 normal(attrib.normals[3 * n], attrib.normals[3 * n + 1], attrib.normals[3 * n + 2]);
                        const float length = glm::length(normal);
                        mesh.normals.push_back(length > 0.0f ? normal / length : normal);
                    }
                    if (allUvs) {
                        const auto t = static_cast<std::size_t>(key.uv);
                        mesh.uvs.emplace_back(attrib.texcoords[2 * t], attrib.texcoords[2 * t + 1]);
                    }
                }
                mesh.indices.push_back(it->second);
            }
            offset += 3;
        }
    }
    return mesh;
}

}  // namespace fg
