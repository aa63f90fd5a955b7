// PLY meshes: ASCII and both binary byte orders give the same triangles,
// attributes and winding; damaged or non-mesh files are errors naming the file.
#include "engine/core/error.h"
#include "engine/scene/shape.h"
#include "tests/support/cli_helpers.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <bit>
#include <chrono>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <future>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

namespace fg {
namespace {

namespace fs = std::filesystem;

fs::path scratchDir() { return test::scratchDirectory("ply"); }

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

// Colours as integers are fractions of the type's range, as floats kept; texture
// coordinates under the other names exporters use; elements other than vertex
// and face, and properties the loader does not use, are read past.
TEST(PlyLoader, ReadsColoursOtherUvNamesAndSkipsUnusedData) {
    const fs::path dir = scratchDir();
    const std::string text =
        "ply\nformat ascii 1.0\nelement material 2\nproperty float shine\nproperty list uchar float tags\n"
        "element vertex 3\nproperty float x\nproperty float y\nproperty float z\nproperty float s\n"
        "property float t\nproperty uchar red\nproperty uchar green\nproperty uchar blue\nproperty float weight\n"
        "element face 1\nproperty uchar flags\nproperty list uchar uint vertex_index\n"
        "property list uchar float extra\nend_header\n"
        "0.5 2 1 2\n0.25 0\n"
        "0 0 0 0.1 0.2 255 0 51 7\n2 0 0 0.3 0.4 0 255 102 7\n0 2 0 0.5 0.6 17 34 0 7\n"
        "9 3 0 1 2 1 0.5\n";
    const TriangleMesh mesh = loadPlyMesh(write(dir / "colours.ply", text).string());
    ASSERT_EQ(mesh.triangleCount(), 1u);
    EXPECT_NEAR(mesh.area(), 2.0f, 1e-6f);
    ASSERT_EQ(mesh.uvs.size(), 3u);
    EXPECT_NEAR(glm::length(mesh.uvs[1] - Vec2(0.3f, 0.4f)), 0.0f, 1e-6f);
    const MeshAttribute* colors = mesh.attribute("vertex_color");
    ASSERT_NE(colors, nullptr);
    ASSERT_EQ(colors->channels, 3);
    ASSERT_EQ(colors->values.size(), 9u);
    EXPECT_NEAR(glm::length(Rgb(colors->values[0], colors->values[1], colors->values[2]) - Rgb(1.0f, 0.0f, 0.2f)), 0.0f, 1e-6f);
    EXPECT_NEAR(glm::length(Rgb(colors->values[6], colors->values[7], colors->values[8]) -
                            Rgb(1.0f / 15.0f, 2.0f / 15.0f, 0.0f)),
                0.0f, 1e-6f);
    // "weight" and "flags" have no channel suffix: Mitsuba leaves them out too.
    EXPECT_EQ(mesh.attributes.size(), 1u);

    // The same mesh in big-endian binary with 16-bit colours, double positions and ushort list counts.
    std::string binary =
        "ply\nformat binary_big_endian 1.0\nelement vertex 3\nproperty double x\nproperty double y\n"
        "property double z\nproperty ushort r\nproperty ushort g\nproperty ushort b\n"
        "element face 1\nproperty list ushort int vertex_indices\nend_header\n";
    const double positions[3][3] = {{0, 0, 0}, {2, 0, 0}, {0, 2, 0}};
    for (const auto& p : positions) {
        for (double c : p) append(binary, c, true);
        for (std::uint16_t c : {std::uint16_t{65535}, std::uint16_t{0}, std::uint16_t{13107}}) append(binary, c, true);
    }
    append(binary, std::uint16_t{3}, true);
    for (std::int32_t i : {0, 1, 2}) append(binary, i, true);
    const TriangleMesh fromBinary = loadPlyMesh(write(dir / "colours_be.ply", binary).string());
    const MeshAttribute* binaryColors = fromBinary.attribute("vertex_color");
    ASSERT_NE(binaryColors, nullptr);
    ASSERT_EQ(binaryColors->values.size(), 9u);
    EXPECT_NEAR(glm::length(Rgb(binaryColors->values[3], binaryColors->values[4], binaryColors->values[5]) -
                            Rgb(1.0f, 0.0f, 0.2f)),
                0.0f, 1e-6f);
    EXPECT_NEAR(fromBinary.area(), 2.0f, 1e-6f);
    EXPECT_TRUE(fromBinary.uvs.empty());
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

// As Mitsuba's mesh_attributes test mesh stores them: vertex color_0..2, face
// color_0..2 and a one-channel face weight_0; a quad's values repeat on both triangles.
TEST(PlyLoader, GroupsVertexAndFacePropertiesIntoNamedAttributes) {
    const fs::path dir = scratchDir();
    const std::string text =
        "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
        "property float color_0\nproperty float color_1\nproperty float color_2\nproperty float normal_x\n"
        "property float pair_0\nproperty float pair_1\n"
        "element face 2\nproperty list uchar int vertex_indices\nproperty float color_0\nproperty float color_1\n"
        "property float color_2\nproperty float weight_0\nproperty uchar tint_r\nproperty uchar tint_g\n"
        "property uchar tint_b\nend_header\n"
        "0 0 0 0.1 0.2 0.3 5 0 0\n1 0 0 0.4 0.5 0.6 6 0 0\n1 1 0 0.7 0.8 0.9 7 0 0\n0 1 0 1 1 1 8 0 0\n"
        "4 0 1 2 3 0.25 0.5 0.75 0.125 255 0 51\n3 0 2 3 1 0 0 0.5 0 0 0\n";
    const TriangleMesh mesh = loadPlyMesh(write(dir / "attributes.ply", text).string());
    ASSERT_EQ(mesh.triangleCount(), 3u);
    const MeshAttribute* vertexColor = mesh.attribute("vertex_color");
    ASSERT_NE(vertexColor, nullptr);
    EXPECT_TRUE(vertexColor->perVertex());
    ASSERT_EQ(vertexColor->values.size(), 12u);
    EXPECT_FLOAT_EQ(vertexColor->values[4], 0.5f);
    const MeshAttribute* normal = mesh.attribute("vertex_normal");
    ASSERT_NE(normal, nullptr);
    EXPECT_EQ(normal->channels, 1);
    EXPECT_FLOAT_EQ(normal->values[3], 8.0f);
    // Two channels are not an attribute in Mitsuba's scheme.
    EXPECT_EQ(mesh.attribute("vertex_pair"), nullptr);

    const MeshAttribute* faceColor = mesh.attribute("face_color");
    ASSERT_NE(faceColor, nullptr);
    EXPECT_FALSE(faceColor->perVertex());
    ASSERT_EQ(faceColor->values.size(), 9u);
    for (int triangle : {0, 1}) EXPECT_FLOAT_EQ(faceColor->values[3 * triangle + 2], 0.75f);
    EXPECT_FLOAT_EQ(faceColor->values[6], 1.0f);
    const MeshAttribute* weight = mesh.attribute("face_weight");
    ASSERT_NE(weight, nullptr);
    ASSERT_EQ(weight->values.size(), 3u);
    EXPECT_FLOAT_EQ(weight->values[1], 0.125f);
    EXPECT_FLOAT_EQ(weight->values[2], 0.5f);
    // prefix_r/g/b is a colour; integers are fractions of their range.
    const MeshAttribute* tint = mesh.attribute("face_tint_color");
    ASSERT_NE(tint, nullptr);
    EXPECT_FLOAT_EQ(tint->values[0], 1.0f);
    EXPECT_FLOAT_EQ(tint->values[2], 0.2f);
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
    const std::string noVertex =
        "ply\nformat ascii 1.0\nelement verTex 3\nproperty float x\nproperty float y\nproperty float z\n"
        "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";
    expectError(write(dir / "novertex.ply", noVertex), "no vertex element");
    const std::string noZ =
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
        "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0\n1 0\n0 1\n3 0 1 2\n";
    expectError(write(dir / "noz.ply", noZ), ":3: PLY vertex element has no x, y and z");
    const std::string fractionalIndex =
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
        "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1.5 2\n";
    expectError(write(dir / "fraction.ply", fractionalIndex), "'1.5' is not an integer");
    // A list count beyond what the rest of the file holds is refused before its items are read.
    const std::string longList =
        "ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
        "property float z\nelement face 1\nproperty list uint int vertex_indices\nend_header\n";
    std::string longListData = longList;
    for (int v = 0; v < 9; ++v) append(longListData, 0.0f, false);
    append(longListData, std::uint32_t{4000000000u}, false);
    for (std::int32_t i : {0, 1, 2}) append(longListData, i, false);
    expectError(write(dir / "longlist.ply", longListData), "list count 4000000000 is more than the file can hold");
}

// Loads on a detached thread so that a loader that hangs fails the test instead
// of stalling it (a std::async future would wait for the load when destroyed).
void expectErrorWithinSeconds(const fs::path& path, const std::string& fragment) {
    std::packaged_task<std::string()> load([file = path.string()]() -> std::string {
        try {
            loadPlyMesh(file);
            return "no error";
        } catch (const InputError& e) {
            return e.what();
        } catch (const std::exception& e) {
            return std::string("not an input error: ") + e.what();
        }
    });
    std::future<std::string> message = load.get_future();
    std::thread(std::move(load)).detach();
    ASSERT_EQ(message.wait_for(std::chrono::seconds(10)), std::future_status::ready) << "loading " << path << " hangs";
    const std::string text = message.get();
    EXPECT_NE(text.find(path.string()), std::string::npos) << text;
    EXPECT_NE(text.find(fragment), std::string::npos) << text;
}

std::string binaryBody(std::size_t bytes) { return std::string(bytes, '\x01'); }

TEST(PlyLoader, MalformedHeadersAreErrorsNotHangsOrCrashes) {
    const fs::path dir = scratchDir();
    expectErrorWithinSeconds(write(dir / "no_end_ascii.ply", "ply\nformat ascii 1.0\n"), "no end_header");
    expectErrorWithinSeconds(
        write(dir / "no_end_binary.ply",
              "ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\n" + binaryBody(64)),
        "no end_header");
    expectErrorWithinSeconds(write(dir / "endless_comment.ply", "ply\nformat ascii 1.0\n" +
                                                                     std::string(100 * 1024, 'c')),
                             "within its first 64 KiB");
    expectErrorWithinSeconds(write(dir / "format.ply", "ply\nformat binary_middle_endian 1.0\nend_header\n"),
                             "unknown PLY format");
    expectErrorWithinSeconds(write(dir / "noformat.ply", "ply\nelement vertex 0\nend_header\n"), "no format line");
    expectErrorWithinSeconds(
        write(dir / "type.ply", "ply\nformat ascii 1.0\nelement vertex 1\nproperty float128 x\nend_header\n0\n"),
        ":4: unknown PLY property type");
    expectErrorWithinSeconds(
        write(dir / "listcount.ply",
              "ply\nformat ascii 1.0\nelement face 1\nproperty list float int vertex_indices\nend_header\n0\n"),
        "count type must be an integer");
    expectErrorWithinSeconds(write(dir / "orphan.ply", "ply\nformat ascii 1.0\nproperty float x\nend_header\n"),
                             "property before any element");
    expectErrorWithinSeconds(write(dir / "count.ply", "ply\nformat ascii 1.0\nelement vertex -3\nend_header\n"),
                             "not a non-negative integer");
}

TEST(PlyLoader, ElementCountsMustFitTheFileSize) {
    const fs::path dir = scratchDir();
    const std::string vertices = "element vertex 1000000000\nproperty float x\nproperty float y\nproperty float z\n"
                                 "element face 1\nproperty list uchar int vertex_indices\nend_header\n";
    expectErrorWithinSeconds(write(dir / "huge_ascii.ply", "ply\nformat ascii 1.0\n" + vertices + "0 0 0\n3 0 0 0\n"),
                             ":3: PLY element 'vertex' has 1000000000 records");
    expectErrorWithinSeconds(
        write(dir / "huge_binary.ply", "ply\nformat binary_little_endian 1.0\n" + vertices + binaryBody(64)),
        ":3: PLY element 'vertex' has 1000000000 records");
    expectErrorWithinSeconds(write(dir / "huge_le.ply", "ply\nformat binary_big_endian 1.0\nelement vertex "
                                                        "18446744073709551615\nproperty double x\nend_header\n" +
                                                            binaryBody(8)),
                             "records");
    expectErrorWithinSeconds(write(dir / "overflow.ply", "ply\nformat binary_big_endian 1.0\nelement vertex "
                                                         "99999999999999999999\nproperty double x\nend_header\n"),
                             "impossibly large count");
    // Lists count only their count field: the fixed part of 2 face records fits, a third does not.
    const std::string faces = "ply\nformat binary_little_endian 1.0\nelement face 3\n"
                              "property list uchar int vertex_indices\nend_header\n";
    expectErrorWithinSeconds(write(dir / "faces.ply", faces + binaryBody(2)), "PLY element 'face' has 3 records");
}

}  // namespace
}  // namespace fg
