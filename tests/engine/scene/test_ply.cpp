// PLY meshes: ASCII and both binary byte orders give the same triangles,
// attributes and winding; damaged or non-mesh files are errors naming the file.
#include "engine/core/error.h"
#include "engine/scene/shape.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <bit>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

namespace fg {
namespace {

namespace fs = std::filesystem;

fs::path scratchDir() {
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    const fs::path dir = fs::path(FLUXGRAPH_TEST_TMP) / "ply" / (std::string(info->test_suite_name()) + "." + info->name());
    fs::remove_all(dir);
    fs::create_directories(dir);
    return dir;
}

// A unit square in the z = 1 plane as one quad plus a triangle hanging below it,
// with normals and texture coordinates.
struct Vertex {
    float x, y, z, nx, ny, nz, u, v;
};
const std::vector<Vertex> kVertices = {
    {0, 0, 1, 0, 0, 1, 0.0f, 0.0f},    {1, 0, 1, 0, 0, 1, 1.0f, 0.0f},     {1, 1, 1, 0, 0, 1, 1.0f, 1.0f},
    {0, 1, 1, 0, 0, 1, 0.0f, 1.0f},    {0.5f, -1, 1, 0, 0, 1, 0.5f, 0.25f},
};
const std::vector<std::vector<int>> kFaces = {{0, 1, 2, 3}, {0, 4, 1}};

std::string header(const std::string& format) {
    return "ply\nformat " + format + " 1.0\ncomment written by the fluxgraph tests\nelement vertex 5\n"
           "property float x\nproperty float y\nproperty float z\nproperty float nx\nproperty float ny\n"
           "property float nz\nproperty float u\nproperty float v\nproperty uchar red\n"
           "element face 2\nproperty list uchar int vertex_indices\nend_header\n";
}

std::string asciiPly() {
    std::ostringstream text;
    text << header("ascii");
    for (const Vertex& v : kVertices) {
        text << v.x << ' ' << v.y << ' ' << v.z << ' ' << v.nx << ' ' << v.ny << ' ' << v.nz << ' ' << v.u << ' ' << v.v
             << " 200\n";
    }
    for (const auto& face : kFaces) {
        text << face.size();
        for (int i : face) text << ' ' << i;
        text << '\n';
    }
    return text.str();
}

template <typename T>
void append(std::string& out, T value, bool bigEndian) {
    char bytes[sizeof(T)];
    std::memcpy(bytes, &value, sizeof(T));
    if (bigEndian != (std::endian::native == std::endian::big)) std::reverse(bytes, bytes + sizeof(T));
    out.append(bytes, sizeof(T));
}

std::string binaryPly(bool bigEndian) {
    std::string data = header(bigEndian ? "binary_big_endian" : "binary_little_endian");
    for (const Vertex& v : kVertices) {
        for (float f : {v.x, v.y, v.z, v.nx, v.ny, v.nz, v.u, v.v}) append(data, f, bigEndian);
        append(data, std::uint8_t{200}, bigEndian);
    }
    for (const auto& face : kFaces) {
        append(data, static_cast<std::uint8_t>(face.size()), bigEndian);
        for (int i : face) append(data, static_cast<std::int32_t>(i), bigEndian);
    }
    return data;
}

fs::path write(const fs::path& path, const std::string& data) {
    std::ofstream(path, std::ios::binary) << data;
    return path;
}

void expectTheTestMesh(const TriangleMesh& mesh, const std::string& what) {
    SCOPED_TRACE(what);
    ASSERT_EQ(mesh.triangleCount(), 3u);
    EXPECT_NEAR(mesh.area(), 1.0f + 0.5f, 1e-5f);
    ASSERT_EQ(mesh.normals.size(), mesh.positions.size());
    ASSERT_EQ(mesh.uvs.size(), mesh.positions.size());
    // Every output vertex carries the attributes of the input vertex at its position.
    for (std::size_t i = 0; i < mesh.positions.size(); ++i) {
        bool found = false;
        for (const Vertex& v : kVertices) {
            if (glm::length(mesh.positions[i] - Vec3(v.x, v.y, v.z)) > 1e-5f) continue;
            found = true;
            EXPECT_NEAR(glm::length(mesh.normals[i] - Vec3(v.nx, v.ny, v.nz)), 0.0f, 1e-5f);
            EXPECT_NEAR(glm::length(mesh.uvs[i] - Vec2(v.u, v.v)), 0.0f, 1e-5f) << "uv stored as in the file";
        }
        EXPECT_TRUE(found) << "vertex " << i;
    }
    // Winding kept: counter-clockwise seen from +z, so geometric normals agree with the stored ones.
    for (std::size_t t = 0; t < mesh.triangleCount(); ++t) {
        const Vec3& a = mesh.positions[mesh.indices[3 * t]];
        const Vec3& b = mesh.positions[mesh.indices[3 * t + 1]];
        const Vec3& c = mesh.positions[mesh.indices[3 * t + 2]];
        EXPECT_GT(glm::cross(b - a, c - a).z, 0.0f) << "triangle " << t;
    }
}

TEST(PlyLoader, AsciiAndBinaryGiveTheSameMesh) {
    const fs::path dir = scratchDir();
    expectTheTestMesh(loadPlyMesh(write(dir / "ascii.ply", asciiPly()).string()), "ascii");
    expectTheTestMesh(loadPlyMesh(write(dir / "le.ply", binaryPly(false)).string()), "binary little-endian");
    expectTheTestMesh(loadPlyMesh(write(dir / "be.ply", binaryPly(true)).string()), "binary big-endian");
}

TEST(PlyLoader, PositionsOnlyMeshHasNoAttributes) {
    const fs::path dir = scratchDir();
    const std::string text =
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
        "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n2 0 0\n0 2 0\n3 0 1 2\n";
    const TriangleMesh mesh = loadPlyMesh(write(dir / "tri.ply", text).string());
    EXPECT_EQ(mesh.triangleCount(), 1u);
    EXPECT_NEAR(mesh.area(), 2.0f, 1e-6f);
    EXPECT_TRUE(mesh.normals.empty());
    EXPECT_TRUE(mesh.uvs.empty());
}

void expectError(const fs::path& path, const std::string& fragment) {
    try {
        loadPlyMesh(path.string());
        ADD_FAILURE() << "no error for " << path;
    } catch (const InputError& e) {
        const std::string message = e.what();
        EXPECT_NE(message.find(path.string()), std::string::npos) << message;
        EXPECT_NE(message.find(fragment), std::string::npos) << message;
    }
}

TEST(PlyLoader, BadFilesAreErrorsNamingTheFile) {
    const fs::path dir = scratchDir();
    expectError(dir / "missing.ply", "not found");
    expectError(write(dir / "obj.ply", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"), "not a PLY file");
    const std::string binary = binaryPly(false);
    expectError(write(dir / "truncated.ply", binary.substr(0, binary.size() - 20)), "PLY");
    const std::string points =
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
        "end_header\n0 0 0\n1 0 0\n0 1 0\n";
    expectError(write(dir / "points.ply", points), "PLY");
    const std::string badIndex =
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
        "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n";
    expectError(write(dir / "badindex.ply", badIndex), "PLY");
    // Legal syntax, but not a polygon (Assimp's triangulation step would abort the program on it).
    const std::string emptyFace =
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
        "element face 2\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n0\n";
    expectError(write(dir / "emptyface.ply", emptyFace), "face 1 has 0 corners");
    const std::string notANumber =
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
        "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 zero 0\n0 1 0\n3 0 1 2\n";
    expectError(write(dir / "nan.ply", notANumber), "cannot parse PLY file");
}

}  // namespace
}  // namespace fg
