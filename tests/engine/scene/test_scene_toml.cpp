#include "engine/scene/scene_toml.h"

#include "engine/core/error.h"
#include "engine/accel/ray_query.h"
#include "engine/scene/scene_loader.h"
#include "engine/shading/bsdf.h"
#include "tests/support/cli_helpers.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <string>

namespace fg {
namespace {

namespace fs = std::filesystem;

const std::string kCornellBox = std::string(FLUXGRAPH_SOURCE_DIR) + "/data/cornell-box/cornell-box.toml";
const std::string kMediumBox = std::string(FLUXGRAPH_SOURCE_DIR) + "/data/medium-box/medium-box.toml";

// A fresh directory per test under the build tree's test scratch space.
fs::path scratchDir() { return test::scratchDirectory("scene_toml"); }

void writeFile(const fs::path& path, const std::string& text) {
    fs::create_directories(path.parent_path());
    std::ofstream(path) << text;
}

const char* kCamera = R"([camera]
eye = [0, 0, 5]
target = [0, 0, 0]
)";

const char* kWhite = R"(
[[material]]
name = "white"
type = "diffuse"
reflectance = [0.5, 0.5, 0.5]
)";

Scene parse(const std::string& body, const std::string& baseDir = ".") {
    return parseTomlScene(std::string(kCamera) + kWhite + body, "test.toml", baseDir);
}

// Parses text expected to fail; returns the error for inspection.
InputError parseError(const std::string& fullText, const std::string& baseDir = ".") {
    try {
        parseTomlScene(fullText, "test.toml", baseDir);
    } catch (const InputError& e) {
        return e;
    }
    ADD_FAILURE() << "no InputError for:\n" << fullText;
    return InputError("no error");
}

// Line numbers below count from the start of the full text; the common header is 8 lines.
constexpr int kHeaderLines = 8;

InputError bodyError(const std::string& body) { return parseError(std::string(kCamera) + kWhite + body); }

void expectErrorAt(const InputError& e, int line, const std::string& fragment) {
    EXPECT_EQ(e.line(), line) << e.what();
    EXPECT_EQ(e.file(), "test.toml");
    EXPECT_NE(std::string(e.what()).find("test.toml:" + std::to_string(line) + ":"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find(fragment), std::string::npos) << e.what();
}

TEST(SceneToml, HeaderLineCountIsWhatTheTestsAssume) {
    const std::string header = std::string(kCamera) + kWhite;
    EXPECT_EQ(std::count(header.begin(), header.end(), '\n'), kHeaderLines);
}

TEST(SceneToml, CornellBoxLoads) {
    const Scene scene = loadTomlScene(kCornellBox);
    EXPECT_EQ(scene.sourcePath, kCornellBox);
    ASSERT_EQ(scene.shapes.size(), 8u);
    EXPECT_EQ(scene.bsdfs.size(), 5u);
    ASSERT_EQ(scene.lights.size(), 1u);
    ASSERT_EQ(scene.lightShape.size(), 1u);
    EXPECT_EQ(scene.lightShape[0], 0);
    EXPECT_EQ(scene.shapes[0].areaLight, 0);
    for (std::size_t i = 1; i < scene.shapes.size(); ++i) EXPECT_EQ(scene.shapes[i].areaLight, -1);
    EXPECT_EQ(scene.shapes[0].name, "cbox_luminaire");
    EXPECT_EQ(scene.shapes[1].bsdf, 1);  // floor: white
    EXPECT_EQ(scene.shapes[4].bsdf, 3);  // green wall
    EXPECT_EQ(scene.shapes[5].bsdf, 2);  // red wall
    EXPECT_EQ(std::get<TriangleMesh>(scene.shapes[1].geometry).triangleCount(), 2u);
    EXPECT_EQ(std::get<TriangleMesh>(scene.shapes[2].geometry).triangleCount(), 4u);
    EXPECT_EQ(std::get<TriangleMesh>(scene.shapes[7].geometry).triangleCount(), 12u);

    EXPECT_EQ(scene.camera.eye, Vec3(278, 273, -800));
    EXPECT_EQ(scene.camera.target, Vec3(278, 273, -799));
    EXPECT_FLOAT_EQ(scene.camera.fovYDegrees, 39.3077f);
    EXPECT_EQ(scene.camera.width, 256);
    EXPECT_EQ(scene.camera.height, 256);
    EXPECT_EQ(scene.camera.medium, -1);

    EXPECT_NEAR(scene.boundsMin.x, 0.0f, 1e-3f);
    EXPECT_NEAR(scene.boundsMax.x, 556.0f, 1e-3f);
    EXPECT_NEAR(scene.boundsMax.y, 548.8f, 1e-3f);
    EXPECT_NEAR(scene.boundsMax.z, 559.2f, 1e-3f);
    EXPECT_EQ(scene.lightPower.size(), 1u);

    // The luminaire was lowered by the transform and faces down into the room.
    const auto& lum = std::get<TriangleMesh>(scene.shapes[0].geometry);
    for (const Vec3& p : lum.positions) EXPECT_NEAR(p.y, 548.3f, 1e-3f);

    RayQuery query(scene);
    // Above the tall box, the middle column of the image sees the back wall.
    const Ray upperMiddle = scene.camera.generateRay({128.0f, 60.0f});
    const Hit back = query.intersect(upperMiddle);
    ASSERT_TRUE(back.valid());
    EXPECT_EQ(back.shape, 3u);
    EXPECT_NEAR(query.surface(upperMiddle, back).p.z, 559.2f, 0.05f);
    EXPECT_NEAR(query.surface(upperMiddle, back).p.x, 278.0f, 0.05f);

    Ray up;
    up.origin = Vec3(278, 1, 279.5f);
    up.direction = Vec3(0, 1, 0);
    const Hit lamp = query.intersect(up);
    ASSERT_TRUE(lamp.valid());
    EXPECT_EQ(lamp.shape, 0u);
    EXPECT_LT(query.surface(up, lamp).ng.y, -0.999f);

    // The red wall is on the left of the image, the green one on the right.
    const Hit left = query.intersect(scene.camera.generateRay({20.0f, 128.0f}));
    const Hit right = query.intersect(scene.camera.generateRay({236.0f, 128.0f}));
    ASSERT_TRUE(left.valid() && right.valid());
    EXPECT_EQ(left.shape, 5u);
    EXPECT_EQ(right.shape, 4u);
}

TEST(SceneToml, MediumBoxLoads) {
    const Scene scene = loadTomlScene(kMediumBox);
    ASSERT_EQ(scene.media.size(), 1u);
    EXPECT_FLOAT_EQ(scene.media[0].sigmaS().x, 0.5f);
    EXPECT_FLOAT_EQ(scene.media[0].sigmaA().z, 0.1f);
    ASSERT_EQ(scene.shapes.size(), 2u);
    EXPECT_EQ(scene.shapes[1].interiorMedium, 0);
    EXPECT_EQ(scene.shapes[1].exteriorMedium, -1);
    EXPECT_EQ(scene.shapes[0].interiorMedium, -1);
    EXPECT_EQ(scene.lights.size(), 1u);
    EXPECT_EQ(scene.lightShape[0], -1);
    EXPECT_EQ(scene.camera.medium, -1);
    // The fog cube floats above the floor without touching it.
    float lowest = 1e9f;
    for (const Vec3& p : std::get<TriangleMesh>(scene.shapes[1].geometry).positions) lowest = std::min(lowest, p.y);
    EXPECT_NEAR(lowest, 0.1f, 1e-5f);
    RayQuery query(scene);
    Ray down;
    down.origin = Vec3(0.2f, 5, 0.3f);
    down.direction = Vec3(0, -1, 0);
    const Hit top = query.intersect(down);
    ASSERT_TRUE(top.valid());
    EXPECT_EQ(top.shape, 1u);
    EXPECT_NEAR(top.t, 5.0f - 1.9f, 1e-4f);
    EXPECT_GT(query.surface(down, top).ng.y, 0.999f);  // outward, so the interior is the fog
}

TEST(SceneToml, EveryFeatureParses) {
    const fs::path dir = scratchDir();
    writeFile(dir / "tex" / "grid.ppm", "P3\n2 2\n255\n255 0 0  0 255 0\n0 0 255  255 255 255\n");
    const std::string text = std::string(R"([camera]
eye = [0, 1, 5]
target = [0, 1, 0]
up = [0, 1, 0]
fov = 45
width = 320
height = 200
medium = "air"

[[medium]]
name = "air"
sigma_s = [0.01, 0.02, 0.03]
sigma_a = 0
g = 0.3
scale = 2

[[medium]]
name = "ink"
sigma_s = 1
sigma_a = 0.5

[[material]]
name = "checks"
type = "diffuse"
reflectance = { checkerboard = { even = 0.2, odd = [0.8, 0.7, 0.6], scale = [4, 4] } }

[[material]]
name = "wood"
type = "plastic"
reflectance = { bitmap = "tex/grid.ppm", uv_scale = [2, 2] }
ior = "bk7"
nonlinear = true

[[material]]
name = "glass"
type = "dielectric"
ior = 1.5
exterior_ior = "air"

[[material]]
name = "film"
type = "thindielectric"
ior = 1.33

[[material]]
name = "gold"
type = "conductor"
material = "Au"

[[material]]
name = "mirror"
type = "conductor"

[[material]]
name = "brushed"
type = "roughconductor"
eta = [0.2, 0.9, 1.1]
k = [3.9, 2.4, 2.2]
alpha = 0.3

[[material]]
name = "frosted"
type = "roughdielectric"
ior = 1.5
alpha = 0.2

[[material]]
name = "boundary"
type = "null"

[[material]]
name = "both"
type = "twosided"
inner = "checks"

[[shape]]
type = "rectangle"
material = "both"
transform = [{ rotate = { axis = [1, 0, 0], angle = -90 } }, { scale = [3, 1, 3] }]

[[shape]]
type = "disk"
segments = 16
material = "gold"
emission = [1, 2, 3]
two_sided_emission = true
transform = [{ lookat = { origin = [0, 3, 0], target = [0, 0, 0], up = [0, 0, 1] } }]

[[shape]]
type = "cube"
material = "boundary"
interior = "ink"
exterior = "air"
flip_normals = true
transform = [{ matrix = [[1, 0, 0, 3], [0, 1, 0, 1], [0, 0, 1, 0], [0, 0, 0, 1]] }]

[[shape]]
name = "ball"
type = "sphere"
center = [1, 1, 1]
radius = 0.25
material = "glass"
flip_normals = true

[[light]]
type = "point"
position = [0, 4, 0]
intensity = 10

[[light]]
type = "spot"
position = [0, 4, 0]
target = [0, 0, 0]
intensity = [5, 5, 5]
cutoff_angle = 30
beam_width = 20

[[light]]
type = "directional"
direction = [0, -1, 0]
irradiance = 2

[[light]]
type = "constant"
radiance = 0.1

[[light]]
type = "envmap"
file = "tex/grid.ppm"
scale = 0.5
transform = [{ rotate = { axis = [0, 1, 0], angle = 90 } }]
)");
    const Scene scene = parseTomlScene(text, "all.toml", dir.string());
    EXPECT_EQ(scene.camera.medium, 0);
    EXPECT_EQ(scene.camera.width, 320);
    EXPECT_EQ(scene.camera.height, 200);
    EXPECT_FLOAT_EQ(scene.camera.fovYDegrees, 45.0f);
    ASSERT_EQ(scene.media.size(), 2u);
    EXPECT_FLOAT_EQ(scene.media[0].sigmaS().z, 0.06f);  // scaled
    EXPECT_FLOAT_EQ(scene.media[0].phase().g(), 0.3f);
    EXPECT_EQ(scene.bsdfs.size(), 10u);
    ASSERT_EQ(scene.shapes.size(), 4u);
    EXPECT_EQ(scene.shapes[0].bsdf, 9);
    EXPECT_EQ(scene.shapes[2].interiorMedium, 1);
    EXPECT_EQ(scene.shapes[2].exteriorMedium, 0);
    EXPECT_EQ(scene.shapes[3].name, "ball");
    EXPECT_TRUE(scene.shapes[3].isSphere());
    EXPECT_TRUE(scene.shapes[3].flipNormals);
    EXPECT_FALSE(scene.shapes[2].flipNormals);  // meshes are flipped in their data instead
    ASSERT_EQ(scene.lights.size(), 6u);
    EXPECT_EQ(scene.lightShape, (std::vector<int>{1, -1, -1, -1, -1, -1}));
    EXPECT_EQ(scene.shapes[1].areaLight, 0);

    // Floor: the rotation made it face +y, then the scale stretched x and z.
    const auto& floor = std::get<TriangleMesh>(scene.shapes[0].geometry);
    for (const Vec3& p : floor.positions) {
        EXPECT_NEAR(std::abs(p.x), 3.0f, 1e-5f);
        EXPECT_NEAR(p.y, 0.0f, 1e-5f);
        EXPECT_NEAR(std::abs(p.z), 3.0f, 1e-5f);
    }
    // The disk was placed at y = 3 looking down.
    RayQuery query(scene);
    Ray up;
    up.origin = Vec3(0.1f, 1.5f, 0.1f);
    up.direction = Vec3(0, 1, 0);
    const Hit disk = query.intersect(up);
    ASSERT_TRUE(disk.valid());
    EXPECT_EQ(disk.shape, 1u);
    EXPECT_NEAR(disk.t, 1.5f, 1e-4f);
    EXPECT_LT(query.surface(up, disk).ng.y, -0.999f);
    // The flipped cube, moved by the row-major matrix to x in [2, 4], y in [0, 2], has inward normals.
    const auto& cube = std::get<TriangleMesh>(scene.shapes[2].geometry);
    float minY = 1e9f;
    for (const Vec3& p : cube.positions) minY = std::min(minY, p.y);
    EXPECT_NEAR(minY, 0.0f, 1e-6f);
    Ray side;
    side.origin = Vec3(5, 1, 0.2f);
    side.direction = Vec3(-1, 0, 0);
    const Hit cubeHit = query.intersect(side);
    ASSERT_TRUE(cubeHit.valid());
    EXPECT_EQ(cubeHit.shape, 2u);
    EXPECT_LT(query.surface(side, cubeHit).ng.x, -0.999f);
}

TEST(SceneToml, TransformStepsApplyInListedOrder) {
    const Scene a = parse(R"(
[[shape]]
type = "rectangle"
material = "white"
transform = [{ scale = 2 }, { translate = [0, 0, 5] }]
)");
    const Scene b = parse(R"(
[[shape]]
type = "rectangle"
material = "white"
transform = [{ translate = [0, 0, 5] }, { scale = 2 }]
)");
    for (const Vec3& p : std::get<TriangleMesh>(a.shapes[0].geometry).positions) {
        EXPECT_FLOAT_EQ(p.z, 5.0f);
        EXPECT_FLOAT_EQ(std::abs(p.x), 2.0f);
    }
    for (const Vec3& p : std::get<TriangleMesh>(b.shapes[0].geometry).positions) {
        EXPECT_FLOAT_EQ(p.z, 10.0f);
        EXPECT_FLOAT_EQ(std::abs(p.x), 2.0f);
    }
    const Scene c = parse(R"(
[[shape]]
type = "rectangle"
material = "white"
transform = [{ matrix = [1, 0, 0, 3,  0, 1, 0, 0,  0, 0, 1, 0,  0, 0, 0, 1] }]
)");
    for (const Vec3& p : std::get<TriangleMesh>(c.shapes[0].geometry).positions) EXPECT_NEAR(std::abs(p.x - 3.0f), 1.0f, 1e-6f);
}

TEST(SceneToml, MalformedTomlReportsItsLine) {
    const std::string text = "[camera]\neye = [0, 0, 5]\ntarget = [0, 0, 0]\nfov = = 40\n";
    const InputError e = parseError(text);
    EXPECT_EQ(e.line(), 4) << e.what();
    EXPECT_EQ(std::string(e.what()).rfind("test.toml:4:", 0), 0u) << e.what();

    const InputError unterminated = parseError(std::string(kCamera) + kWhite + "\n[[shape]]\ntype = \"obj\nmaterial = \"white\"\n");
    EXPECT_EQ(unterminated.line(), kHeaderLines + 3) << unterminated.what();
}

TEST(SceneToml, UnknownKeysAreErrors) {
    expectErrorAt(bodyError(R"(
[[shape]]
type = "sphere"
material = "white"
radius = 1
colour = [1, 0, 0]
)"),
                  kHeaderLines + 6, "unknown key 'colour'");
    // A key valid for other shape types is still unknown here.
    expectErrorAt(bodyError(R"(
[[shape]]
type = "rectangle"
material = "white"
radius = 1
)"),
                  kHeaderLines + 5, "unknown key 'radius'");
    expectErrorAt(parseError("[camera]\neye = [0, 0, 5]\ntarget = [0, 0, 0]\nfocus = 3\n"), 4, "unknown key 'focus'");
    expectErrorAt(parseError(std::string(kCamera) + "\n[integrator]\ntype = \"path\"\n"), 5, "unknown key 'integrator'");
    expectErrorAt(bodyError(R"(
[[material]]
name = "c"
type = "diffuse"
reflectance = { checkerboard = { even = 0.1, odd = 0.9, size = 3 } }
)"),
                  kHeaderLines + 5, "unknown key 'size'");
}

TEST(SceneToml, UnknownReferencesAreErrors) {
    expectErrorAt(bodyError(R"(
[[shape]]
type = "cube"
material = "chrome"
)"),
                  kHeaderLines + 4, "unknown material 'chrome'");
    expectErrorAt(bodyError(R"(
[[shape]]
type = "cube"
material = "white"
interior = "smoke"
)"),
                  kHeaderLines + 5, "unknown medium 'smoke'");
    expectErrorAt(parseError("[camera]\neye = [0, 0, 5]\ntarget = [0, 0, 0]\nmedium = \"fog\"\n"), 4, "unknown medium 'fog'");
    // twosided may only wrap a material defined above it.
    expectErrorAt(bodyError(R"(
[[material]]
name = "both"
type = "twosided"
inner = "later"

[[material]]
name = "later"
type = "diffuse"
)"),
                  kHeaderLines + 5, "unknown material 'later'");
}

TEST(SceneToml, NonsenseValuesAreErrors) {
    expectErrorAt(bodyError("\n[[shape]]\ntype = \"sphere\"\nmaterial = \"white\"\nradius = -1\n"), kHeaderLines + 5, "radius");
    expectErrorAt(parseError("[camera]\neye = [0, 0, 5]\ntarget = [0, 0, 0]\nfov = 180\n"), 4, "fov");
    expectErrorAt(parseError("[camera]\neye = [0, 0, 5]\ntarget = [0, 0, 0]\nfov = 0\n"), 4, "fov");
    expectErrorAt(parseError("[camera]\neye = [0, 0, 5]\ntarget = [0, 0, 5]\n"), 3, "target");
    expectErrorAt(parseError("[camera]\neye = [0, 0, 5]\ntarget = [0, 0, 0]\nup = [0, 0, 1]\n"), 4, "parallel");
    expectErrorAt(parseError("[camera]\neye = [0, 0, 5]\ntarget = [0, 0, 0]\nwidth = 0\n"), 4, "width");
    expectErrorAt(bodyError("\n[[medium]]\nname = \"m\"\nsigma_s = [0.1, -0.2, 0.1]\nsigma_a = 0\n"), kHeaderLines + 4,
                  "sigma_s");
    expectErrorAt(bodyError("\n[[medium]]\nname = \"m\"\nsigma_s = 1\nsigma_a = 0\ng = 1\n"), kHeaderLines + 6, "'g'");
    expectErrorAt(bodyError("\n[[material]]\nname = \"g\"\ntype = \"dielectric\"\nior = 0\n"), kHeaderLines + 5, "ior");
    expectErrorAt(bodyError("\n[[material]]\nname = \"g\"\ntype = \"dielectric\"\nior = \"unobtainium\"\n"), kHeaderLines + 5,
                  "unknown IOR preset");
    expectErrorAt(bodyError("\n[[material]]\nname = \"r\"\ntype = \"roughconductor\"\nalpha = -0.1\n"), kHeaderLines + 5,
                  "alpha");
    expectErrorAt(bodyError("\n[[material]]\nname = \"r\"\ntype = \"roughdielectric\"\nalpha = 0\n"), kHeaderLines + 5, "alpha");
    expectErrorAt(bodyError("\n[[material]]\nname = \"m\"\ntype = \"conductor\"\nmaterial = \"Mithril\"\n"), kHeaderLines + 5,
                  "unknown conductor");
    expectErrorAt(bodyError("\n[[material]]\nname = \"d\"\ntype = \"diffuse\"\nreflectance = 1.5\n"), kHeaderLines + 5,
                  "reflectance");
    expectErrorAt(bodyError("\n[[material]]\nname = \"white\"\ntype = \"diffuse\"\n"), kHeaderLines + 3, "defined twice");
    expectErrorAt(bodyError("\n[[material]]\nname = \"x\"\ntype = \"velvet\"\n"), kHeaderLines + 4, "unknown material type");
    expectErrorAt(bodyError("\n[[shape]]\ntype = \"cube\"\nmaterial = \"white\"\ntransform = [{ scale = 0 }]\n"),
                  kHeaderLines + 5, "scale");
    expectErrorAt(bodyError("\n[[shape]]\ntype = \"cube\"\nmaterial = \"white\"\nemission = [1, -1, 1]\n"), kHeaderLines + 5,
                  "emission");
    expectErrorAt(bodyError("\n[[shape]]\ntype = \"sphere\"\nmaterial = \"white\"\ntransform = [{ scale = 2 }]\n"),
                  kHeaderLines + 5, "transform");
    expectErrorAt(bodyError("\n[[light]]\ntype = \"spot\"\nposition = [0, 1, 0]\ntarget = [0, 0, 0]\nintensity = 1\n"
                            "cutoff_angle = 20\nbeam_width = 30\n"),
                  kHeaderLines + 8, "beam_width");
}

// The key picks the microfacet distribution: the material must evaluate like
// the one built directly with that distribution, and unlike the other one.
TEST(SceneToml, RoughMaterialsTakeADistribution) {
    const Scene scene = parse(R"(
[[material]]
name = "default"
type = "roughconductor"
material = "Au"
alpha = 0.3

[[material]]
name = "beckmann metal"
type = "roughconductor"
material = "Au"
alpha = 0.3
distribution = "beckmann"

[[material]]
name = "beckmann glass"
type = "roughdielectric"
ior = 1.5
alpha = 0.3
distribution = "beckmann"

[[material]]
name = "coated"
type = "roughplastic"
reflectance = [0.2, 0.4, 0.6]
ior = 1.5
alpha = 0.3
distribution = "beckmann"
nonlinear = true
specular_reflectance = 0.5

[[material]]
name = "ggx coated"
type = "roughplastic"
alpha = 0.3
)");
    ASSERT_EQ(scene.bsdfs.size(), 6u);
    const ConductorIor gold = *conductorPreset("Au");
    const Vec3 wo = glm::normalize(Vec3(0.3f, 0.1f, 0.9f)), wi = glm::normalize(Vec3(-0.5f, 0.2f, 0.6f));
    const Vec3 below(wi.x, wi.y, -wi.z);
    const auto value = [&](const Bsdf& b, const Vec3& to) { return b.eval(wo, to, Vec2(0.5f), TransportMode::Radiance); };
    const struct {
        std::shared_ptr<Bsdf> loaded, expected, other;
        Vec3 to;
    } cases[] = {
        {scene.bsdfs[1], makeRoughConductor(gold, 0.3f), makeRoughConductor(gold, 0.3f, Rgb(1.0f), MicrofacetType::Beckmann),
         wi},
        {scene.bsdfs[2], makeRoughConductor(gold, 0.3f, Rgb(1.0f), MicrofacetType::Beckmann), makeRoughConductor(gold, 0.3f),
         wi},
        {scene.bsdfs[3], makeRoughDielectric(1.5f, 0.3f, MicrofacetType::Beckmann), makeRoughDielectric(1.5f, 0.3f), below},
        {scene.bsdfs[4],
         makeRoughPlastic(makeConstantTexture(Rgb(0.2f, 0.4f, 0.6f)), 1.5f, 0.3f, MicrofacetType::Beckmann, true, Rgb(0.5f)),
         makeRoughPlastic(makeConstantTexture(Rgb(0.2f, 0.4f, 0.6f)), 1.5f, 0.3f, MicrofacetType::Ggx, true, Rgb(0.5f)), wi},
        {scene.bsdfs[5], makeRoughPlastic(makeConstantTexture(Rgb(0.5f)), 1.5f, 0.3f, MicrofacetType::Ggx),
         makeRoughPlastic(makeConstantTexture(Rgb(0.5f)), 1.5f, 0.3f, MicrofacetType::Beckmann), wi},
    };
    for (const auto& c : cases) {
        EXPECT_EQ(value(*c.loaded, c.to), value(*c.expected, c.to));
        EXPECT_NE(value(*c.loaded, c.to), value(*c.other, c.to));
    }
    expectErrorAt(bodyError("\n[[material]]\nname = \"r\"\ntype = \"roughconductor\"\ndistribution = \"phong\"\n"),
                  kHeaderLines + 5, "unknown distribution 'phong'");
    expectErrorAt(bodyError("\n[[material]]\nname = \"p\"\ntype = \"roughplastic\"\nalpha = -1\n"), kHeaderLines + 5,
                  "alpha");
    expectErrorAt(bodyError("\n[[material]]\nname = \"p\"\ntype = \"roughplastic\"\nspecular_reflectance = 2\n"),
                  kHeaderLines + 5, "specular_reflectance");
    expectErrorAt(bodyError("\n[[material]]\nname = \"p\"\ntype = \"plastic\"\ndistribution = \"ggx\"\n"),
                  kHeaderLines + 5, "distribution");
}

TEST(SceneToml, WrongTypesAndMissingKeysAreErrors) {
    expectErrorAt(parseError("[camera]\neye = [0, 0, 5]\ntarget = [0, 0, 0]\nfov = \"wide\"\n"), 4, "must be a number");
    expectErrorAt(parseError("[camera]\neye = [0, 0]\ntarget = [0, 0, 0]\n"), 2, "array of 3 numbers");
    expectErrorAt(parseError("[camera]\neye = [0, 0, 5]\ntarget = [0, 0, 0]\nwidth = 12.5\n"), 4, "integer");
    // A missing required key points at its table's header.
    expectErrorAt(bodyError("\n\n[[shape]]\nmaterial = \"white\"\n"), kHeaderLines + 3, "missing key 'type'");
    expectErrorAt(parseError("\n[camera]\ntarget = [0, 0, 0]\n"), 2, "missing key 'eye'");
    // A single table where an array of tables is expected.
    expectErrorAt(bodyError("\n[shape]\ntype = \"cube\"\nmaterial = \"white\"\n"), kHeaderLines + 2, "[[shape]]");
    const InputError noCamera = parseError(kWhite);
    EXPECT_NE(std::string(noCamera.what()).find("camera"), std::string::npos);
}

TEST(SceneToml, RelativeObjPathsResolveAgainstTheSceneFile) {
    const fs::path dir = scratchDir();
    writeFile(dir / "meshes" / "quad.obj",
              "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nf 1/1 2/2 3/3 4/4\n");
    const std::string body = std::string(kCamera) + kWhite + "\n[[shape]]\ntype = \"obj\"\nfile = \"meshes/quad.obj\"\nmaterial = \"white\"\n";
    fs::create_directories(dir / "scenes");
    writeFile(dir / "scene.toml", body);

    // Loaded from a file: resolved against the file's directory, whatever the working directory.
    const fs::path previous = fs::current_path();
    fs::current_path(dir / "scenes");
    Scene fromFile;
    EXPECT_NO_THROW(fromFile = loadTomlScene((dir / "scene.toml").string()));
    fs::current_path(previous);
    ASSERT_EQ(fromFile.shapes.size(), 1u);
    const auto& mesh = std::get<TriangleMesh>(fromFile.shapes[0].geometry);
    EXPECT_EQ(mesh.triangleCount(), 2u);
    EXPECT_EQ(mesh.uvs.size(), 4u);
    EXPECT_EQ(fromFile.shapes[0].name, "quad");

    // Parsed from text: resolved against the given base directory.
    EXPECT_NO_THROW(parseTomlScene(body, "text.toml", dir.string()));
    const InputError wrongBase = parseError(body, (dir / "scenes").string());
    expectErrorAt(wrongBase, kHeaderLines + 4, "not found");
}

TEST(SceneToml, MissingFilesAreErrors) {
    const fs::path dir = scratchDir();
    expectErrorAt(parseError(std::string(kCamera) + kWhite + "\n[[shape]]\ntype = \"obj\"\nfile = \"nowhere.obj\"\nmaterial = \"white\"\n",
                             dir.string()),
                  kHeaderLines + 4, "nowhere.obj");
    expectErrorAt(parseError(std::string(kCamera) + "\n[[material]]\nname = \"t\"\ntype = \"diffuse\"\nreflectance = { bitmap = \"none.png\" }\n",
                             dir.string()),
                  8, "none.png");
    expectErrorAt(parseError(std::string(kCamera) + "\n[[light]]\ntype = \"envmap\"\nfile = \"sky.exr\"\n", dir.string()), 7, "sky.exr");
    try {
        loadTomlScene((dir / "absent.toml").string());
        ADD_FAILURE() << "no error for a missing scene file";
    } catch (const InputError& e) {
        EXPECT_NE(std::string(e.what()).find("absent.toml"), std::string::npos);
    }
    // A file that exists but is not a valid OBJ: the message names both files.
    writeFile(dir / "broken.obj", "v 0 0 0\nv 1 0 0\nf 1 2 7\n");
    const InputError broken =
        parseError(std::string(kCamera) + kWhite + "\n[[shape]]\ntype = \"obj\"\nfile = \"broken.obj\"\nmaterial = \"white\"\n", dir.string());
    expectErrorAt(broken, kHeaderLines + 4, "broken.obj");
}

TEST(ObjLoader, ReindexesDistinctCornersAndTriangulates) {
    const fs::path dir = scratchDir();
    // Two quads sharing an edge by position, but with different normals and uvs on each side.
    writeFile(dir / "fold.obj",
              "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 1 0 -1\nv 1 1 -1\n"
              "vn 0 0 1\nvn 1 0 0\n"
              "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
              "g first\nf 1/1/1 2/2/1 3/3/1 4/4/1\n"
              "g second\nf 2/1/2 5/2/2 6/3/2 3/4/2\n");
    const TriangleMesh mesh = loadObjMesh((dir / "fold.obj").string());
    EXPECT_EQ(mesh.triangleCount(), 4u);
    // 8 distinct (position, normal, uv) triples although there are only 6 positions.
    EXPECT_EQ(mesh.positions.size(), 8u);
    ASSERT_EQ(mesh.normals.size(), 8u);
    ASSERT_EQ(mesh.uvs.size(), 8u);
    for (std::size_t t = 0; t < mesh.triangleCount(); ++t) {
        const Vec3& a = mesh.positions[mesh.indices[3 * t]];
        const Vec3& b = mesh.positions[mesh.indices[3 * t + 1]];
        const Vec3& c = mesh.positions[mesh.indices[3 * t + 2]];
        const Vec3 faceNormal = glm::normalize(glm::cross(b - a, c - a));
        // Winding preserved: each face's geometric normal matches its vertex normals.
        for (int k = 0; k < 3; ++k) EXPECT_GT(glm::dot(faceNormal, mesh.normals[mesh.indices[3 * t + k]]), 0.999f);
    }
    EXPECT_NEAR(mesh.area(), 2.0f, 1e-6f);

    // A shared corner with identical attributes is stored once.
    writeFile(dir / "strip.obj", "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3\nf 1 3 4\n");
    const TriangleMesh strip = loadObjMesh((dir / "strip.obj").string());
    EXPECT_EQ(strip.positions.size(), 4u);
    EXPECT_TRUE(strip.normals.empty());
    EXPECT_TRUE(strip.uvs.empty());

    // Normals on only some corners are dropped rather than half-used.
    writeFile(dir / "mixed.obj", "v 0 0 0\nv 1 0 0\nv 1 1 0\nvn 0 0 1\nf 1//1 2//1 3\n");
    EXPECT_TRUE(loadObjMesh((dir / "mixed.obj").string()).normals.empty());
}

TEST(ObjLoader, ErrorsNameTheFile) {
    const fs::path dir = scratchDir();
    const std::string missing = (dir / "missing.obj").string();
    try {
        loadObjMesh(missing);
        ADD_FAILURE();
    } catch (const InputError& e) {
        EXPECT_EQ(e.file(), missing);
    }
    writeFile(dir / "empty.obj", "# nothing\nv 0 0 0\n");
    try {
        loadObjMesh((dir / "empty.obj").string());
        ADD_FAILURE();
    } catch (const InputError& e) {
        EXPECT_NE(std::string(e.what()).find("empty.obj"), std::string::npos);
    }
}

// Loads dir/name holding `text` through loadScene; returns the error message, or "" if it loaded.
std::string loadSceneError(const fs::path& dir, const std::string& name, const std::string& text) {
    writeFile(dir / name, text);
    try {
        loadScene((dir / name).string());
    } catch (const InputError& e) {
        return e.what();
    }
    return "";
}

TEST(SceneExtent, CoordinatesBeyondRepresentableRangeAreErrors) {
    const fs::path dir = scratchDir();
    const std::string path = (dir / "scene.toml").string();
    const auto expectRejected = [&](const std::string& text, const std::string& fragment) {
        const std::string message = loadSceneError(dir, "scene.toml", text);
        EXPECT_NE(message.find(path + ": " + fragment), std::string::npos) << message;
        EXPECT_NE(message.find("beyond 1e10"), std::string::npos) << message;
    };
    expectRejected("[camera]\neye = [2e18, 0, 0]\ntarget = [0, 0, 0]\n", "camera position");
    expectRejected("[camera]\neye = [0, 0, 5]\ntarget = [0, 0, -3e12]\n", "camera target");
    expectRejected(std::string(kCamera) + "\n[[light]]\ntype = \"point\"\nposition = [0, -2e18, 0]\nintensity = 1\n",
                   "light position");
    expectRejected(std::string(kCamera) + kWhite + "\n[[shape]]\ntype = \"sphere\"\nmaterial = \"white\"\nradius = 1e11\n",
                   "shape");
    writeFile(dir / "far.obj", "v 0 0 0\nv 1e12 0 0\nv 0 1 0\nf 1 2 3\n");
    expectRejected(std::string(kCamera) + kWhite + "\n[[shape]]\ntype = \"obj\"\nfile = \"far.obj\"\nmaterial = \"white\"\n",
                   "shape 'far' vertex");
    // Large but representable scenes still load.
    EXPECT_EQ(loadSceneError(dir, "big.toml", "[camera]\neye = [1e9, 0, 0]\ntarget = [0, 0, 0]\n"), "");
}

TEST(ObjLoader, NonFiniteVerticesAreErrors) {
    const fs::path dir = scratchDir();
    for (const std::string value : {"nan", "inf", "-inf", "1e400", "zero"}) {
        const fs::path path = dir / (value + ".obj");
        writeFile(path, "v 0 0 0\nv 1 0 0\nv " + value + " 0 0\nf 1 2 3\n");
        try {
            loadObjMesh(path.string());
            ADD_FAILURE() << "no error for a vertex at " << value;
        } catch (const InputError& e) {
            EXPECT_NE(std::string(e.what()).find(path.string() + ":3: vertex 3 has a coordinate '" + value + "' that is not a finite number"),
                      std::string::npos)
                << e.what();
        }
    }
}

// ---- Scene::finalize --------------------------------------------------------

class FixedPowerLight final : public Light {
public:
    FixedPowerLight(const Rgb& power, bool infinite) : power_(power), infinite_(infinite) {}
    bool isDelta() const override { return false; }
    bool isInfinite() const override { return infinite_; }
    std::optional<LightSample> sampleLi(const Vec3&, const Vec2&) const override { return std::nullopt; }
    float pdfLi(const Vec3&, const Vec3&, const Vec3&, const Vec3&) const override { return 0.0f; }
    Rgb emitted(const Vec3&, const Vec3&) const override { return Rgb(0.0f); }
    Rgb environment(const Vec3&) const override { return Rgb(0.0f); }
    // Infinite lights' power grows with the scene, as a real environment's does.
    Rgb power() const override { return infinite_ ? power_ * sceneRadius * sceneRadius : power_; }
    std::optional<EmissionSample> sampleEmission(const Vec2&, const Vec2&) const override { return std::nullopt; }
    void setSceneBounds(const Vec3& center, float radius) override {
        sceneCenter = center;
        sceneRadius = radius;
    }
    Vec3 sceneCenter{-1.0f};
    float sceneRadius = -1.0f;

private:
    Rgb power_;
    bool infinite_;
};

TEST(Scene, FinalizeComputesBoundsAndLightPower) {
    Scene scene;
    TriangleMesh quad = makeRectangleMesh();  // [-1, 1]^2 at z = 0
    Shape mesh;
    mesh.geometry = quad;
    scene.shapes.push_back(mesh);
    Shape ball;
    ball.geometry = Sphere{Vec3(3, 0, 0), 1.0f};
    scene.shapes.push_back(ball);
    auto a = std::make_shared<FixedPowerLight>(Rgb(1.0f), false);
    auto b = std::make_shared<FixedPowerLight>(Rgb(3.0f), false);
    auto env = std::make_shared<FixedPowerLight>(Rgb(0.25f), true);
    scene.lights = {a, env, b};
    scene.lightShape = {-1, -1, -1};
    scene.finalize();

    EXPECT_EQ(scene.boundsMin, Vec3(-1, -1, -1));
    EXPECT_EQ(scene.boundsMax, Vec3(4, 1, 1));
    const Vec3 center(1.5f, 0, 0);
    const float radius = glm::length(Vec3(2.5f, 1, 1));
    for (const auto& light : {a, b, env}) {
        EXPECT_EQ(light->sceneCenter, center);
        EXPECT_FLOAT_EQ(light->sceneRadius, radius);
    }
    ASSERT_EQ(scene.lightPower.size(), 3u);
    const float envPower = 0.25f * radius * radius;
    const float total = 1.0f + 3.0f + envPower;
    EXPECT_NEAR(scene.lightPower.discretePmf(0), 1.0f / total, 1e-6f);
    EXPECT_NEAR(scene.lightPower.discretePmf(1), envPower / total, 1e-6f);
    EXPECT_NEAR(scene.lightPower.discretePmf(2), 3.0f / total, 1e-6f);
    EXPECT_EQ(scene.infiniteLights(), std::vector<int>{1});
}

TEST(Scene, FinalizeWithoutLightsOrShapes) {
    Scene scene;
    scene.finalize();
    EXPECT_EQ(scene.lightPower.size(), 0u);
    EXPECT_EQ(scene.boundsMin, Vec3(0.0f));
    EXPECT_EQ(scene.boundsMax, Vec3(0.0f));
    EXPECT_TRUE(scene.infiniteLights().empty());
}

}  // namespace
}  // namespace fg
