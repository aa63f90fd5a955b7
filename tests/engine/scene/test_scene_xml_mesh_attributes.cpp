// Mitsuba XML import of the mesh_attribute texture and blendbsdf: a PLY
// mesh's face and vertex attributes reach the material through the ray
// query's hit, and a name the mesh lacks, a sphere, or a use outside a
// material is an error naming the file, line and plugin, all in one load.
#include "engine/scene/scene_xml.h"

#include "engine/accel/ray_query.h"
#include "engine/core/error.h"
#include "engine/shading/bsdf.h"
#include "tests/support/cli_helpers.h"
#include "tests/support/scene_text.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <string>

namespace fg {
namespace {

namespace fs = std::filesystem;
using test::lineOf;

// An 8-pixel film without a fov: these tests only trace rays at known points.
std::string sceneText(const std::string& body) { return test::mitsubaSceneText(body, {.filmSize = 8, .fov = std::nullopt}); }

fs::path scratchDir() { return test::scratchDirectory("scene_xml_mesh_attributes"); }

fs::path writeFile(const fs::path& path, const std::string& text) {
    test::writeText(path, text);
    return path;
}

// The unit square at z = 0 as two triangles, (0 1 2) and (0 2 3), with a
// colour per vertex and per face and a one-channel face weight, named as
// Mitsuba writes them.
fs::path writeSquare(const fs::path& dir) {
    return writeFile(dir / "square.ply",
                     "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
                     "property float color_0\nproperty float color_1\nproperty float color_2\n"
                     "element face 2\nproperty list uchar int vertex_indices\nproperty float color_0\n"
                     "property float color_1\nproperty float color_2\nproperty float weight_0\nend_header\n"
                     "0 0 0 1 0 0\n1 0 0 0 1 0\n1 1 0 0 0 1\n0 1 0 1 1 1\n"
                     "3 0 1 2 0.2 0.4 0.6 0.25\n3 0 2 3 0.9 0.8 0.7 0.75\n");
}

// The diffuse albedo the shape's material has where a ray down the z axis through (x, y) hits it.
Rgb albedoAt(const Scene& scene, const RayQuery& rays, float x, float y) {
    Ray ray;
    ray.origin = Vec3(x, y, 1.0f);
    ray.direction = Vec3(0.0f, 0.0f, -1.0f);
    const Hit hit = rays.intersect(ray);
    EXPECT_TRUE(hit.valid());
    if (!hit.valid()) return Rgb(-1.0f);
    const SurfacePoint sp = rays.surface(ray, hit);
    const Bsdf& bsdf = *scene.bsdfs[static_cast<std::size_t>(scene.shapes[hit.shape].bsdf)];
    const std::optional<Rgb> reflectance = bsdf.constantReflectance(sp.texturePoint());
    EXPECT_TRUE(reflectance.has_value());
    return reflectance.value_or(Rgb(-1.0f)) * kPi;
}

void expectNear(const Rgb& a, const Rgb& b, float tolerance, const std::string& what) {
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(a[c], b[c], tolerance) << what << " component " << c;
}

Scene loadSquare(const fs::path& dir, const std::string& name, const std::string& bsdf) {
    writeSquare(dir);
    const std::string text = sceneText("    <shape type=\"ply\"><string name=\"filename\" value=\"square.ply\"/>\n" + bsdf + "</shape>\n");
    return loadXmlScene(writeFile(dir / name, text).string());
}

TEST(SceneXmlMeshAttributes, FaceColourIsConstantOverEachFace) {
    const Scene scene = loadSquare(scratchDir(), "face.xml",
                                   "<bsdf type=\"diffuse\"><texture type=\"mesh_attribute\" name=\"reflectance\">"
                                   "<string name=\"name\" value=\"face_color\"/></texture></bsdf>\n");
    const RayQuery rays(scene);
    // Below the diagonal is triangle (0 1 2), above it (0 2 3).
    for (const Vec2 p : {Vec2(0.6f, 0.1f), Vec2(0.9f, 0.5f), Vec2(0.5f, 0.45f)})
        expectNear(albedoAt(scene, rays, p.x, p.y), Rgb(0.2f, 0.4f, 0.6f), 1e-6f, "first face");
    for (const Vec2 p : {Vec2(0.1f, 0.6f), Vec2(0.5f, 0.9f), Vec2(0.45f, 0.5f)})
        expectNear(albedoAt(scene, rays, p.x, p.y), Rgb(0.9f, 0.8f, 0.7f), 1e-6f, "second face");
}

TEST(SceneXmlMeshAttributes, VertexColourIsInterpolatedOverEachTriangle) {
    const Scene scene = loadSquare(scratchDir(), "vertex.xml",
                                   "<bsdf type=\"diffuse\"><texture type=\"mesh_attribute\" name=\"reflectance\">"
                                   "<string name=\"name\" value=\"vertex_color\"/><float name=\"scale\" value=\"0.5\"/>"
                                   "</texture></bsdf>\n");
    const RayQuery rays(scene);
    // Bilinear in the square's coordinates on each triangle: (x, y) = b1 (1, 0) + b2 (1, 1) on (0 1 2),
    // b1 (1, 1) + b2 (0, 1) on (0 2 3).
    const auto expected = [](float x, float y) {
        const Rgb v[4] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}, {1, 1, 1}};
        if (y < x) return 0.5f * ((1.0f - x) * v[0] + (x - y) * v[1] + y * v[2]);
        return 0.5f * ((1.0f - y) * v[0] + x * v[2] + (y - x) * v[3]);
    };
    for (const Vec2 p : {Vec2(0.6f, 0.1f), Vec2(0.9f, 0.5f), Vec2(0.1f, 0.6f), Vec2(0.3f, 0.9f), Vec2(0.02f, 0.01f)})
        expectNear(albedoAt(scene, rays, p.x, p.y), expected(p.x, p.y), 1e-5f, "at " + std::to_string(p.x) + ", " + std::to_string(p.y));
}

TEST(SceneXmlMeshAttributes, BlendbsdfTakesAFaceWeight) {
    const Scene scene = loadSquare(scratchDir(), "blend.xml",
                                   "<bsdf type=\"blendbsdf\"><texture type=\"mesh_attribute\" name=\"weight\">"
                                   "<string name=\"name\" value=\"face_weight\"/></texture>"
                                   "<bsdf type=\"diffuse\"><rgb name=\"reflectance\" value=\"0 .5 .5\"/></bsdf>"
                                   "<bsdf type=\"diffuse\"><rgb name=\"reflectance\" value=\"1 1 0\"/></bsdf></bsdf>\n");
    const RayQuery rays(scene);
    expectNear(albedoAt(scene, rays, 0.6f, 0.1f), 0.75f * Rgb(0, 0.5f, 0.5f) + 0.25f * Rgb(1, 1, 0), 1e-6f, "weight 0.25");
    expectNear(albedoAt(scene, rays, 0.1f, 0.6f), 0.25f * Rgb(0, 0.5f, 0.5f) + 0.75f * Rgb(1, 1, 0), 1e-6f, "weight 0.75");
}

// Each problem is its own "file:line: plugin 'type': message" line, all from one load.
TEST(SceneXmlMeshAttributes, MissingAttributesAndMisplacedTexturesAreErrors) {
    const fs::path dir = scratchDir();
    writeSquare(dir);
    const std::string text = sceneText(
        "    <texture type=\"mesh_attribute\" id=\"normals\"><string name=\"name\" value=\"vertex_normal\"/></texture>\n"
        "    <bsdf type=\"diffuse\" id=\"by_normal\"><ref name=\"reflectance\" id=\"normals\"/></bsdf>\n"
        "    <shape type=\"ply\"><string name=\"filename\" value=\"square.ply\"/><ref id=\"by_normal\"/></shape> <!-- ply -->\n"
        "    <shape type=\"rectangle\"><ref id=\"by_normal\"/></shape> <!-- rectangle -->\n"
        "    <shape type=\"sphere\"><ref id=\"by_normal\"/></shape> <!-- sphere -->\n"
        "    <shape type=\"ply\"><string name=\"filename\" value=\"square.ply\"/>\n"
        "        <bsdf type=\"diffuse\"><texture type=\"mesh_attribute\" name=\"reflectance\">\n"
        "            <string name=\"name\" value=\"color\"/></texture></bsdf></shape> <!-- prefix -->\n"
        "    <shape type=\"rectangle\"><emitter type=\"area\"> <!-- emitter -->\n"
        "        <texture type=\"mesh_attribute\" name=\"radiance\"><string name=\"name\" value=\"face_color\"/></texture>\n"
        "    </emitter></shape>\n"
        "    <shape type=\"ply\"><string name=\"filename\" value=\"square.ply\"/>\n"
        "        <bsdf type=\"normalmap\"><texture type=\"mesh_attribute\"> <!-- normalmap -->\n"
        "            <string name=\"name\" value=\"vertex_color\"/></texture><bsdf type=\"diffuse\"/></bsdf></shape>\n");
    const fs::path path = writeFile(dir / "errors.xml", text);
    std::string message;
    try {
        loadXmlScene(path.string());
        ADD_FAILURE() << "no InputError";
    } catch (const InputError& e) {
        message = e.what();
    }
    const auto expectLine = [&](const std::string& marker, const std::string& fragment) {
        const std::string location = path.string() + ":" + std::to_string(lineOf(text, marker)) + ": ";
        const auto at = message.find(location);
        ASSERT_NE(at, std::string::npos) << "expected " << location << " in:\n" << message;
        const std::string line = message.substr(at, message.find('\n', at) - at);
        EXPECT_NE(line.find(fragment), std::string::npos) << "expected " << fragment << " in: " << line;
    };
    const std::string texture = "mesh_attribute texture at " + path.string() + ":" + std::to_string(lineOf(text, "id=\"normals\""));
    expectLine("<!-- ply -->", "shape 'ply': the mesh has no attribute 'vertex_normal' (read by the " + texture +
                                   "); it has vertex_color, face_color, face_weight");
    expectLine("<!-- rectangle -->", "shape 'rectangle': the mesh has no attribute 'vertex_normal'");
    expectLine("<!-- rectangle -->", "it has none");
    expectLine("<!-- sphere -->", "shape 'sphere': its bsdf reads the mesh attribute 'vertex_normal'");
    expectLine("<!-- sphere -->", "a sphere is not a mesh");
    expectLine("value=\"color\"", "texture 'mesh_attribute': name 'color' must start with \"vertex_\" or \"face_\"");
    expectLine("name=\"radiance\"", "emitter 'area': a mesh_attribute texture cannot serve as an emitter's 'radiance'");
    expectLine("<!-- normalmap -->", "bsdf 'normalmap': a mesh_attribute texture cannot serve as a bump or normal map");
    EXPECT_EQ(std::count(message.begin(), message.end(), '\n'), 5) << message;  // six lines
}

}  // namespace
}  // namespace fg
