// Stanford PLY meshes (Turk 1994; ASCII, binary little- and big-endian)
// through the Open Asset Import Library. Assimp does the parse because it
// reads every property layout and list encoding; but it trusts the header: a
// header without end_header makes its parser loop forever (or, in a binary
// file, read out of bounds), and a huge element count makes it allocate for
// that count before it notices the file is short. So the header is checked
// here first: magic, end_header within a bound, known format and property
// types, and element counts that the file's size can hold. Only a file that
// passes is given to Assimp.
// Assimp only parses and validates (indices in range): its other
// post-processing steps assert, and abort the program, on legal but
// degenerate input such as an empty face. Polygons are therefore
// fan-triangulated here (as convex, like Mitsuba's loader does with quads)
// and faces with fewer than three corners are errors. Normals and texture
// coordinates are kept only when every vertex has them.
#include "engine/core/error.h"
#include "engine/scene/shape.h"

#include <assimp/Importer.hpp>
#include <assimp/postprocess.h>
#include <assimp/scene.h>

#include <algorithm>
#include <charconv>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <optional>
#include <sstream>
#include <string_view>
#include <vector>

namespace fg {

namespace {

// Longer headers are not written by any exporter; the bound keeps a file
// without end_header from being scanned to its end as header text.
constexpr std::size_t kMaxHeaderBytes = 64 * 1024;

// Size in bytes of a PLY scalar type (both the 1994 names and the sized aliases).
std::optional<std::uint64_t> scalarSize(std::string_view type) {
    if (type == "char" || type == "uchar" || type == "int8" || type == "uint8") return 1;
    if (type == "short" || type == "ushort" || type == "int16" || type == "uint16") return 2;
    if (type == "int" || type == "uint" || type == "int32" || type == "uint32" || type == "float" || type == "float32")
        return 4;
    if (type == "double" || type == "float64") return 8;
    return std::nullopt;
}

bool isIntegerType(std::string_view type) {
    return type != "float" && type != "float32" && type != "double" && type != "float64";
}

struct PlyElement {
    std::string name;
    std::uint64_t count = 0;
    int line = 0;
    std::uint64_t fixedBytes = 0;  // scalars, plus the count field of each list (its items vary)
    std::uint64_t valueCount = 0;  // scalars and lists (at least their count) per record
    std::vector<bool> propertyIsList;  // per property, in the order of the header
};

// Walks an ASCII body value by value along the header's elements and
// properties. Assimp reserves a list's items by the count it reads, so a
// count of 40 digits would be a 19 GB allocation before the data is found
// missing; here every list count must be an integer no larger than the
// number of values the rest of the file could still hold.
void checkPlyAsciiBody(std::string_view body, const std::vector<PlyElement>& elements, const std::string& path) {
    std::size_t position = 0;
    const auto isSpace = [](char c) { return c == ' ' || c == '\t' || c == '\n' || c == '\r' || c == '\v' || c == '\f'; };
    const auto nextValue = [&]() -> std::optional<std::string_view> {
        while (position < body.size() && isSpace(body[position])) ++position;
        if (position == body.size()) return std::nullopt;
        const std::size_t start = position;
        while (position < body.size() && !isSpace(body[position])) ++position;
        return body.substr(start, position - start);
    };
    // Assimp reads an ASCII body as C text: a NUL ends its values where this
    // walk would not, so the two would disagree on which value is a count.
    for (std::size_t offset = 0; offset < body.size(); ++offset) {
        const auto byte = static_cast<unsigned char>(body[offset]);
        if ((byte < 0x20 && !isSpace(body[offset])) || byte >= 0x7f) {
            throw InputError(path, 0, "PLY ascii data holds the byte 0x" + std::string(1, "0123456789abcdef"[byte >> 4]) +
                                          std::string(1, "0123456789abcdef"[byte & 15]) + " at data offset " +
                                          std::to_string(offset) + ", which is not text");
        }
    }
    for (const PlyElement& element : elements) {
        for (std::uint64_t record = 0; record < element.count; ++record) {
            for (const bool isList : element.propertyIsList) {
                const std::optional<std::string_view> value = nextValue();
                const auto where = [&] { return "PLY element '" + element.name + "' record " + std::to_string(record); };
                if (!value) throw InputError(path, element.line, where() + ": the file ends before its values do");
                if (!isList) continue;
                std::uint64_t items = 0;
                const auto [end, error] = std::from_chars(value->data(), value->data() + value->size(), items);
                // Every further value takes at least one character and a separator.
                const std::uint64_t room = (body.size() - position) / 2 + 1;
                if (error != std::errc() || end != value->data() + value->size() || items > room) {
                    throw InputError(path, element.line,
                                     where() + ": list count '" + std::string(value->substr(0, 24)) +
                                         (value->size() > 24 ? "..." : "") + "' is not a count the file can hold");
                }
                for (std::uint64_t item = 0; item < items; ++item) {
                    if (!nextValue()) throw InputError(path, element.line, where() + ": the file ends inside a list");
                }
            }
        }
    }
}

// Checks the header of `data` (which starts with "ply") and that the element
// counts fit the file's size; throws an InputError naming path:line otherwise.
void checkPlyHeader(const std::string& data, const std::string& path) {
    std::size_t position = 0;
    int line = 0;
    std::string format;
    std::vector<PlyElement> elements;
    bool ended = false;
    while (!ended) {
        const std::size_t newline = std::string_view(data).substr(0, kMaxHeaderBytes).find('\n', position);
        if (newline == std::string::npos) {
            throw InputError(path, 0, "PLY header has no end_header line" +
                                          std::string(data.size() > kMaxHeaderBytes ? " within its first 64 KiB" : ""));
        }
        ++line;
        std::string text = data.substr(position, newline - position);
        position = newline + 1;
        if (!text.empty() && text.back() == '\r') text.pop_back();
        std::istringstream words(text);
        std::string keyword;
        words >> keyword;
        const auto fail = [&](const std::string& message) { throw InputError(path, line, message); };
        if (line == 1) continue;  // "ply", checked by the caller
        if (keyword.empty() || keyword == "comment" || keyword == "obj_info") continue;
        std::vector<std::string> rest;
        for (std::string word; words >> word;) rest.push_back(word);
        if (keyword == "format") {
            if (!format.empty()) fail("PLY header has a second format line");
            if (rest.size() != 2) fail("PLY format line must be 'format <ascii|binary_little_endian|binary_big_endian> 1.0'");
            if (rest[0] != "ascii" && rest[0] != "binary_little_endian" && rest[0] != "binary_big_endian")
                fail("unknown PLY format '" + rest[0] + "' (expected ascii, binary_little_endian or binary_big_endian)");
            format = rest[0];
        } else if (keyword == "element") {
            if (rest.size() != 2) fail("PLY element line must be 'element <name> <count>'");
            PlyElement element;
            element.name = rest[0];
            element.line = line;
            const std::string& count = rest[1];
            const auto [end, error] = std::from_chars(count.data(), count.data() + count.size(), element.count);
            if (error == std::errc::result_out_of_range)
                fail("PLY element '" + element.name + "' has an impossibly large count " + count);
            if (error != std::errc() || end != count.data() + count.size())
                fail("PLY element '" + element.name + "' has a count that is not a non-negative integer: '" + count + "'");
            elements.push_back(element);
        } else if (keyword == "property") {
            if (elements.empty()) fail("PLY property before any element");
            PlyElement& element = elements.back();
            if (!rest.empty() && rest[0] == "list") {
                if (rest.size() != 4) fail("PLY list property must be 'property list <count type> <item type> <name>'");
                const std::optional<std::uint64_t> countSize = scalarSize(rest[1]);
                if (!countSize || !isIntegerType(rest[1])) fail("PLY list count type must be an integer type, not '" + rest[1] + "'");
                if (!scalarSize(rest[2])) fail("unknown PLY property type '" + rest[2] + "'");
                element.fixedBytes += *countSize;
                element.propertyIsList.push_back(true);
            } else {
                if (rest.size() != 2) fail("PLY property line must be 'property <type> <name>'");
                const std::optional<std::uint64_t> size = scalarSize(rest[0]);
                if (!size) fail("unknown PLY property type '" + rest[0] + "'");
                element.fixedBytes += *size;
                element.propertyIsList.push_back(false);
            }
            ++element.valueCount;
        } else if (keyword == "end_header") {
            // Only a bare end_header: with other bytes after it on the line
            // (end_header\v...), Assimp's parser does not stop.
            if (text.find_last_not_of(' ') + 1 != std::string_view("end_header").size() || text.find("end_header") != 0)
                fail("PLY end_header line must hold nothing else");
            ended = true;
        } else {
            fail("unexpected line in PLY header: '" + text + "'");
        }
    }
    if (format.empty()) throw InputError(path, 0, "PLY header has no format line");

    // The smallest body the header allows: in binary the fixed part of every
    // record; in ASCII every value takes at least one character and a separator
    // (the last one may end the file without its separator).
    const std::uint64_t bodyBytes = data.size() - position;
    const bool ascii = format == "ascii";
    const std::uint64_t available = bodyBytes + (ascii ? 1 : 0);
    std::uint64_t needed = 0;
    for (const PlyElement& element : elements) {
        // An element without properties still counts a byte per record, so that
        // its count is bounded too.
        const std::uint64_t recordBytes = std::max<std::uint64_t>(1, ascii ? 2 * element.valueCount : element.fixedBytes);
        if (element.count > available / recordBytes || needed + element.count * recordBytes > available) {
            throw InputError(path, element.line,
                             "PLY element '" + element.name + "' has " + std::to_string(element.count) +
                                 " records, more than the file's " + std::to_string(bodyBytes) + " bytes of data can hold");
        }
        needed += element.count * recordBytes;
    }
    if (ascii) checkPlyAsciiBody(std::string_view(data).substr(position), elements, path);
}

}  // namespace

TriangleMesh loadPlyMesh(const std::string& path) {
    std::error_code ec;
    if (!std::filesystem::is_regular_file(path, ec)) throw InputError(path, 0, "PLY file not found");
    std::ifstream in(path, std::ios::binary);
    if (!in) throw InputError(path, 0, "cannot open PLY file");
    const std::string data((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    if (in.bad()) throw InputError(path, 0, "cannot read PLY file");
    if (data.size() < 4 || data.compare(0, 3, "ply") != 0 || (data[3] != '\n' && data[3] != '\r')) {
        throw InputError(path, 0, "not a PLY file (it must start with the line 'ply')");
    }
    checkPlyHeader(data, path);

    Assimp::Importer importer;
    const unsigned flags = aiProcess_ValidateDataStructure;
    const aiScene* scene = importer.ReadFileFromMemory(data.data(), data.size(), flags, "ply");
    if (!scene) throw InputError(path, 0, std::string("cannot parse PLY file: ") + importer.GetErrorString());
    if (scene->mNumMeshes == 0) throw InputError(path, 0, "PLY file contains no faces");

    bool allNormals = true, allUvs = true;
    for (unsigned m = 0; m < scene->mNumMeshes; ++m) {
        const aiMesh* mesh = scene->mMeshes[m];
        allNormals = allNormals && mesh->HasNormals();
        allUvs = allUvs && mesh->HasTextureCoords(0);
    }

    TriangleMesh result;
    for (unsigned m = 0; m < scene->mNumMeshes; ++m) {
        const aiMesh* mesh = scene->mMeshes[m];
        const auto base = static_cast<std::uint32_t>(result.positions.size());
        for (unsigned v = 0; v < mesh->mNumVertices; ++v) {
            const aiVector3D& p = mesh->mVertices[v];
            result.positions.emplace_back(p.x, p.y, p.z);
            if (allNormals) {
                const aiVector3D& n = mesh->mNormals[v];
                const Vec3 normal(n.x, n.y, n.z);
                const float length = glm::length(normal);
                result.normals.push_back(length > 0.0f ? normal / length : normal);
            }
            if (allUvs) result.uvs.emplace_back(mesh->mTextureCoords[0][v].x, mesh->mTextureCoords[0][v].y);
        }
        for (unsigned f = 0; f < mesh->mNumFaces; ++f) {
            const aiFace& face = mesh->mFaces[f];
            if (face.mNumIndices < 3) {
                throw InputError(path, 0, "face " + std::to_string(f) + " has " + std::to_string(face.mNumIndices) +
                                              " corners; only polygon meshes are supported");
            }
            for (unsigned c = 0; c < face.mNumIndices; ++c) {
                if (face.mIndices[c] >= mesh->mNumVertices) throw InputError(path, 0, "face refers to a vertex that does not exist");
            }
            for (unsigned c = 1; c + 1 < face.mNumIndices; ++c) {
                result.indices.push_back(base + face.mIndices[0]);
                result.indices.push_back(base + face.mIndices[c]);
                result.indices.push_back(base + face.mIndices[c + 1]);
            }
        }
    }
    if (result.indices.empty()) throw InputError(path, 0, "PLY file contains no faces");
    for (const Vec3& p : result.positions) {
        if (!isFinite(p)) throw InputError(path, 0, "PLY file contains a vertex position that is not a finite number");
    }
    return result;
}

}  // namespace fg
