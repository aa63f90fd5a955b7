// Mitsuba's .serialized meshes. A file holds one or more shapes, each a
// 16-bit format tag 0x041C and a 16-bit version (3 or 4) followed by a zlib
// stream; the stream holds 32-bit flags (vertex normals, texture coordinates,
// vertex colours, face normals, single or double precision), in version 4 the
// shape's name (NUL-terminated), the 64-bit vertex and triangle counts, then
// positions, normals, uvs and colours, then the indices (32-bit, or 64-bit
// when there are more than 2^32 vertices). A file with several shapes ends
// with a table of shape offsets (64-bit in version 4, 32-bit in version 3)
// and a 32-bit shape count. Everything is little-endian.
//
// Inflation is zlib's. Every count is checked against what the file can
// hold before anything is allocated: the compressed stream is at most the
// file, and zlib's ratio is at most 1032:1, so a header claiming more is
// rejected instead of allocated.
#include "engine/core/error.h"
#include "engine/scene/shape.h"

#include <zlib.h>

#include <cmath>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <iterator>
#include <limits>
#include <string>
#include <vector>

namespace fg {

namespace {

constexpr std::uint16_t kFormatTag = 0x041C;
constexpr std::uint32_t kHasNormals = 0x0001;
constexpr std::uint32_t kHasUvs = 0x0002;
constexpr std::uint32_t kHasColors = 0x0008;
constexpr std::uint32_t kFaceNormals = 0x0010;
constexpr std::uint32_t kSinglePrecision = 0x1000;
constexpr std::uint32_t kDoublePrecision = 0x2000;
constexpr std::uint32_t kKnownFlags = kHasNormals | kHasUvs | kHasColors | kFaceNormals | kSinglePrecision | kDoublePrecision;
// zlib's deflate never compresses better than about 1032:1.
constexpr std::uint64_t kMaxInflationRatio = 1032;

template <typename T>
T readLittle(const unsigned char* bytes) {
    T value{};
    std::memcpy(&value, bytes, sizeof(T));  // the machines fluxgraph runs on are little-endian
    return value;
}

// Reads from the inflated stream, failing with the file's name when it runs out.
class Inflater {
public:
    Inflater(const std::string& path, const unsigned char* data, std::size_t size) : path_(path) {
        stream_.next_in = const_cast<unsigned char*>(data);
        stream_.avail_in = static_cast<uInt>(std::min<std::size_t>(size, std::numeric_limits<uInt>::max()));
        if (inflateInit(&stream_) != Z_OK) throw InputError(path_, 0, "cannot start zlib");
        compressedSize_ = size;
    }
    ~Inflater() { inflateEnd(&stream_); }
    Inflater(const Inflater&) = delete;
    Inflater& operator=(const Inflater&) = delete;

    // Upper bound of what the stream can still produce.
    std::uint64_t maxRemaining() const { return compressedSize_ * kMaxInflationRatio + 64; }

    void read(void* out, std::size_t bytes, const char* what) {
        stream_.next_out = static_cast<unsigned char*>(out);
        while (bytes > 0) {
            const auto chunk = static_cast<uInt>(std::min<std::size_t>(bytes, std::numeric_limits<uInt>::max()));
            stream_.avail_out = chunk;
            const int status = inflate(&stream_, Z_NO_FLUSH);
            const std::size_t produced = chunk - stream_.avail_out;
            bytes -= produced;
            if (bytes == 0) break;
            if (status == Z_STREAM_END || (status == Z_BUF_ERROR && produced == 0)) {
                throw InputError(path_, 0, std::string("serialized mesh: the compressed data ends inside the ") + what);
            }
            if (status != Z_OK && status != Z_BUF_ERROR) {
                throw InputError(path_, 0, std::string("serialized mesh: corrupt compressed data in the ") + what +
                                               (stream_.msg ? std::string(" (") + stream_.msg + ")" : std::string()));
            }
        }
    }
    template <typename T>
    T value(const char* what) {
        T v{};
        read(&v, sizeof(T), what);
        return v;
    }

private:
    std::string path_;
    z_stream stream_{};
    std::uint64_t compressedSize_ = 0;
};

std::vector<unsigned char> readWholeFile(const std::string& path) {
    std::ifstream in(path, std::ios::binary);
    if (!in) throw InputError(path, 0, "cannot open the serialized mesh");
    std::vector<unsigned char> bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    if (in.bad()) throw InputError(path, 0, "cannot read the serialized mesh");
    return bytes;
}

// Byte offset of shape `index`: 0 for the first, else from the table at the end of the file.
std::size_t shapeOffset(const std::string& path, const std::vector<unsigned char>& file, std::uint16_t version, int index) {
    if (index == 0) return 0;
    if (file.size() < 4) throw InputError(path, 0, "serialized mesh: file too short");
    const auto count = readLittle<std::uint32_t>(file.data() + file.size() - 4);
    const std::size_t entry = version >= 4 ? 8 : 4;
    if (count == 0 || static_cast<std::uint64_t>(count) * entry + 4 > file.size()) {
        throw InputError(path, 0, "serialized mesh: shape_index " + std::to_string(index) +
                                      " given, but the file has no valid table of shapes");
    }
    if (static_cast<std::uint32_t>(index) >= count) {
        throw InputError(path, 0, "serialized mesh: shape_index " + std::to_string(index) + " out of range (the file holds " +
                                      std::to_string(count) + " shapes)");
    }
    const unsigned char* table = file.data() + file.size() - 4 - static_cast<std::size_t>(count) * entry;
    const std::uint64_t offset = version >= 4 ? readLittle<std::uint64_t>(table + index * entry)
                                              : readLittle<std::uint32_t>(table + index * entry);
    if (offset + 4 > file.size()) throw InputError(path, 0, "serialized mesh: shape offset beyond the end of the file");
    return static_cast<std::size_t>(offset);
}

}  // namespace

TriangleMesh loadSerializedMesh(const std::string& path, int shapeIndex) {
    if (shapeIndex < 0) throw InputError(path, 0, "serialized mesh: shape_index must not be negative");
    const std::vector<unsigned char> file = readWholeFile(path);
    if (file.size() < 4) throw InputError(path, 0, "serialized mesh: file too short for a header");
    const std::uint16_t firstVersion = readLittle<std::uint16_t>(file.data() + 2);
    const std::size_t offset = shapeOffset(path, file, firstVersion, shapeIndex);
    const auto tag = readLittle<std::uint16_t>(file.data() + offset);
    const auto version = readLittle<std::uint16_t>(file.data() + offset + 2);
    if (tag != kFormatTag) throw InputError(path, 0, "serialized mesh: not a Mitsuba serialized file (bad format tag)");
    if (version != 3 && version != 4) {
        throw InputError(path, 0, "serialized mesh: unsupported version " + std::to_string(version) + " (supported: 3, 4)");
    }

    Inflater in(path, file.data() + offset + 4, file.size() - offset - 4);
    const auto flags = in.value<std::uint32_t>("header");
    if ((flags & ~kKnownFlags) != 0) throw InputError(path, 0, "serialized mesh: unknown flags in the header");
    const bool single = (flags & kSinglePrecision) != 0, dbl = (flags & kDoublePrecision) != 0;
    if (single == dbl) throw InputError(path, 0, "serialized mesh: the header must name exactly one precision");
    if (version >= 4) {
        // The shape's name: skipped, but bounded.
        for (int i = 0;; ++i) {
            if (in.value<char>("shape name") == '\0') break;
            if (i > 4096) throw InputError(path, 0, "serialized mesh: unterminated shape name");
        }
    }
    const auto vertexCount = in.value<std::uint64_t>("header");
    const auto triangleCount = in.value<std::uint64_t>("header");
    if (vertexCount == 0 || triangleCount == 0) throw InputError(path, 0, "serialized mesh: the shape has no triangles");
    if (vertexCount > std::numeric_limits<std::uint32_t>::max()) {
        throw InputError(path, 0, "serialized mesh: more than 2^32 vertices are not supported");
    }
    const std::uint64_t realSize = single ? 4 : 8;
    std::uint64_t perVertex = 3 * realSize;
    if (flags & kHasNormals) perVertex += 3 * realSize;
    if (flags & kHasUvs) perVertex += 2 * realSize;
    if (flags & kHasColors) perVertex += 3 * realSize;
    const std::uint64_t limit = in.maxRemaining();
    if (vertexCount > limit / perVertex || triangleCount > limit / 12 ||
        vertexCount * perVertex + triangleCount * 12 > limit) {
        throw InputError(path, 0, "serialized mesh: the header claims " + std::to_string(vertexCount) + " vertices and " +
                                      std::to_string(triangleCount) + " triangles, more than the file can hold");
    }

    auto readVectors = [&](int components, const char* what) {
        std::vector<double> values(static_cast<std::size_t>(vertexCount) * components);
        if (single) {
            std::vector<float> raw(values.size());
            in.read(raw.data(), raw.size() * sizeof(float), what);
            for (std::size_t i = 0; i < raw.size(); ++i) values[i] = raw[i];
        } else {
            in.read(values.data(), values.size() * sizeof(double), what);
        }
        for (double v : values)
            if (!std::isfinite(v)) throw InputError(path, 0, std::string("serialized mesh: non-finite value in the ") + what);
        return values;
    };

    TriangleMesh mesh;
    const std::size_t n = static_cast<std::size_t>(vertexCount);
    const std::vector<double> positions = readVectors(3, "positions");
    mesh.positions.resize(n);
    for (std::size_t v = 0; v < n; ++v) {
        mesh.positions[v] = Vec3(static_cast<float>(positions[3 * v]), static_cast<float>(positions[3 * v + 1]),
                                 static_cast<float>(positions[3 * v + 2]));
    }
    if (flags & kHasNormals) {
        const std::vector<double> normals = readVectors(3, "normals");
        mesh.normals.resize(n);
        for (std::size_t v = 0; v < n; ++v) {
            const Vec3 normal(static_cast<float>(normals[3 * v]), static_cast<float>(normals[3 * v + 1]),
                              static_cast<float>(normals[3 * v + 2]));
            const float length = glm::length(normal);
            if (!(length > 0.0f)) throw InputError(path, 0, "serialized mesh: zero-length vertex normal");
            mesh.normals[v] = normal / length;
        }
    }
    if (flags & kHasUvs) {
        const std::vector<double> uvs = readVectors(2, "texture coordinates");
        mesh.uvs.resize(n);
        for (std::size_t v = 0; v < n; ++v) mesh.uvs[v] = Vec2(static_cast<float>(uvs[2 * v]), static_cast<float>(uvs[2 * v + 1]));
    }
    if (flags & kHasColors) readVectors(3, "vertex colours");  // fluxgraph has no vertex colours
    mesh.indices.resize(static_cast<std::size_t>(triangleCount) * 3);
    in.read(mesh.indices.data(), mesh.indices.size() * sizeof(std::uint32_t), "indices");
    for (std::uint32_t index : mesh.indices) {
        if (index >= vertexCount) {
            throw InputError(path, 0, "serialized mesh: vertex index " + std::to_string(index) + " out of range (" +
                                          std::to_string(vertexCount) + " vertices)");
        }
    }
    // Face normals requested by the file: flat shading.
    if (flags & kFaceNormals) mesh.normals.clear();
    return mesh;
}

}  // namespace fg
