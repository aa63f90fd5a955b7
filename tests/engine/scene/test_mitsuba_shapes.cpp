// Mitsuba shapes and sensors beyond the basic ones: the orthographic sensor,
// rotated spheres, cylinders, serialized meshes, shape groups and instances,
// and the refusal of heterogeneous media.
#include "engine/accel/ray_query.h"
#include "engine/core/error.h"
#include "engine/scene/scene_toml.h"
#include "engine/scene/scene_xml.h"
#include "engine/shading/light.h"
#include "tests/support/chi2.h"
#include "tests/support/cli_helpers.h"
#include "tests/support/scene_text.h"

#include <glm/gtc/matrix_transform.hpp>
#include <gtest/gtest.h>
#include <zlib.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

namespace fg {
namespace {

namespace fs = std::filesystem;
using test::lineOf;

fs::path scratchDir() { return test::scratchDirectory("mitsuba_shapes"); }

fs::path writeFile(const fs::path& path, const std::string& text) {
    test::writeText(path, text);
    return path;
}

bool contains(const std::string& text, const std::string& part) { return text.find(part) != std::string::npos; }

std::string sceneText(const std::string& body, const std::string& sensor = "") {
    return test::mitsubaSceneText(body, {.fov = std::nullopt, .sensor = sensor});
}

std::string loadErrorMessage(const fs::path& path) {
    try {
        loadXmlScene(path.string());
    } catch (const InputError& e) {
        return e.what();
    }
    ADD_FAILURE() << "no InputError for " << path;
    return "";
}

// The error names file:line of `marker` and contains `part`.
void expectErrorAt(const fs::path& path, const std::string& text, const std::string& marker, const std::string& part) {
    writeFile(path, text);
    const std::string message = loadErrorMessage(path);
    const std::string location = path.string() + ":" + std::to_string(lineOf(text, marker)) + ":";
    EXPECT_TRUE(contains(message, location)) << "expected " << location << " in: " << message;
    EXPECT_TRUE(contains(message, part)) << "expected '" << part << "' in: " << message;
    EXPECT_EQ(message.find('\n'), std::string::npos) << "one line: " << message;
}

// ---- orthographic sensor --------------------------------------------------------------

TEST(MitsubaSensor, OrthographicRaysAreParallelAndSpanTheScaledWindow) {
    const fs::path dir = scratchDir();
    // As Mitsuba's test scene: x and y scaled by 1.5, 200 x 120 pixels, looking along +x.
    const std::string sensor = R"(    <sensor type="orthographic">
        <float name="near_clip" value="1"/><float name="far_clip" value="1000"/>
        <transform name="to_world"><scale x="1.5" y="1.5"/><lookat target="0, 0, 1" origin="-5, 0, 3" up="0, 0, 1"/></transform>
        <film type="hdrfilm"><integer name="width" value="200"/><integer name="height" value="120"/></film>
    </sensor>
)";
    const Scene scene = loadXmlScene(writeFile(dir / "ortho.xml", sceneText("", sensor)).string());
    const Camera& camera = scene.camera;
    ASSERT_TRUE(camera.orthographic);
    const Vec3 forward = glm::normalize(Vec3(5, 0, -2));
    // The window spans local x in [-1, 1] and y in [-1/aspect, 1/aspect], times the scale.
    const float halfWidth = 1.5f, halfHeight = 1.5f * 120.0f / 200.0f;
    const Ray centre = camera.generateRay(Vec2(100.0f, 60.0f));
    const Ray corner = camera.generateRay(Vec2(0.0f, 0.0f));
    const Ray other = camera.generateRay(Vec2(200.0f, 120.0f));
    for (const Ray* r : {&centre, &corner, &other}) {
        EXPECT_NEAR(glm::dot(r->direction, forward), 1.0f, 1e-6f) << "parallel rays";
        EXPECT_NEAR(r->tMax, 999.0f, 1e-3f) << "far - near";
    }
    const Vec3 eyeOnNearPlane = Vec3(-5, 0, 3) + 1.0f * forward;
    EXPECT_NEAR(glm::length(centre.origin - eyeOnNearPlane), 0.0f, 1e-5f);
    const Vec3 diagonal = other.origin - corner.origin;
    EXPECT_NEAR(glm::dot(diagonal, forward), 0.0f, 1e-5f);
    const Vec3 up = glm::normalize(glm::cross(glm::cross(forward, Vec3(0, 0, 1)), forward));
    EXPECT_NEAR(std::abs(glm::dot(diagonal, up)), 2.0f * halfHeight, 1e-4f);
    EXPECT_NEAR(glm::length(diagonal - glm::dot(diagonal, up) * up), 2.0f * halfWidth, 1e-4f);
    // Image up is world up; Mitsuba's +x (up x forward) is image left.
    EXPECT_GT(glm::dot(corner.origin - centre.origin, up), 0.0f);
    EXPECT_GT(glm::dot(corner.origin - centre.origin, glm::cross(Vec3(0, 0, 1), forward)), 0.0f);
    // project() inverts generateRay for points anywhere along the ray.
    for (const Vec2 raster : {Vec2(3.5f, 7.25f), Vec2(150.0f, 100.0f)}) {
        const Ray r = camera.generateRay(raster);
        Vec2 back;
        ASSERT_TRUE(camera.project(r.origin + 37.0f * r.direction, &back));
        EXPECT_NEAR(back.x, raster.x, 1e-3f);
        EXPECT_NEAR(back.y, raster.y, 1e-3f);
    }
}

TEST(MitsubaSensor, OrthographicErrors) {
    const fs::path dir = scratchDir();
    const std::string skewed = sceneText("", R"(    <sensor type="orthographic">
        <transform name="to_world"><scale x="1" y="2"/></transform>
    </sensor>
)");
    expectErrorAt(dir / "skewed.xml", skewed, "to_world", "sensor 'orthographic'");
    const std::string fov = sceneText("", R"(    <sensor type="orthographic">
        <float name="fov" value="30"/>
    </sensor>
)");
    expectErrorAt(dir / "fov.xml", fov, "name=\"fov\"", "unknown parameter 'fov'");
}

TEST(SceneToml, OrthographicCamera) {
    const Scene scene = parseTomlScene(R"([camera]
type = "orthographic"
eye = [0, 0, 5]
target = [0, 0, 0]
view_height = 3
width = 40
height = 20
)",
                                       "ortho.toml", ".");
    ASSERT_TRUE(scene.camera.orthographic);
    const Ray a = scene.camera.generateRay(Vec2(0.0f, 10.0f));
    const Ray b = scene.camera.generateRay(Vec2(40.0f, 10.0f));
    EXPECT_NEAR(glm::length(b.origin - a.origin), 6.0f, 1e-5f) << "width = view_height * aspect";
    EXPECT_NEAR(a.direction.z, -1.0f, 1e-6f);
    EXPECT_THROW(parseTomlScene("[camera]\ntype = \"orthographic\"\neye = [0, 0, 5]\ntarget = [0, 0, 0]\nfov = 30\n", "o.toml", "."),
                 InputError);
    EXPECT_THROW(parseTomlScene("[camera]\ntype = \"fisheye\"\neye = [0, 0, 5]\ntarget = [0, 0, 0]\n", "o.toml", "."),
                 InputError);
}

// ---- spheres --------------------------------------------------------------------------

TEST(MitsubaShapes, RotatedSphereTurnsItsParametrisation) {
    const fs::path dir = scratchDir();
    const std::string text = sceneText(R"(    <shape type="sphere">
        <transform name="to_world"><scale value="2"/><rotate x="1" angle="90"/><translate x="1"/></transform>
    </shape>
)");
    Scene scene = loadXmlScene(writeFile(dir / "rotated.xml", text).string());
    ASSERT_EQ(scene.shapes.size(), 1u);
    const Sphere& sphere = std::get<Sphere>(scene.shapes[0].geometry);
    EXPECT_NEAR(sphere.radius, 2.0f, 1e-6f);
    EXPECT_NEAR(glm::length(sphere.center - Vec3(1, 0, 0)), 0.0f, 1e-6f);
    const RayQuery rays(scene);
    // Rotating +90 degrees about x carries the object's +z pole (v = 0) to world -y.
    Ray ray;
    ray.origin = Vec3(1, -10, 0);
    ray.direction = Vec3(0, 1, 0);
    const SurfacePoint pole = rays.surface(ray, rays.intersect(ray));
    EXPECT_NEAR(pole.p.y, -2.0f, 1e-4f);
    EXPECT_NEAR(pole.uv.y, 0.0f, 1e-3f);
    // The object's +x (u = 0, on the equator v = 1/2) stays +x; object +y (u = 1/4) goes to world +z.
    ray.origin = Vec3(1, 0, 10);
    ray.direction = Vec3(0, 0, -1);
    const SurfacePoint side = rays.surface(ray, rays.intersect(ray));
    EXPECT_NEAR(side.uv.x, 0.25f, 1e-4f);
    EXPECT_NEAR(side.uv.y, 0.5f, 1e-4f);
}

// ---- disks -------------------------------------------------------------------------------

TEST(MitsubaShapes, DiskUvIsPolarAsMitsubas) {
    Scene scene;
    Shape disk;
    disk.geometry = makeDiskMesh(128);
    scene.shapes.push_back(disk);
    scene.finalize();
    const RayQuery rays(scene);
    for (const Vec2 point : {Vec2(0.5f, 0.2f), Vec2(-0.3f, 0.6f), Vec2(-0.4f, -0.7f), Vec2(0.8f, -0.05f)}) {
        Ray ray;
        ray.origin = Vec3(point, 1.0f);
        ray.direction = Vec3(0, 0, -1);
        const SurfacePoint sp = rays.surface(ray, rays.intersect(ray));
        float phi = std::atan2(point.y, point.x);
        if (phi < 0.0f) phi += 2.0f * kPi;
        EXPECT_NEAR(sp.uv.x, glm::length(point), 2e-3f) << "u = r";
        // Linear across each fan triangle: exact on the rim, within half a segment inside.
        EXPECT_NEAR(sp.uv.y, phi / (2.0f * kPi), 0.5f / 128.0f) << "v = phi / 2 pi";
    }
    EXPECT_NEAR(disk.area(), kPi, 2e-3f);
}

// ---- cylinders ------------------------------------------------------------------------

TEST(MitsubaShapes, CylinderIsAnOutwardFacingTube) {
    const fs::path dir = scratchDir();
    const std::string text = sceneText(R"(    <shape type="cylinder">
        <float name="radius" value="0.5"/><point name="p0" x="1" y="0" z="0"/><point name="p1" x="1" y="3" z="0"/>
    </shape>
    <shape type="cylinder"><transform name="to_world"><scale x="2" y="2" z="4"/><translate z="100"/></transform></shape>
)");
    const Scene scene = loadXmlScene(writeFile(dir / "cylinder.xml", text).string());
    ASSERT_EQ(scene.shapes.size(), 2u);
    EXPECT_NEAR(scene.shapes[0].area(), 2.0f * kPi * 0.5f * 3.0f, 1e-3f);
    EXPECT_NEAR(scene.shapes[1].area(), 2.0f * kPi * 2.0f * 4.0f, 1e-2f);
    const auto& tube = std::get<TriangleMesh>(scene.shapes[0].geometry);
    for (std::size_t v = 0; v < tube.positions.size(); ++v) {
        const Vec3 radial = tube.positions[v] - Vec3(1.0f, tube.positions[v].y, 0.0f);
        EXPECT_NEAR(glm::length(radial), 0.5f, 1e-5f);
        EXPECT_NEAR(glm::dot(tube.normals[v], radial / 0.5f), 1.0f, 1e-5f) << "vertex normals point outwards";
    }
    // Facet windings face outwards too, and the tube is open: a ray along its axis passes.
    const RayQuery rays(scene);
    Ray ray;
    ray.origin = Vec3(1.0f, 1.5f, 5.0f);
    ray.direction = Vec3(0, 0, -1);
    const SurfacePoint outside = rays.surface(ray, rays.intersect(ray));
    EXPECT_NEAR(outside.ng.z, 1.0f, 1e-3f);
    EXPECT_NEAR(outside.uv.y, 0.5f, 1e-4f) << "v is the height along p0 -> p1";
    ray.origin = Vec3(1.0f, -5.0f, 0.0f);
    ray.direction = Vec3(0, 1, 0);
    EXPECT_FALSE(rays.intersect(ray).valid());

    expectErrorAt(dir / "bad.xml",
                  sceneText("    <shape type=\"cylinder\"><float name=\"radius\" value=\"-1\"/></shape>\n"), "radius",
                  "shape 'cylinder'");
}

// Archimedes: the axial projection of a unit tube onto the unit sphere
// (z in [0, 1] -> cos theta = 2 z - 1, same phi) preserves area, so points
// uniform on the tube map to directions uniform on the sphere.
TEST(MitsubaShapes, CylinderAreaSamplingIsUniformChi2) {
    Shape shape;
    shape.geometry = makeCylinderMesh();
    const auto light = makeAreaLight(shape, Rgb(1.0f));
    test::Chi2Config config;
    config.samples = 400'000;
    const auto result = test::chi2SphereTest(
        [&](const Vec2& u) -> std::optional<Vec3> {
            const auto e = light->sampleEmission(u, Vec2(0.3f, 0.6f));
            if (!e) return std::nullopt;
            const float cosTheta = 2.0f * e->origin.z - 1.0f;
            const float sinTheta = std::sqrt(std::max(0.0f, 1.0f - cosTheta * cosTheta));
            const float phi = std::atan2(e->origin.y, e->origin.x);
            return Vec3(sinTheta * std::cos(phi), sinTheta * std::sin(phi), cosTheta);
        },
        [](const Vec3&) { return 1.0 / (4.0 * M_PI); }, config);
    EXPECT_TRUE(result.passed) << result.message;
}

TEST(SceneToml, Cylinder) {
    const Scene scene = parseTomlScene(R"([camera]
eye = [0, 0, 5]
target = [0, 0, 0]
[[material]]
name = "white"
type = "diffuse"
[[shape]]
type = "cylinder"
material = "white"
radius = 0.25
p0 = [0, 0, 0]
p1 = [0, 2, 0]
)",
                                       "cyl.toml", ".");
    ASSERT_EQ(scene.shapes.size(), 1u);
    EXPECT_NEAR(scene.shapes[0].area(), 2.0f * kPi * 0.25f * 2.0f, 1e-3f);
    EXPECT_THROW(parseTomlScene("[camera]\neye = [0, 0, 5]\ntarget = [0, 0, 0]\n[[material]]\nname = \"w\"\ntype = \"diffuse\"\n"
                                "[[shape]]\ntype = \"cylinder\"\nmaterial = \"w\"\np1 = [0, 0, 0]\n",
                                "cyl.toml", "."),
                 InputError);
}

// ---- shape groups and instances ------------------------------------------------------

TEST(MitsubaShapes, InstancesEqualTheFlattenedScene) {
    const fs::path dir = scratchDir();
    writeFile(dir / "quad.obj", "v -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\nf 1 2 3 4\n");
    const std::string members = R"(
        <shape type="obj"><string name="filename" value="quad.obj"/>
            <transform name="to_world"><rotate y="1" angle="-80"/></transform>
            <bsdf type="diffuse"><rgb name="reflectance" value="0.2 0.5 0.3"/></bsdf></shape>
        <shape type="sphere"><transform name="to_world"><scale value="0.5"/><translate x="-1"/></transform></shape>
        <shape type="cylinder"><float name="radius" value="0.3"/></shape>)";
    const std::string placement = R"(<rotate y="1" angle="45"/><rotate x="1" angle="-25"/><scale value="1.5"/><translate z="2"/>)";
    const std::string grouped = sceneText("    <shape type=\"shapegroup\" id=\"group\">" + members +
                                          "\n    </shape>\n"
                                          "    <shape type=\"instance\"><ref id=\"group\"/></shape>\n"
                                          "    <shape type=\"instance\"><ref id=\"group\"/><transform name=\"to_world\">" +
                                          placement + "</transform></shape>\n");
    // The same shapes written out twice, the second time with the placement appended to each to_world.
    std::string flattened = members;
    for (const char* original : {"<rotate y=\"1\" angle=\"-80\"/>", "<translate x=\"-1\"/>"}) {
        flattened.replace(flattened.find(original), std::string(original).size(), std::string(original) + placement);
    }
    const std::string radius = "<float name=\"radius\" value=\"0.3\"/>";
    flattened.replace(flattened.find(radius), radius.size(),
                      radius + "<transform name=\"to_world\">" + placement + "</transform>");
    const Scene a = loadXmlScene(writeFile(dir / "grouped.xml", grouped).string());
    const Scene b = loadXmlScene(writeFile(dir / "flat.xml", sceneText(members + flattened + "\n")).string());
    ASSERT_EQ(a.shapes.size(), 6u);
    ASSERT_EQ(b.shapes.size(), 6u);
    for (std::size_t i = 0; i < 6; ++i) {
        SCOPED_TRACE("shape " + std::to_string(i));
        EXPECT_EQ(a.shapes[i].isSphere(), b.shapes[i].isSphere());
        EXPECT_NEAR(a.shapes[i].area(), b.shapes[i].area(), 1e-4f * b.shapes[i].area());
        if (const auto* sa = std::get_if<Sphere>(&a.shapes[i].geometry)) {
            const Sphere& sb = std::get<Sphere>(b.shapes[i].geometry);
            EXPECT_NEAR(glm::length(sa->center - sb.center), 0.0f, 1e-5f);
            EXPECT_NEAR(sa->radius, sb.radius, 1e-6f);
            for (int c = 0; c < 3; ++c) EXPECT_NEAR(glm::length(sa->worldToObject[c] - sb.worldToObject[c]), 0.0f, 1e-5f);
            continue;
        }
        ASSERT_TRUE(std::holds_alternative<MeshInstance>(a.shapes[i].geometry)) << "group meshes are instanced";
        const TriangleMesh ma = a.shapes[i].worldMesh();
        const auto& mb = std::get<TriangleMesh>(b.shapes[i].geometry);
        ASSERT_EQ(ma.positions.size(), mb.positions.size());
        EXPECT_EQ(ma.indices, mb.indices);
        for (std::size_t v = 0; v < ma.positions.size(); ++v) {
            EXPECT_NEAR(glm::length(ma.positions[v] - mb.positions[v]), 0.0f, 1e-5f);
            EXPECT_NEAR(glm::length(ma.normals[v] - mb.normals[v]), 0.0f, 1e-5f);
        }
    }
    // Members share their group's material and mesh data across instances.
    EXPECT_EQ(a.shapes[0].bsdf, a.shapes[3].bsdf);
    EXPECT_EQ(std::get<MeshInstance>(a.shapes[0].geometry).mesh, std::get<MeshInstance>(a.shapes[3].geometry).mesh);

    // Traced through Embree instances, every ray sees what it sees in the flattened scene.
    const RayQuery rayA(a), rayB(b);
    int hits = 0;
    for (int j = 0; j < 40; ++j) {
        for (int i = 0; i < 40; ++i) {
            Ray ray;
            ray.origin = Vec3(-8.0f, 0.5f, 0.3f);
            ray.direction = glm::normalize(Vec3(1.0f, -0.6f + 1.2f * (i + 0.5f) / 40.0f, -0.9f + 1.8f * (j + 0.5f) / 40.0f));
            const Hit ha = rayA.intersect(ray), hb = rayB.intersect(ray);
            ASSERT_EQ(ha.shape, hb.shape) << i << ", " << j;
            if (!ha.valid()) continue;
            ++hits;
            EXPECT_NEAR(ha.t, hb.t, 1e-4f * hb.t);
            const SurfacePoint sa = rayA.surface(ray, ha), sb = rayB.surface(ray, hb);
            EXPECT_NEAR(glm::length(sa.p - sb.p), 0.0f, 1e-4f);
            EXPECT_NEAR(glm::dot(sa.ng, sb.ng), 1.0f, 1e-4f);
            EXPECT_NEAR(glm::dot(sa.ns, sb.ns), 1.0f, 1e-4f);
            EXPECT_NEAR(glm::length(sa.uv - sb.uv), 0.0f, 1e-4f);
            const Vec3 dp(0.01f, -0.02f, 0.015f);
            const Vec3 da = rayA.shadingNormalDifferential(ray, ha, dp), db = rayB.shadingNormalDifferential(ray, hb, dp);
            EXPECT_NEAR(glm::length(da - db), 0.0f, 1e-3f * (1.0f + glm::length(db)));
        }
    }
    EXPECT_GT(hits, 100) << "the rays must meet the instances";
}

// A mirroring instance keeps the side its normals face, as a mirrored copy would.
TEST(MitsubaShapes, MirroredInstanceFacesLikeAMirroredCopy) {
    const fs::path dir = scratchDir();
    const std::string member = R"(<shape type="rectangle"><transform name="to_world"><rotate y="1" angle="30"/></transform></shape>)";
    const std::string mirror = R"(<scale x="-1"/><translate x="0.5"/>)";
    const Scene grouped = loadXmlScene(
        writeFile(dir / "g.xml", sceneText("    <shape type=\"shapegroup\" id=\"g\">" + member + "</shape>\n"
                                           "    <shape type=\"instance\"><ref id=\"g\"/><transform name=\"to_world\">" +
                                           mirror + "</transform></shape>\n"))
            .string());
    const Scene flat = loadXmlScene(
        writeFile(dir / "f.xml", sceneText(R"(<shape type="rectangle"><transform name="to_world"><rotate y="1" angle="30"/>)" +
                                           mirror + "</transform></shape>\n"))
            .string());
    const RayQuery a(grouped), b(flat);
    for (const float side : {-1.0f, 1.0f}) {
        Ray ray;
        ray.origin = Vec3(0.3f, 0.2f, 5.0f * side);
        ray.direction = Vec3(0.0f, 0.0f, -side);
        const SurfacePoint sa = a.surface(ray, a.intersect(ray)), sb = b.surface(ray, b.intersect(ray));
        EXPECT_NEAR(glm::dot(sa.ng, sb.ng), 1.0f, 1e-5f);
        EXPECT_NEAR(glm::dot(sa.ns, sb.ns), 1.0f, 1e-5f);
    }
}

TEST(MitsubaShapes, ShapeGroupErrors) {
    const fs::path dir = scratchDir();
    expectErrorAt(dir / "noid.xml", sceneText("    <shape type=\"shapegroup\"><shape type=\"cube\"/></shape>\n"),
                  "shapegroup", "needs an id");
    expectErrorAt(dir / "notgroup.xml",
                  sceneText("    <shape type=\"cube\" id=\"box\"/>\n    <shape type=\"instance\"><ref id=\"box\"/></shape>\n"),
                  "<ref id=\"box\"", "must refer to a shapegroup");
    // An unused group is still read.
    expectErrorAt(dir / "unused.xml",
                  sceneText("    <shape type=\"shapegroup\" id=\"g\">\n        <shape type=\"sdfgrid\"/>\n    </shape>\n"),
                  "sdfgrid", "unknown shape type");
    expectErrorAt(dir / "nested.xml",
                  sceneText("    <shape type=\"shapegroup\" id=\"g\">\n        <shape type=\"shapegroup\" id=\"h\"><shape type=\"cube\"/></shape>\n"
                            "    </shape>\n    <shape type=\"instance\"><ref id=\"g\"/></shape>\n"),
                  "id=\"h\"", "cannot be nested");
}

// ---- serialized meshes --------------------------------------------------------------

template <typename T>
void append(std::string& bytes, const T& value) {
    bytes.append(reinterpret_cast<const char*>(&value), sizeof(T));
}

std::string deflate(const std::string& raw) {
    uLongf size = compressBound(static_cast<uLong>(raw.size()));
    std::string out(size, '\0');
    EXPECT_EQ(compress(reinterpret_cast<Bytef*>(out.data()), &size, reinterpret_cast<const Bytef*>(raw.data()),
                       static_cast<uLong>(raw.size())),
              Z_OK);
    out.resize(size);
    return out;
}

// One shape in Mitsuba's serialized layout: a quad [-1, 1]^2 at height z, normals +z, uvs.
std::string serializedQuad(float z, std::uint16_t version = 4, std::uint64_t claimedVertices = 4) {
    std::string raw;
    append<std::uint32_t>(raw, 0x0001 | 0x0002 | 0x1000);
    if (version >= 4) raw += std::string("quad") + '\0';
    append<std::uint64_t>(raw, claimedVertices);
    append<std::uint64_t>(raw, 2);
    const float positions[4][3] = {{-1, -1, z}, {1, -1, z}, {1, 1, z}, {-1, 1, z}};
    for (const auto& p : positions) for (float c : p) append(raw, c);
    for (int v = 0; v < 4; ++v) for (float c : {0.0f, 0.0f, 1.0f}) append(raw, c);
    const float uvs[4][2] = {{0, 0}, {1, 0}, {1, 1}, {0, 1}};
    for (const auto& uv : uvs) for (float c : uv) append(raw, c);
    for (std::uint32_t i : {0u, 1u, 2u, 0u, 2u, 3u}) append(raw, i);
    std::string shape;
    append<std::uint16_t>(shape, 0x041C);
    append<std::uint16_t>(shape, version);
    return shape + deflate(raw);
}

TEST(SerializedMesh, LoadsShapesByIndex) {
    const fs::path dir = scratchDir();
    const std::string first = serializedQuad(0.0f), second = serializedQuad(2.0f);
    std::string file = first + second;
    append<std::uint64_t>(file, 0);
    append<std::uint64_t>(file, first.size());
    append<std::uint32_t>(file, 2);
    const fs::path path = writeFile(dir / "two.serialized", file);
    const TriangleMesh a = loadSerializedMesh(path.string(), 0);
    const TriangleMesh b = loadSerializedMesh(path.string(), 1);
    ASSERT_EQ(a.positions.size(), 4u);
    ASSERT_EQ(b.indices.size(), 6u);
    EXPECT_NEAR(a.area(), 4.0f, 1e-6f);
    EXPECT_EQ(a.positions[2], Vec3(1, 1, 0));
    EXPECT_EQ(b.positions[2], Vec3(1, 1, 2));
    EXPECT_EQ(b.normals[0], Vec3(0, 0, 1));
    EXPECT_EQ(b.uvs[2], Vec2(1, 1));
    EXPECT_THROW(loadSerializedMesh(path.string(), 2), InputError);

    // Through the XML importer, with to_world and face_normals.
    const std::string text = sceneText(R"(    <shape type="serialized"><string name="filename" value="two.serialized"/>
        <integer name="shape_index" value="1"/><boolean name="face_normals" value="true"/>
        <transform name="to_world"><scale value="2"/></transform></shape>
)");
    const Scene scene = loadXmlScene(writeFile(dir / "scene.xml", text).string());
    const auto& mesh = std::get<TriangleMesh>(scene.shapes.at(0).geometry);
    EXPECT_NEAR(mesh.area(), 16.0f, 1e-5f);
    EXPECT_TRUE(mesh.normals.empty());
    EXPECT_EQ(mesh.positions[0], Vec3(-2, -2, 4));
}

TEST(SerializedMesh, BadFilesAreOneClearError) {
    const fs::path dir = scratchDir();
    const std::string good = serializedQuad(0.0f, 3);
    EXPECT_EQ(loadSerializedMesh(writeFile(dir / "v3.serialized", good).string()).positions.size(), 4u) << "version 3";
    struct Case {
        std::string name, bytes, expected;
    };
    std::string badTag = good;
    badTag[0] = 'x';
    std::string badVersion = good;
    badVersion[2] = 9;
    const std::string truncated = good.substr(0, good.size() - 8);
    std::string corrupt = good;
    for (std::size_t i = 8; i < corrupt.size(); i += 3) corrupt[i] = static_cast<char>(corrupt[i] ^ 0x5a);
    const Case cases[] = {
        {"empty", "", "too short"},
        {"tag", badTag, "format tag"},
        {"version", badVersion, "version 9"},
        {"truncated", truncated, "serialized mesh"},
        {"corrupt", corrupt, "serialized mesh"},
        // A header claiming 2^31 vertices is refused before anything is allocated.
        {"huge", serializedQuad(0.0f, 4, std::uint64_t(1) << 31), "more than the file can hold"},
    };
    for (const Case& c : cases) {
        const fs::path path = writeFile(dir / (c.name + ".serialized"), c.bytes);
        try {
            loadSerializedMesh(path.string());
            ADD_FAILURE() << c.name << ": no error";
        } catch (const InputError& e) {
            const std::string message = e.what();
            EXPECT_TRUE(contains(message, path.string())) << message;
            EXPECT_TRUE(contains(message, c.expected)) << c.name << ": " << message;
        }
    }
    // In a scene, the error names the element's line.
    const std::string text = sceneText("    <shape type=\"serialized\"><string name=\"filename\" value=\"tag.serialized\"/></shape>\n");
    expectErrorAt(dir / "scene.xml", text, "filename", "shape 'serialized'");
}

// ---- the teapot that data/veach-ajar supplies ----------------------------------------------

// Outward-facing meshes enclose a positive signed volume (divergence theorem).
double signedVolume(const TriangleMesh& mesh) {
    double volume = 0.0;
    for (std::size_t t = 0; t + 2 < mesh.indices.size(); t += 3) {
        const glm::dvec3 a(mesh.positions[mesh.indices[t]]), b(mesh.positions[mesh.indices[t + 1]]),
            c(mesh.positions[mesh.indices[t + 2]]);
        volume += glm::dot(a, glm::cross(b, c)) / 6.0;
    }
    return volume;
}

TEST(VeachAjarTeapot, MeshesFaceOutwardsAndStandOnTheirBase) {
    const fs::path models = fs::path(FLUXGRAPH_SOURCE_DIR) / "data" / "veach-ajar" / "models";
    const TriangleMesh body = loadObjMesh((models / "Mesh000.obj").string());
    const TriangleMesh lid = loadObjMesh((models / "Mesh009.obj").string());
    float lowest = 1e9f, highest = -1e9f;
    for (const TriangleMesh* mesh : {&body, &lid}) {
        ASSERT_GT(mesh->triangleCount(), 1000u);
        ASSERT_EQ(mesh->normals.size(), mesh->positions.size());
        for (const Vec3& p : mesh->positions) {
            lowest = std::min(lowest, p.y);
            highest = std::max(highest, p.y);
        }
        // Winding and vertex normals agree.
        for (std::size_t t = 0; t + 2 < mesh->indices.size(); t += 3) {
            const std::uint32_t i0 = mesh->indices[t], i1 = mesh->indices[t + 1], i2 = mesh->indices[t + 2];
            const Vec3 ng = glm::cross(mesh->positions[i1] - mesh->positions[i0], mesh->positions[i2] - mesh->positions[i0]);
            ASSERT_GT(glm::dot(ng, mesh->normals[i0] + mesh->normals[i1] + mesh->normals[i2]), 0.0f) << "triangle " << t / 3;
        }
    }
    EXPECT_NEAR(lowest, 0.0f, 1e-4f) << "base on y = 0";
    EXPECT_NEAR(highest, 3.15f, 1e-3f) << "Newell's teapot is 3.15 units tall";
    EXPECT_GT(signedVolume(body), 15.0);
    EXPECT_GT(signedVolume(lid), 0.0);
}

// ---- media -------------------------------------------------------------------------------

TEST(MitsubaMedia, HeterogeneousMediaAreRefusedByName) {
    const fs::path dir = scratchDir();
    const std::string grid = sceneText(R"(    <shape type="cube">
        <medium type="heterogeneous" name="interior">
            <volume name="sigma_t" type="gridvolume"><string name="filename" value="smoke.vol"/></volume>
        </medium>
    </shape>
)");
    expectErrorAt(dir / "grid.xml", grid, "heterogeneous", "heterogeneous medium not supported");
    const std::string volumeInHomogeneous = sceneText(R"(    <medium type="homogeneous" id="fog">
        <volume name="albedo" type="constvolume"/>
    </medium>
)");
    expectErrorAt(dir / "volume.xml", volumeInHomogeneous, "<volume", "heterogeneous medium not supported");
}

}  // namespace
}  // namespace fg
