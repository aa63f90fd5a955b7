// Mitsuba XML import: the real Cornell box files, every structural feature
// (defaults, $substitution, defines, include, path, ref, transforms), the
// plugins, and the error contract (file:LINE and the plugin named).
#include "engine/scene/scene_xml.h"

#include "engine/core/error.h"
#include "engine/image/image_io.h"
#include "engine/core/job.h"
#include "engine/core/render.h"
#include "engine/scene/scene_loader.h"
#include "engine/scene/scene_toml.h"
#include "engine/scene/spectrum.h"
#include "tests/support/render_helpers.h"
#include "tests/support/cli_helpers.h"
#include "tests/support/scene_text.h"

#include <glm/gtc/matrix_transform.hpp>
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <string>

namespace fg {
namespace {

namespace fs = std::filesystem;
using test::lineOf;

const fs::path kCboxDir = fs::path(FLUXGRAPH_SOURCE_DIR) / ".." / "shared" / "scenes" / "mitsuba-cbox";
const std::string kTomlCornellBox = std::string(FLUXGRAPH_SOURCE_DIR) + "/data/cornell-box/cornell-box.toml";

#define SKIP_WITHOUT_CBOX()                                                                                 \
    if (!fs::exists(kCboxDir / "cbox.xml")) {                                                              \
        GTEST_SKIP() << "Mitsuba's Cornell box is not available at " << kCboxDir.string()                  \
                     << " (the shared scenes checkout next to the repository)";                            \
    }

fs::path scratchDir() { return test::scratchDirectory("scene_xml"); }

fs::path writeFile(const fs::path& path, const std::string& text) {
    test::writeText(path, text);
    return path;
}

bool contains(const std::string& text, const std::string& part) { return text.find(part) != std::string::npos; }

const char* kQuadObj = "v -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nf 1/1 2/2 3/3 4/4\n";

InputError loadError(const fs::path& path, const std::map<std::string, std::string>& defines = {}) {
    try {
        loadXmlScene(path.string(), defines);
    } catch (const InputError& e) {
        return e;
    }
    ADD_FAILURE() << "no InputError for " << path;
    return InputError("no error");
}

// Loads `text` written to dir/name, expecting an error at the line holding `marker`
// that names `plugin`; returns the message.
std::string expectErrorAt(const fs::path& dir, const std::string& text, const std::string& marker,
                          const std::string& plugin, const std::string& name = "scene.xml") {
    const fs::path path = writeFile(dir / name, text);
    const std::string message = loadError(path).what();
    const std::string location = path.string() + ":" + std::to_string(lineOf(text, marker)) + ":";
    EXPECT_TRUE(contains(message, location)) << "expected " << location << " in: " << message;
    EXPECT_TRUE(contains(message, plugin)) << "expected " << plugin << " in: " << message;
    return message;
}

// Diffuse reflectance of a shape's material (eval of a Lambertian at normal incidence is R / pi).
Rgb diffuseAlbedo(const Scene& scene, std::size_t shape, const Vec2& uv = Vec2(0.5f)) {
    const Bsdf& bsdf = *scene.bsdfs[static_cast<std::size_t>(scene.shapes[shape].bsdf)];
    return kPi * bsdf.eval(Vec3(0, 0, 1), Vec3(0, 0, 1), uv, TransportMode::Radiance);
}

void expectNear(const Vec3& a, const Vec3& b, float tolerance, const std::string& what = "") {
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(a[c], b[c], tolerance) << what << " component " << c;
}

// ---- the real Cornell box -----------------------------------------------------------

TEST(SceneXml, MitsubaCornellBoxFilesLoad) {
    SKIP_WITHOUT_CBOX();
    struct Case {
        const char* file;
        int spp;
        std::optional<FilterKind> filter;
        bool spectral;
    };
    const Case cases[] = {{"cbox.xml", 128, FilterKind::Gaussian, true},
                          {"cbox-spectral.xml", 256, FilterKind::Box, true},
                          {"cbox-rgb.xml", 256, FilterKind::Box, false}};
    for (const Case& c : cases) {
        SCOPED_TRACE(c.file);
        const Scene scene = loadXmlScene((kCboxDir / c.file).string());
        ASSERT_EQ(scene.shapes.size(), 8u);
        ASSERT_EQ(scene.lights.size(), 1u);
        EXPECT_EQ(scene.lightShape[0], 0);
        EXPECT_EQ(scene.shapes[0].areaLight, 0);
        EXPECT_EQ(scene.shapes[0].name, "cbox_luminaire");
        expectNear(scene.camera.eye, Vec3(278, 273, -800), 1e-3f, "eye");
        expectNear(glm::normalize(scene.camera.target - scene.camera.eye), Vec3(0, 0, 1), 1e-6f, "view direction");
        expectNear(scene.camera.up, Vec3(0, 1, 0), 1e-6f, "up");
        EXPECT_NEAR(scene.camera.fovYDegrees, 39.3077f, 1e-3f);
        EXPECT_EQ(scene.camera.width, 256);
        EXPECT_EQ(scene.camera.height, 256);
        EXPECT_FALSE(scene.camera.mirrored);
        EXPECT_NEAR(scene.camera.nearClip, 10.0f, 1e-6f);
        EXPECT_NEAR(scene.camera.farClip, 2800.0f, 1e-3f);
        EXPECT_EQ(scene.hints.samplesPerPixel, c.spp);
        EXPECT_EQ(scene.hints.maxDepth, 5);  // Mitsuba's 6 path vertices: 5 scattering events
        EXPECT_EQ(scene.hints.filter, c.filter);
        // The luminaire sits 0.5 below the ceiling (y = 548.8).
        const auto& luminaire = std::get<TriangleMesh>(scene.shapes[0].geometry);
        for (const Vec3& p : luminaire.positions) EXPECT_NEAR(p.y, 548.3f, 1e-3f);
        // The red wall (shape 5) and its reflectance.
        const Rgb red = diffuseAlbedo(scene, 5);
        if (c.spectral) {
            // The measured spectrum converted here; Mitsuba's RGB for it, unadapted, is checked in test_spectrum.
            EXPECT_GT(red.x, 0.4f);
            EXPECT_LT(red.y, 0.06f);
            EXPECT_LT(red.z, 0.06f);
        } else {
            expectNear(red, Rgb(0.570068f, 0.0430135f, 0.0443706f), 1e-6f, "red wall");
        }
        // The emitter: Mitsuba's RGB radiance, or the spectrum converted.
        const Rgb radiance = scene.lights[0]->emitted(Vec3(0, -1, 0), Vec3(0, -1, 0));
        if (c.spectral) {
            const SpectrumSample light[] = {{400, 0}, {500, 8}, {600, 15.6f}, {700, 18.4f}};
            expectNear(radiance, emissionSpectrumToRgb(light), 1e-4f, "radiance");
        } else {
            expectNear(radiance, Rgb(18.387f, 10.9873f, 2.75357f), 1e-4f, "radiance");
        }
    }
}

TEST(SceneXml, DefinesOverrideDefaults) {
    SKIP_WITHOUT_CBOX();
    const std::string path = (kCboxDir / "cbox.xml").string();
    const Scene scene = loadXmlScene(path, {{"spp", "16"}, {"res", "48"}});
    EXPECT_EQ(scene.hints.samplesPerPixel, 16);
    EXPECT_EQ(scene.camera.width, 48);
    EXPECT_EQ(scene.camera.height, 48);
    EXPECT_EQ(scene.hints.maxDepth, 5);  // its default (Mitsuba's 6) stays
    // Through the generic loader too.
    EXPECT_EQ(loadScene(path, {{"max_depth", "3"}}).hints.maxDepth, 2);
    // A define the scene does not know is a typo, not something to ignore.
    const std::string message = loadError(path, {{"sample_count", "4"}}).what();
    EXPECT_TRUE(contains(message, "sample_count")) << message;
    EXPECT_TRUE(contains(message, path)) << message;
    // A define that does not parse where it is substituted is reported where it is used.
    const std::string bad = loadError(path, {{"spp", "many"}}).what();
    EXPECT_TRUE(contains(bad, "sampler 'independent'")) << bad;
    EXPECT_TRUE(contains(bad, "'many'")) << bad;
    // TOML scenes have no parameters.
    EXPECT_THROW(loadScene(kTomlCornellBox, {{"spp", "4"}}), InputError);
}

// The same box from XML and from the TOML transcription, rendered with the
// path tracer: every wall region must agree, and the red wall must be on the left.
TEST(SceneXml, CornellBoxRendersLikeTheTomlBox) {
    SKIP_WITHOUT_CBOX();
    const Scene xml = loadXmlScene((kCboxDir / "cbox-rgb.xml").string());
    const Scene toml = loadTomlScene(kTomlCornellBox);
    FilmSettings film;
    film.width = 64;
    film.height = 64;
    const std::map<std::string, ParamValue> params = {{"pt.spp", std::int64_t{48}}, {"pt.max_depth", std::int64_t{6}}};
    // Different seeds: the comparison is statistical, not a replay of the same paths.
    const test::RenderedImage a = test::renderPipeline(xml, "pt", params, film, 11);
    const test::RenderedImage b = test::renderPipeline(toml, "pt", params, film, 12);

    Camera camera = toml.camera;
    camera.width = film.width;
    camera.height = film.height;
    struct Region {
        const char* name;
        Vec3 point;  // a point on the wall, clear of the boxes and the light
    };
    const Region regions[] = {{"red wall", {548, 300, 300}},   {"green wall", {1, 300, 300}},
                              {"back wall", {150, 420, 558}},  {"floor", {450, 1, 100}},
                              {"ceiling", {130, 547, 130}}};
    for (const Region& r : regions) {
        Vec2 raster;
        ASSERT_TRUE(camera.project(r.point, &raster)) << r.name;
        const int cx = static_cast<int>(raster.x), cy = static_cast<int>(raster.y);
        Rgb meanA(0.0f), meanB(0.0f);
        int count = 0;
        for (int y = cy - 3; y <= cy + 3; ++y) {
            for (int x = cx - 3; x <= cx + 3; ++x) {
                ASSERT_TRUE(x >= 0 && y >= 0 && x < film.width && y < film.height) << r.name;
                meanA += a.at(x, y);
                meanB += b.at(x, y);
                ++count;
            }
        }
        meanA /= static_cast<float>(count);
        meanB /= static_cast<float>(count);
        for (int c = 0; c < 3; ++c) {
            EXPECT_NEAR(meanA[c], meanB[c], 0.05f * maxComponent(meanB)) << r.name << " channel " << c;
        }
        EXPECT_GT(luminance(meanA), 0.01f) << r.name << " is lit";
        if (std::string(r.name) == "red wall") {
            EXPECT_LT(cx, film.width / 2) << "the red wall is on the left";
            EXPECT_GT(meanA.x, 3.0f * meanA.y) << "and red in the XML render";
        }
        if (std::string(r.name) == "green wall") {
            EXPECT_GT(cx, film.width / 2) << "the green wall is on the right";
            EXPECT_GT(meanA.y, 1.5f * meanA.x) << "and green in the XML render";
        }
    }
}

// ---- structure ----------------------------------------------------------------------

TEST(SceneXml, DefaultsSubstitutionAndDefines) {
    const fs::path dir = scratchDir();
    writeFile(dir / "meshes" / "quad.obj", kQuadObj);
    const std::string text = test::mitsubaSceneText(R"(
    <default name="albedo" value="0.25"/>
    <default name="mesh" value="quad"/>
    <default name="dir" value="meshes"/>
    <shape type="obj">
        <string name="filename" value="$dir/$mesh.obj"/>
        <bsdf type="diffuse"><rgb name="reflectance" value="$albedo, 0.5, $albedo"/></bsdf>
    </shape>
)");
    const fs::path path = writeFile(dir / "scene.xml", text);
    const Scene scene = loadXmlScene(path.string());
    expectNear(diffuseAlbedo(scene, 0), Rgb(0.25f, 0.5f, 0.25f), 1e-6f);
    EXPECT_EQ(scene.shapes[0].name, "quad");

    // A define wins over the default, wherever the parameter is used.
    const Scene overridden = loadXmlScene(path.string(), {{"albedo", "0.75"}});
    expectNear(diffuseAlbedo(overridden, 0), Rgb(0.75f, 0.5f, 0.75f), 1e-6f);

    // An undeclared parameter is an error at the element that uses it.
    const std::string undeclared = test::mitsubaSceneText("    <shape type=\"rectangle\"><float name=\"x\" value=\"$nope\"/></shape>\n");
    const std::string message = expectErrorAt(dir, undeclared, "$nope", "$nope", "undeclared.xml");
    EXPECT_TRUE(contains(message, "undefined parameter")) << message;
}

TEST(SceneXml, IncludesArePathsRelativeToTheIncludingFile) {
    const fs::path dir = scratchDir();
    writeFile(dir / "parts" / "materials.xml", R"(<scene version="3.0.0">
    <bsdf type="diffuse" id="grey"><rgb name="reflectance" value="0.3"/></bsdf>
    <include filename="more/shapes.xml"/>
</scene>
)");
    writeFile(dir / "parts" / "more" / "shapes.xml", R"(<scene version="3.0.0">
    <shape type="rectangle" id="floor"><ref id="grey"/></shape>
</scene>
)");
    const fs::path path = writeFile(dir / "scene.xml", test::mitsubaSceneText("    <include filename=\"parts/materials.xml\"/>\n"));
    const Scene scene = loadXmlScene(path.string());
    ASSERT_EQ(scene.shapes.size(), 1u);
    EXPECT_EQ(scene.shapes[0].name, "floor");
    expectNear(diffuseAlbedo(scene, 0), Rgb(0.3f), 1e-6f);

    // A cycle is reported at the include that closes it.
    writeFile(dir / "a.xml", "<scene version=\"3.0.0\">\n    <include filename=\"b.xml\"/>\n</scene>\n");
    const std::string b = "<scene version=\"3.0.0\">\n\n    <include filename=\"a.xml\"/>\n</scene>\n";
    writeFile(dir / "b.xml", b);
    const fs::path cyclic = writeFile(dir / "cyclic.xml", test::mitsubaSceneText("    <include filename=\"a.xml\"/>\n"));
    const std::string message = loadError(cyclic).what();
    EXPECT_TRUE(contains(message, (dir / "b.xml").string() + ":3:")) << message;
    EXPECT_TRUE(contains(message, "cycle")) << message;

    // A missing include names the including file and line.
    const std::string missing = test::mitsubaSceneText("    <include filename=\"nowhere.xml\"/>\n");
    const std::string m2 = expectErrorAt(dir, missing, "nowhere.xml", "nowhere.xml", "missing.xml");
    EXPECT_TRUE(contains(m2, "not found")) << m2;

    // Errors inside an included file name that file.
    writeFile(dir / "broken.xml", "<scene version=\"3.0.0\">\n    <bsdf type=\"velvet\" id=\"v\"/>\n</scene>\n");
    const std::string m3 = loadError(writeFile(dir / "uses-broken.xml", test::mitsubaSceneText("    <include filename=\"broken.xml\"/>\n"))).what();
    EXPECT_TRUE(contains(m3, (dir / "broken.xml").string() + ":2:")) << m3;
    EXPECT_TRUE(contains(m3, "bsdf 'velvet'")) << m3;
}

TEST(SceneXml, DeepNestingIsAnErrorNotAStackOverflow) {
    const fs::path dir = scratchDir();
    // Each element on its own line, so the element past the bound is on line 2 + bound.
    const auto nested = [](int depth) {
        std::string open, close;
        for (int i = 0; i < depth; ++i) {
            open += "<shape type=\"rectangle\">\n";
            close += "</shape>\n";
        }
        return open + close;
    };
    for (const int depth : {257, 9000}) {
        const fs::path path = writeFile(dir / ("deep" + std::to_string(depth) + ".xml"),
                                        "<scene version=\"3.0.0\">\n" + nested(depth) + "</scene>\n");
        const std::string message = loadError(path).what();
        EXPECT_TRUE(contains(message, path.string() + ":258: elements nested more than 256 deep")) << message;
    }
    // The depth counts through includes: 200 levels around an include of 100 more.
    writeFile(dir / "inner.xml", "<scene version=\"3.0.0\">\n" + nested(100) + "</scene>\n");
    std::string open, close;
    for (int i = 0; i < 200; ++i) {
        open += "<shape type=\"rectangle\">\n";
        close += "</shape>\n";
    }
    const fs::path outer = writeFile(dir / "outer.xml", "<scene version=\"3.0.0\">\n" + open +
                                                            "<include filename=\"inner.xml\"/>\n" + close + "</scene>\n");
    const std::string message = loadError(outer).what();
    EXPECT_TRUE(contains(message, (dir / "inner.xml").string() + ":58: elements nested more than 256 deep")) << message;
}

TEST(SceneXml, IncludeChainsAreBounded) {
    const fs::path dir = scratchDir();
    const int files = 40;
    for (int i = 0; i < files; ++i) {
        const std::string next = i + 1 < files ? "    <include filename=\"part" + std::to_string(i + 1) + ".xml\"/>\n" : "";
        writeFile(dir / ("part" + std::to_string(i) + ".xml"), "<scene version=\"3.0.0\">\n" + next + "</scene>\n");
    }
    const fs::path path = writeFile(dir / "scene.xml", test::mitsubaSceneText("    <include filename=\"part0.xml\"/>\n"));
    const std::string message = loadError(path).what();
    EXPECT_TRUE(contains(message, (dir / "part31.xml").string() + ":2: includes nested more than 32 deep")) << message;
}

TEST(SceneXml, PathElementsAddSearchDirectories) {
    const fs::path dir = scratchDir();
    writeFile(dir / "assets" / "geometry" / "quad.obj", kQuadObj);
    const std::string text = test::mitsubaSceneText(R"(    <path value="assets/geometry"/>
    <shape type="obj"><string name="filename" value="quad.obj"/></shape>
)");
    const Scene scene = loadXmlScene(writeFile(dir / "scene.xml", text).string());
    ASSERT_EQ(scene.shapes.size(), 1u);
    EXPECT_NEAR(scene.shapes[0].area(), 4.0f, 1e-5f);
    // Without the path the file is not found.
    const std::string without = test::mitsubaSceneText("    <shape type=\"obj\"><string name=\"filename\" value=\"quad.obj\"/></shape>\n");
    const std::string message = expectErrorAt(dir, without, "quad.obj", "shape 'obj'", "without.xml");
    EXPECT_TRUE(contains(message, "file not found")) << message;
}

TEST(SceneXml, ReferencesShareObjectsAndMayPointForward) {
    const fs::path dir = scratchDir();
    const std::string text = test::mitsubaSceneText(R"(
    <shape type="rectangle"><ref id="glass"/><ref name="interior" id="fog"/><ref name="exterior" id="air"/></shape>
    <shape type="cube"><ref id="glass"/><ref id="light"/></shape>
    <shape type="disk"><bsdf type="twosided"><ref id="matte"/></bsdf><ref id="light"/></shape>
    <bsdf type="dielectric" id="glass"><string name="int_ior" value="water"/><string name="ext_ior" value="air"/></bsdf>
    <bsdf type="diffuse" id="matte"><ref name="reflectance" id="checks"/></bsdf>
    <texture type="checkerboard" id="checks"><rgb name="color0" value="0.8"/><rgb name="color1" value="0.1"/></texture>
    <medium type="homogeneous" id="fog"><rgb name="sigma_t" value="2"/><float name="albedo" value="0.5"/></medium>
    <medium type="homogeneous" id="air"><float name="sigma_t" value="0.1"/></medium>
    <emitter type="area" id="light"><rgb name="radiance" value="3, 2, 1"/></emitter>
)");
    const Scene scene = loadXmlScene(writeFile(dir / "scene.xml", text).string());
    ASSERT_EQ(scene.shapes.size(), 3u);
    EXPECT_EQ(scene.shapes[0].bsdf, scene.shapes[1].bsdf) << "one bsdf, referenced twice";
    EXPECT_EQ(scene.bsdfs.size(), 3u);  // glass, matte, twosided
    EXPECT_EQ(scene.media.size(), 2u);
    ASSERT_GE(scene.shapes[0].interiorMedium, 0);
    ASSERT_GE(scene.shapes[0].exteriorMedium, 0);
    const HomogeneousMedium& fog = scene.media[static_cast<std::size_t>(scene.shapes[0].interiorMedium)];
    expectNear(fog.sigmaS(), Rgb(1.0f), 1e-6f, "fog sigma_s");
    expectNear(fog.sigmaA(), Rgb(1.0f), 1e-6f, "fog sigma_a");
    const HomogeneousMedium& air = scene.media[static_cast<std::size_t>(scene.shapes[0].exteriorMedium)];
    expectNear(air.sigmaS(), Rgb(0.075f), 1e-6f, "Mitsuba's default albedo 0.75");
    EXPECT_NEAR(air.phase().g(), 0.0f, 0.0f);
    // The area emitter referenced by two shapes lights both.
    EXPECT_EQ(scene.lights.size(), 2u);
    EXPECT_EQ(scene.lightShape, (std::vector<int>{1, 2}));
    expectNear(scene.lights[0]->emitted(Vec3(0, 0, 1), Vec3(0, 0, 1)), Rgb(3, 2, 1), 1e-6f);
    // Water in air: a dielectric with eta = 1.333 / 1.000277 reflects (eta-1)^2/(eta+1)^2 at normal incidence.
    const Bsdf& glass = *scene.bsdfs[static_cast<std::size_t>(scene.shapes[0].bsdf)];
    const auto s = glass.sample(Vec3(0, 0, 1), Vec2(0.5f), 0.0f, Vec2(0.5f), TransportMode::Radiance);
    ASSERT_TRUE(s.has_value());
    const float eta = 1.333f / 1.000277f;
    EXPECT_NEAR(s->pdf, sqr((eta - 1) / (eta + 1)), 1e-4f);
    // The textured, two-sided disk: checker colours on both sides.
    const Rgb front = diffuseAlbedo(scene, 2, Vec2(0.1f, 0.1f));
    EXPECT_NEAR(front.x, 0.8f, 1e-6f);
    const Bsdf& disk = *scene.bsdfs[static_cast<std::size_t>(scene.shapes[2].bsdf)];
    EXPECT_NEAR(kPi * disk.eval(Vec3(0, 0, -1), Vec3(0, 0, -1), Vec2(0.7f, 0.1f), TransportMode::Radiance).x, 0.1f, 1e-6f);
}

Vec3 transformedRectangleCorner(const std::string& steps, const Vec3& corner) {
    const fs::path dir = scratchDir();
    const std::string text = test::mitsubaSceneText("    <shape type=\"rectangle\"><transform name=\"to_world\">" + steps +
                                       "</transform></shape>\n");
    const Scene scene = loadXmlScene(writeFile(dir / "t.xml", text).string());
    const auto& mesh = std::get<TriangleMesh>(scene.shapes[0].geometry);
    const TriangleMesh reference = makeRectangleMesh();
    for (std::size_t i = 0; i < reference.positions.size(); ++i) {
        if (reference.positions[i] == corner) return mesh.positions[i];
    }
    ADD_FAILURE() << "no such corner";
    return Vec3(0.0f);
}

TEST(SceneXml, TransformsMatchTheirMatrices) {
    const Vec3 corner(1, -1, 0);
    auto check = [&](const std::string& steps, const Mat4& expected) {
        const Vec3 got = transformedRectangleCorner(steps, corner);
        expectNear(got, Vec3(expected * Vec4(corner, 1.0f)), 1e-5f, steps);
    };
    check("<translate x=\"1\" z=\"3\"/>", glm::translate(Mat4(1.0f), Vec3(1, 0, 3)));
    check("<translate value=\"1, 2, 3\"/>", glm::translate(Mat4(1.0f), Vec3(1, 2, 3)));
    check("<translate value=\"1 2 3\"/>", glm::translate(Mat4(1.0f), Vec3(1, 2, 3)));
    check("<scale value=\"2\"/>", glm::scale(Mat4(1.0f), Vec3(2)));
    check("<scale value=\"2, 3, 4\"/>", glm::scale(Mat4(1.0f), Vec3(2, 3, 4)));
    check("<scale y=\"5\"/>", glm::scale(Mat4(1.0f), Vec3(1, 5, 1)));
    check("<rotate y=\"1\" angle=\"90\"/>", glm::rotate(Mat4(1.0f), glm::radians(90.0f), Vec3(0, 1, 0)));
    check("<rotate value=\"1, 1, 0\" angle=\"30\"/>", glm::rotate(Mat4(1.0f), glm::radians(30.0f), glm::normalize(Vec3(1, 1, 0))));
    Mat4 m(1.0f);
    m[0] = Vec4(0, 1, 0, 0);  // columns: x -> y, y -> -x
    m[1] = Vec4(-1, 0, 0, 0);
    m[3] = Vec4(5, 6, 7, 1);
    check("<matrix value=\"0 -1 0 5  1 0 0 6  0 0 1 7  0 0 0 1\"/>", m);
    // Steps apply in the order written: first scale, then translate.
    check("<scale value=\"2\"/><translate x=\"1\"/>",
          glm::translate(Mat4(1.0f), Vec3(1, 0, 0)) * glm::scale(Mat4(1.0f), Vec3(2)));
    // lookat: +z towards the target, +x = up x direction.
    Mat4 look(1.0f);
    look[0] = Vec4(-1, 0, 0, 0);
    look[1] = Vec4(0, 1, 0, 0);
    look[2] = Vec4(0, 0, -1, 0);
    look[3] = Vec4(1, 2, 3, 1);
    check("<lookat origin=\"1, 2, 3\" target=\"1, 2, 0\" up=\"0, 1, 0\"/>", look);
}

// ---- sensor -------------------------------------------------------------------------

Scene sceneWithSensor(const std::string& sensorBody, int width, int height, const std::string& version = "3.0.0") {
    const fs::path dir = scratchDir();
    const std::string text = "<scene version=\"" + version + "\">\n<sensor type=\"perspective\">\n" + sensorBody +
                             "<film type=\"hdrfilm\"><integer name=\"width\" value=\"" + std::to_string(width) +
                             "\"/><integer name=\"height\" value=\"" + std::to_string(height) + "\"/></film>\n</sensor>\n</scene>\n";
    return loadXmlScene(writeFile(dir / "sensor.xml", text).string());
}

float verticalFov(float fovDeg, float axisPixels, float heightPixels) {
    return 2.0f * std::atan(std::tan(glm::radians(fovDeg) / 2.0f) * heightPixels / axisPixels) * 180.0f / kPi;
}

TEST(SceneXml, FieldOfViewAxesBecomeTheVerticalAngle) {
    const float w = 200, h = 100;
    EXPECT_NEAR(sceneWithSensor("<float name=\"fov\" value=\"60\"/>", 200, 100).camera.fovYDegrees, verticalFov(60, w, h), 1e-4f)
        << "Mitsuba's default axis is x";
    EXPECT_NEAR(sceneWithSensor("<float name=\"fov\" value=\"60\"/><string name=\"fov_axis\" value=\"y\"/>", 200, 100)
                    .camera.fovYDegrees, 60.0f, 1e-4f);
    EXPECT_NEAR(sceneWithSensor("<float name=\"fov\" value=\"60\"/><string name=\"fov_axis\" value=\"diagonal\"/>", 200, 100)
                    .camera.fovYDegrees, verticalFov(60, std::sqrt(w * w + h * h), h), 1e-4f);
    EXPECT_NEAR(sceneWithSensor("<float name=\"fov\" value=\"60\"/><string name=\"fov_axis\" value=\"smaller\"/>", 200, 100)
                    .camera.fovYDegrees, 60.0f, 1e-4f);
    EXPECT_NEAR(sceneWithSensor("<float name=\"fov\" value=\"60\"/><string name=\"fov_axis\" value=\"larger\"/>", 200, 100)
                    .camera.fovYDegrees, verticalFov(60, w, h), 1e-4f);
    EXPECT_NEAR(sceneWithSensor("<float name=\"fov\" value=\"60\"/><string name=\"fov_axis\" value=\"larger\"/>", 100, 200)
                    .camera.fovYDegrees, 60.0f, 1e-4f);
    // 50 mm on 35 mm film spans 46.8 degrees across the diagonal.
    const float diagonal = 2.0f * std::atan(std::sqrt(36.0f * 36.0f + 24.0f * 24.0f) / 100.0f) * 180.0f / kPi;
    EXPECT_NEAR(sceneWithSensor("<string name=\"focal_length\" value=\"50mm\"/>", 300, 200).camera.fovYDegrees,
                verticalFov(diagonal, std::sqrt(300.0f * 300.0f + 200.0f * 200.0f), 200), 1e-4f);
    EXPECT_NEAR(sceneWithSensor("", 300, 200).camera.fovYDegrees,
                verticalFov(diagonal, std::sqrt(300.0f * 300.0f + 200.0f * 200.0f), 200), 1e-4f)
        << "no fov: Mitsuba's 50 mm";
}

TEST(SceneXml, SensorClipPlanesAndMirroring) {
    const std::string lookat =
        "<transform name=\"to_world\"><lookat origin=\"0, 0, 0\" target=\"0, 0, 1\" up=\"0, 1, 0\"/></transform>\n";
    const Scene plain = sceneWithSensor("<float name=\"fov\" value=\"90\"/><float name=\"near_clip\" value=\"2\"/>"
                                        "<float name=\"far_clip\" value=\"10\"/>" + lookat, 64, 64);
    const Camera& camera = plain.camera;
    EXPECT_FALSE(camera.mirrored);
    // The centre ray starts on the near plane and ends on the far one.
    const Ray centre = camera.generateRay(Vec2(32, 32));
    expectNear(centre.origin, Vec3(0, 0, 2), 1e-5f, "near plane");
    EXPECT_NEAR(centre.tMax, 8.0f, 1e-4f);
    // Off-axis rays reach the same planes (depth along the axis, not distance).
    const Ray corner = camera.generateRay(Vec2(0, 0));
    EXPECT_NEAR(corner.origin.z, 2.0f, 1e-5f);
    EXPECT_NEAR((corner.origin + corner.tMax * corner.direction).z, 10.0f, 1e-4f);
    // Mitsuba's image +x is the camera's -x: looking along +z with up +y, the left edge sees +x.
    EXPECT_GT(corner.direction.x, 0.0f);

    const std::string mirroredLookat = "<transform name=\"to_world\"><scale x=\"-1\"/>"
                                       "<lookat origin=\"0, 0, 0\" target=\"0, 0, 1\" up=\"0, 1, 0\"/></transform>\n";
    const Scene mirrored = sceneWithSensor("<float name=\"fov\" value=\"90\"/>" + mirroredLookat, 64, 64);
    EXPECT_TRUE(mirrored.camera.mirrored);
    EXPECT_LT(mirrored.camera.generateRay(Vec2(0, 0)).direction.x, 0.0f);
    Vec2 raster;
    ASSERT_TRUE(mirrored.camera.project(Vec3(-1, 0, 2), &raster));
    EXPECT_LT(raster.x, 32.0f) << "project agrees with generateRay";
}

TEST(SceneXml, FilmSamplerAndIntegratorHints) {
    const fs::path dir = scratchDir();
    auto hintsOf = [&](const std::string& filter, const std::string& extra = "") {
        const std::string text = "<scene version=\"3.0.0\">\n<integrator type=\"volpath\"><integer name=\"max_depth\" value=\"-1\"/>"
                                 "<boolean name=\"hide_emitters\" value=\"true\"/></integrator>\n"
                                 "<sensor type=\"perspective\"><sampler type=\"stratified\"><integer name=\"sample_count\" value=\"9\"/>"
                                 "<integer name=\"seed\" value=\"3\"/></sampler>\n"
                                 "<film type=\"hdrfilm\"><string name=\"pixel_format\" value=\"rgba\"/>" + filter + extra +
                                 "</film></sensor>\n</scene>\n";
        return loadXmlScene(writeFile(dir / "hints.xml", text).string());
    };
    const Scene gaussian = hintsOf("");
    EXPECT_EQ(gaussian.hints.samplesPerPixel, 9);
    EXPECT_EQ(gaussian.hints.maxDepth, -1);
    EXPECT_EQ(gaussian.hints.filter, FilterKind::Gaussian) << "Mitsuba's default filter";
    EXPECT_NEAR(gaussian.hints.gaussianSigma, 0.5f, 0.0f);
    EXPECT_NEAR(gaussian.hints.filterRadius, 2.0f, 0.0f);
    EXPECT_EQ(gaussian.camera.width, 768);
    EXPECT_EQ(gaussian.camera.height, 576);
    const Scene box = hintsOf("<rfilter type=\"box\"><float name=\"radius\" value=\"0.75\"/></rfilter>");
    EXPECT_EQ(box.hints.filter, FilterKind::Box);
    EXPECT_NEAR(box.hints.filterRadius, 0.75f, 0.0f);
    const Scene tent = hintsOf("<rfilter type=\"tent\"/>");
    EXPECT_EQ(tent.hints.filter, FilterKind::Tent);
    EXPECT_NEAR(tent.hints.filterRadius, 1.0f, 0.0f);
    const std::string message = loadError(writeFile(dir / "h.xml", "")).what();  // an empty file is not a scene
    EXPECT_TRUE(contains(message, "h.xml")) << message;
    EXPECT_THROW(hintsOf("<rfilter type=\"lanczos\"/>"), InputError);
    EXPECT_THROW(hintsOf("", "<integer name=\"crop_width\" value=\"5\"/>"), InputError);
}

// ---- shapes, materials, lights ---------------------------------------------------------

TEST(SceneXml, ShapesAndNormals) {
    const fs::path dir = scratchDir();
    writeFile(dir / "quad.obj", kQuadObj);
    writeFile(dir / "tri.ply",
              "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
              "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n2 0 0\n0 2 0\n3 0 1 2\n");
    const std::string text = test::mitsubaSceneText(R"(
    <shape type="sphere"><point name="center" x="1" y="2" z="3"/><float name="radius" value="0.5"/>
        <transform name="to_world"><scale value="2"/><translate x="1"/></transform></shape>
    <shape type="sphere"><boolean name="flip_normals" value="true"/></shape>
    <shape type="rectangle"><transform name="to_world"><scale value="3"/></transform><boolean name="flip_normals" value="true"/></shape>
    <shape type="disk"><transform name="to_world"><scale value="2"/></transform></shape>
    <shape type="cube"/>
    <shape type="obj"><string name="filename" value="quad.obj"/></shape>
    <shape type="obj"><string name="filename" value="quad.obj"/><boolean name="face_normals" value="true"/>
        <boolean name="flip_tex_coords" value="false"/></shape>
    <shape type="ply"><string name="filename" value="tri.ply"/></shape>
)");
    const Scene scene = loadXmlScene(writeFile(dir / "scene.xml", text).string());
    ASSERT_EQ(scene.shapes.size(), 8u);
    const Sphere& sphere = std::get<Sphere>(scene.shapes[0].geometry);
    expectNear(sphere.center, Vec3(3, 4, 6), 1e-5f, "center folded through to_world");
    EXPECT_NEAR(sphere.radius, 1.0f, 1e-6f);
    EXPECT_TRUE(scene.shapes[1].flipNormals);
    const auto& rect = std::get<TriangleMesh>(scene.shapes[2].geometry);
    EXPECT_NEAR(rect.area(), 36.0f, 1e-4f);
    EXPECT_NEAR(rect.normals[0].z, -1.0f, 1e-6f) << "flip_normals";
    EXPECT_NEAR(scene.shapes[3].area(), 4.0f * kPi, 0.01f);
    EXPECT_NEAR(scene.shapes[4].area(), 24.0f, 1e-4f);
    // An OBJ without normals gets vertex normals (Mitsuba computes them); face_normals drops them.
    const auto& smooth = std::get<TriangleMesh>(scene.shapes[5].geometry);
    ASSERT_EQ(smooth.normals.size(), smooth.positions.size());
    for (const Vec3& n : smooth.normals) expectNear(n, Vec3(0, 0, 1), 1e-6f, "computed normal");
    EXPECT_TRUE(std::get<TriangleMesh>(scene.shapes[6].geometry).normals.empty());
    // OBJ texture coordinates are flipped as Mitsuba flips them, unless flip_tex_coords is false.
    for (std::size_t i = 0; i < smooth.positions.size(); ++i) {
        EXPECT_NEAR(smooth.uvs[i].y, 1.0f - (smooth.positions[i].y + 1.0f) / 2.0f, 1e-6f);
        const auto& kept = std::get<TriangleMesh>(scene.shapes[6].geometry);
        EXPECT_NEAR(kept.uvs[i].y, (kept.positions[i].y + 1.0f) / 2.0f, 1e-6f);
    }
    EXPECT_NEAR(scene.shapes[7].area(), 2.0f, 1e-6f);
    EXPECT_EQ(scene.shapes[7].name, "tri");
    // Shapes without a bsdf share Mitsuba's default diffuse 0.5.
    EXPECT_EQ(scene.shapes[0].bsdf, scene.shapes[7].bsdf);
    expectNear(diffuseAlbedo(scene, 0), Rgb(0.5f), 1e-6f);

    // A stretched sphere (an ellipsoid) cannot be represented.
    const std::string stretched = test::mitsubaSceneText(
        "    <shape type=\"sphere\"><transform name=\"to_world\"><scale x=\"1\" y=\"2\" z=\"1\"/></transform></shape>\n");
    expectErrorAt(dir, stretched, "to_world", "shape 'sphere'", "stretched.xml");
}

TEST(SceneXml, MaterialsAndTextures) {
    const fs::path dir = scratchDir();
    // A 1 x 2 bitmap: red on top, blue below.
    ImageChannels image;
    image.width = 1;
    image.height = 2;
    image.rgb = {Rgb(1, 0, 0), Rgb(0, 0, 1)};
    writeExr((dir / "stripes.exr").string(), image, {});
    const std::string text = test::mitsubaSceneText(R"(
    <shape type="rectangle"><bsdf type="diffuse"><texture type="bitmap" name="reflectance">
        <string name="filename" value="stripes.exr"/></texture></bsdf></shape>
    <shape type="rectangle"><bsdf type="diffuse"><texture type="checkerboard" name="reflectance">
        <rgb name="color0" value="0.9"/><rgb name="color1" value="0.1"/>
        <transform name="to_uv"><scale x="2" y="2"/></transform></texture></bsdf></shape>
    <shape type="rectangle"><bsdf type="conductor"><string name="material" value="Au"/></bsdf></shape>
    <shape type="rectangle"><bsdf type="roughconductor"><float name="alpha" value="0.3"/>
        <rgb name="eta" value="0.2, 0.9, 1.1"/><rgb name="k" value="3.6, 2.6, 2.3"/></bsdf></shape>
    <shape type="rectangle"><bsdf type="roughdielectric"><string name="distribution" value="ggx"/>
        <float name="alpha_u" value="0.2"/><float name="alpha_v" value="0.2"/><float name="int_ior" value="1.33"/></bsdf></shape>
    <shape type="rectangle"><bsdf type="plastic"><spectrum name="diffuse_reflectance" value="0.3"/>
        <boolean name="nonlinear" value="true"/></bsdf></shape>
    <shape type="rectangle"><bsdf type="thindielectric"/></shape>
    <shape type="rectangle"><bsdf type="null"/></shape>
    <shape type="rectangle"><bsdf type="diffuse"><spectrum name="reflectance" value="380:0.5, 780:0.5"/></bsdf></shape>
    <shape type="rectangle"><bsdf type="diffuse"><srgb name="reflectance" value="#808080"/></bsdf></shape>
)");
    const Scene scene = loadXmlScene(writeFile(dir / "scene.xml", text).string());
    ASSERT_EQ(scene.shapes.size(), 10u);
    // Mitsuba's v = 0 is the top image row.
    const Rgb top = diffuseAlbedo(scene, 0, Vec2(0.5f, 0.25f));
    const Rgb bottom = diffuseAlbedo(scene, 0, Vec2(0.5f, 0.75f));
    EXPECT_GT(top.x, 0.9f);
    EXPECT_LT(top.z, 0.1f);
    EXPECT_GT(bottom.z, 0.9f);
    // Checkerboard with to_uv scale 2: four checkers per unit, color0 where both cells are even.
    EXPECT_NEAR(diffuseAlbedo(scene, 1, Vec2(0.1f, 0.1f)).x, 0.9f, 1e-6f);
    EXPECT_NEAR(diffuseAlbedo(scene, 1, Vec2(0.3f, 0.1f)).x, 0.1f, 1e-6f);
    EXPECT_NEAR(diffuseAlbedo(scene, 1, Vec2(0.3f, 0.3f)).x, 0.9f, 1e-6f);
    // Gold reflects more red than blue at normal incidence.
    const Bsdf& gold = *scene.bsdfs[static_cast<std::size_t>(scene.shapes[2].bsdf)];
    const auto s = gold.sample(Vec3(0, 0, 1), Vec2(0.5f), 0.5f, Vec2(0.5f), TransportMode::Radiance);
    ASSERT_TRUE(s.has_value());
    EXPECT_GT(s->weight.x, s->weight.z);
    EXPECT_TRUE(scene.bsdfs[static_cast<std::size_t>(scene.shapes[3].bsdf)]->hasSmoothLobe());
    EXPECT_TRUE(scene.bsdfs[static_cast<std::size_t>(scene.shapes[7].bsdf)]->isNull());
    expectNear(diffuseAlbedo(scene, 8), Rgb(0.5f), 1e-4f, "flat spectrum");
    expectNear(diffuseAlbedo(scene, 9), Rgb(0.2158605f), 1e-4f, "sRGB 128 decoded");

    // Distributions other than Beckmann (the default) and GGX are errors.
    const std::string phong = test::mitsubaSceneText(
        "    <bsdf type=\"roughconductor\" id=\"p\">\n        <string name=\"distribution\" value=\"phong\"/>\n    </bsdf>\n");
    expectErrorAt(dir, phong, "phong", "bsdf 'roughconductor'", "phong.xml");
    const std::string aniso = test::mitsubaSceneText(
        "    <bsdf type=\"roughconductor\" id=\"p\">\n        <float name=\"alpha_u\" value=\"0.1\"/>\n"
        "        <float name=\"alpha_v\" value=\"0.3\"/>\n    </bsdf>\n");
    expectErrorAt(dir, aniso, "alpha_v", "bsdf 'roughconductor'", "aniso.xml");
    const std::string bright = test::mitsubaSceneText(
        "    <bsdf type=\"diffuse\" id=\"d\">\n        <rgb name=\"reflectance\" value=\"1.5, 0, 0\"/>\n    </bsdf>\n");
    expectErrorAt(dir, bright, "1.5, 0, 0", "bsdf 'diffuse'", "bright.xml");
    const std::string unknownIor = test::mitsubaSceneText(
        "    <bsdf type=\"dielectric\" id=\"d\">\n        <string name=\"int_ior\" value=\"unobtainium\"/>\n    </bsdf>\n");
    expectErrorAt(dir, unknownIor, "unobtainium", "bsdf 'dielectric'", "ior.xml");
}

// distribution selects the microfacet model, Beckmann by default as in
// Mitsuba; roughplastic reads Mitsuba's parameters and defaults.
TEST(SceneXml, RoughBsdfsTakeTheirDistribution) {
    const fs::path dir = scratchDir();
    const std::string text = test::mitsubaSceneText(R"(    <bsdf type="roughconductor" id="default"><string name="material" value="Au"/>
        <float name="alpha" value="0.3"/></bsdf>
    <bsdf type="roughconductor" id="ggx"><string name="material" value="Au"/>
        <float name="alpha" value="0.3"/><string name="distribution" value="ggx"/></bsdf>
    <bsdf type="roughdielectric" id="glass"><float name="alpha" value="0.3"/><float name="int_ior" value="1.5"/>
        <float name="ext_ior" value="1"/></bsdf>
    <bsdf type="roughplastic" id="coated"><rgb name="diffuse_reflectance" value="0.2, 0.4, 0.6"/>
        <float name="alpha" value="0.2"/><string name="int_ior" value="bk7"/><float name="ext_ior" value="1"/>
        <boolean name="nonlinear" value="true"/><spectrum name="specular_reflectance" value="0.5"/>
        <boolean name="sample_visible" value="false"/></bsdf>
    <bsdf type="roughplastic" id="plain"><float name="ext_ior" value="1"/><string name="distribution" value="ggx"/></bsdf>
    <shape type="rectangle"><ref id="default"/></shape>
    <shape type="rectangle"><ref id="ggx"/></shape>
    <shape type="rectangle"><ref id="glass"/></shape>
    <shape type="rectangle"><ref id="coated"/></shape>
    <shape type="rectangle"><ref id="plain"/></shape>
)");
    const Scene scene = loadXmlScene(writeFile(dir / "scene.xml", text).string());
    ASSERT_EQ(scene.shapes.size(), 5u);
    const auto bsdfOf = [&](std::size_t shape) { return scene.bsdfs[static_cast<std::size_t>(scene.shapes[shape].bsdf)]; };
    const ConductorIor gold = *conductorPreset("Au");
    const Vec3 wo = glm::normalize(Vec3(0.3f, 0.1f, 0.9f)), wi = glm::normalize(Vec3(-0.5f, 0.2f, 0.6f));
    const Vec3 below(wi.x, wi.y, -wi.z);
    const auto value = [&](const Bsdf& b, const Vec3& to) { return b.eval(wo, to, Vec2(0.5f), TransportMode::Radiance); };
    const auto diffuse = [](float r, float g, float b) { return makeConstantTexture(Rgb(r, g, b)); };
    const struct {
        std::shared_ptr<Bsdf> loaded, expected, other;
        Vec3 to;
    } cases[] = {
        {bsdfOf(0), makeRoughConductor(gold, 0.3f, Rgb(1.0f), MicrofacetType::Beckmann), makeRoughConductor(gold, 0.3f), wi},
        {bsdfOf(1), makeRoughConductor(gold, 0.3f), makeRoughConductor(gold, 0.3f, Rgb(1.0f), MicrofacetType::Beckmann), wi},
        {bsdfOf(2), makeRoughDielectric(1.5f, 0.3f, MicrofacetType::Beckmann), makeRoughDielectric(1.5f, 0.3f), below},
        {bsdfOf(3),
         makeRoughPlastic(diffuse(0.2f, 0.4f, 0.6f), 1.5046f, 0.2f, MicrofacetType::Beckmann, true, Rgb(0.5f)),
         makeRoughPlastic(diffuse(0.2f, 0.4f, 0.6f), 1.5046f, 0.2f, MicrofacetType::Beckmann, false, Rgb(0.5f)), wi},
        // Mitsuba's defaults: diffuse 0.5, polypropylene (1.49), alpha 0.1.
        {bsdfOf(4), makeRoughPlastic(diffuse(0.5f, 0.5f, 0.5f), 1.49f, 0.1f, MicrofacetType::Ggx),
         makeRoughPlastic(diffuse(0.5f, 0.5f, 0.5f), 1.49f, 0.1f, MicrofacetType::Beckmann), wi},
    };
    for (std::size_t i = 0; i < std::size(cases); ++i) {
        const Rgb loaded = value(*cases[i].loaded, cases[i].to), expected = value(*cases[i].expected, cases[i].to);
        expectNear(loaded, expected, 1e-6f * std::max(1.0f, expected.x), "shape " + std::to_string(i));
        EXPECT_NE(loaded, value(*cases[i].other, cases[i].to)) << "shape " << i;
    }

    const std::string unknown = test::mitsubaSceneText(
        "    <bsdf type=\"roughplastic\" id=\"p\">\n        <string name=\"distribution\" value=\"blinn\"/>\n    </bsdf>\n");
    expectErrorAt(dir, unknown, "blinn", "bsdf 'roughplastic'", "blinn.xml");
    const std::string rough = test::mitsubaSceneText(
        "    <bsdf type=\"roughplastic\" id=\"p\">\n        <float name=\"alpha\" value=\"-2\"/>\n    </bsdf>\n");
    expectErrorAt(dir, rough, "roughplastic", "alpha", "alpha.xml");
}

TEST(SceneXml, EmittersAndMedia) {
    const fs::path dir = scratchDir();
    ImageChannels sky;
    sky.width = 8;
    sky.height = 4;
    sky.rgb.assign(32, Rgb(0.5f));
    writeExr((dir / "sky.exr").string(), sky, {});
    const std::string text = R"(<scene version="3.0.0">
    <sensor type="perspective">
        <ref id="haze"/>
        <float name="fov" value="45"/>
    </sensor>
    <medium type="homogeneous" id="haze">
        <rgb name="sigma_s" value="0.5"/><rgb name="sigma_a" value="0.25"/><float name="scale" value="2"/>
        <phase type="hg"/>
    </medium>
    <emitter type="point"><point name="position" value="1, 2, 3"/><rgb name="intensity" value="2"/></emitter>
    <emitter type="point"><transform name="to_world"><translate x="4"/></transform></emitter>
    <emitter type="spot"><transform name="to_world"><lookat origin="0, 5, 0" target="0, 0, 0" up="1, 0, 0"/></transform>
        <float name="cutoff_angle" value="30"/><float name="intensity" value="10"/></emitter>
    <emitter type="directional"><vector name="direction" value="0, -1, 0"/><spectrum name="irradiance" value="3"/></emitter>
    <emitter type="constant"><rgb name="radiance" value="0.1"/></emitter>
    <emitter type="envmap"><string name="filename" value="sky.exr"/><float name="scale" value="2"/>
        <transform name="to_world"><rotate y="1" angle="90"/></transform></emitter>
    <shape type="sphere"><float name="radius" value="10"/></shape>
</scene>
)";
    const Scene scene = loadXmlScene(writeFile(dir / "scene.xml", text).string());
    ASSERT_EQ(scene.media.size(), 1u);
    EXPECT_EQ(scene.camera.medium, 0);
    expectNear(scene.media[0].sigmaS(), Rgb(1.0f), 1e-6f, "sigma_s * scale");
    expectNear(scene.media[0].sigmaA(), Rgb(0.5f), 1e-6f, "sigma_a * scale");
    EXPECT_NEAR(scene.media[0].phase().g(), 0.8f, 1e-6f) << "Mitsuba's default g";
    ASSERT_EQ(scene.lights.size(), 6u);
    EXPECT_NEAR(scene.lights[0]->power().x, 4.0f * kPi * 2.0f, 1e-4f);
    const auto fromPoint = scene.lights[0]->sampleLi(Vec3(1, 2, 0), Vec2(0.5f));
    ASSERT_TRUE(fromPoint.has_value());
    expectNear(fromPoint->wi, Vec3(0, 0, 1), 1e-6f, "position");
    const auto fromTranslated = scene.lights[1]->sampleLi(Vec3(0, 0, 0), Vec2(0.5f));
    ASSERT_TRUE(fromTranslated.has_value());
    expectNear(fromTranslated->wi, Vec3(1, 0, 0), 1e-6f, "to_world position");
    // The spot points down its to_world +z: lit straight below, dark to the side.
    const auto below = scene.lights[2]->sampleLi(Vec3(0, 0, 0), Vec2(0.5f));
    const auto aside = scene.lights[2]->sampleLi(Vec3(5, 5, 0), Vec2(0.5f));
    ASSERT_TRUE(below.has_value());
    EXPECT_GT(below->value.x, 0.0f);
    EXPECT_TRUE(!aside.has_value() || isBlack(aside->value));
    const auto sun = scene.lights[3]->sampleLi(Vec3(0, 0, 0), Vec2(0.5f));
    ASSERT_TRUE(sun.has_value());
    expectNear(sun->wi, Vec3(0, 1, 0), 1e-6f, "towards the directional light");
    // A single-value <spectrum> on an emitter is not grey in Mitsuba 3's RGB mode (spectrum.h).
    expectNear(sun->value, uniformEmissionToRgb(3.0f), 1e-5f);
    expectNear(scene.lights[4]->environment(Vec3(0, 1, 0)), Rgb(0.1f), 1e-6f);
    expectNear(scene.lights[5]->environment(Vec3(0, 1, 0)), Rgb(1.0f), 1e-4f);
    EXPECT_EQ(scene.infiniteLights().size(), 3u);
}

TEST(SceneXml, Mitsuba06NamesAndDefaults) {
    const fs::path dir = scratchDir();
    const std::string text = R"(<?xml version="1.0" encoding="utf-8"?>
<scene version="0.6.0">
    <integrator type="path"><integer name="maxDepth" value="5"/></integrator>
    <sensor type="perspective">
        <float name="fov" value="30"/><string name="fovAxis" value="y"/>
        <float name="nearClip" value="0.5"/>
        <transform name="toWorld"><lookAt origin="0, 0, -5" target="0, 0, 0" up="0, 1, 0"/></transform>
        <sampler type="ldsampler"><integer name="sampleCount" value="64"/></sampler>
        <film type="ldrfilm"><integer name="width" value="40"/><integer name="height" value="30"/>
            <float name="gamma" value="2.2"/><rfilter type="gaussian"/></film>
    </sensor>
    <bsdf type="conductor" id="metal"/>
    <bsdf type="dielectric" id="glass"><float name="intIOR" value="1.6"/><float name="extIOR" value="1.0"/></bsdf>
    <shape type="rectangle"><ref id="metal"/></shape>
    <shape type="rectangle"><ref id="glass"/></shape>
</scene>
)";
    const Scene scene = loadXmlScene(writeFile(dir / "old.xml", text).string());
    EXPECT_EQ(scene.hints.maxDepth, 4);  // 0.x counts path vertices as Mitsuba 3 does
    EXPECT_EQ(scene.hints.samplesPerPixel, 64);
    EXPECT_NEAR(scene.camera.fovYDegrees, 30.0f, 1e-5f);
    EXPECT_NEAR(scene.camera.nearClip, 0.5f, 1e-6f);
    expectNear(scene.camera.eye, Vec3(0, 0, -5), 1e-6f);
    EXPECT_EQ(scene.camera.width, 40);
    // Mitsuba 0.6's conductor defaults to copper: redder than blue (a mirror would be neutral).
    const Bsdf& metal = *scene.bsdfs[static_cast<std::size_t>(scene.shapes[0].bsdf)];
    const auto s = metal.sample(Vec3(0, 0, 1), Vec2(0.5f), 0.5f, Vec2(0.5f), TransportMode::Radiance);
    ASSERT_TRUE(s.has_value());
    EXPECT_GT(s->weight.x, 1.2f * s->weight.z);
    const Bsdf& glass = *scene.bsdfs[static_cast<std::size_t>(scene.shapes[1].bsdf)];
    const auto g = glass.sample(Vec3(0, 0, 1), Vec2(0.5f), 0.0f, Vec2(0.5f), TransportMode::Radiance);
    ASSERT_TRUE(g.has_value());
    EXPECT_NEAR(g->pdf, sqr(0.6f / 2.6f), 1e-4f);
    // Mitsuba 3's conductor is a perfect mirror by default.
    const std::string v3 = test::mitsubaSceneText("    <bsdf type=\"conductor\" id=\"m\"/>\n    <shape type=\"rectangle\"><ref id=\"m\"/></shape>\n");
    const Scene mirror = loadXmlScene(writeFile(dir / "new.xml", v3).string());
    const auto m = mirror.bsdfs[0]->sample(Vec3(0, 0, 1), Vec2(0.5f), 0.5f, Vec2(0.5f), TransportMode::Radiance);
    ASSERT_TRUE(m.has_value());
    expectNear(m->weight, Rgb(1.0f), 1e-5f, "mirror");
}

// ---- the error contract ---------------------------------------------------------------

TEST(SceneXml, ErrorsNameFileLineAndPlugin) {
    const fs::path dir = scratchDir();
    writeFile(dir / "quad.obj", kQuadObj);
    // Unknown plugin type.
    expectErrorAt(dir, test::mitsubaSceneText("    <bsdf type=\"hair\" id=\"m\"/>\n"), "hair", "bsdf 'hair'", "plugin.xml");
    expectErrorAt(dir, test::mitsubaSceneText("    <shape type=\"serialized\"/>\n"), "serialized", "shape 'serialized'", "plugin2.xml");
    expectErrorAt(dir, test::mitsubaSceneText("    <emitter type=\"sunsky\"/>\n"), "sunsky", "emitter 'sunsky'", "plugin3.xml");
    // Unknown parameter of a supported plugin, reported at the parameter's own line.
    const std::string unknown = test::mitsubaSceneText(
        "    <bsdf type=\"diffuse\" id=\"d\">\n        <float name=\"roughness\" value=\"0.1\"/>\n    </bsdf>\n");
    const std::string m1 = expectErrorAt(dir, unknown, "roughness", "bsdf 'diffuse'", "param.xml");
    EXPECT_TRUE(contains(m1, "unknown parameter 'roughness'")) << m1;
    EXPECT_TRUE(contains(m1, "reflectance")) << "the message lists what is understood: " << m1;
    // Malformed numbers.
    const std::string malformed = "<scene version=\"3.0.0\">\n    <sensor type=\"perspective\">\n"
                                  "        <float name=\"fov\" value=\"4o\"/>\n    </sensor>\n</scene>\n";
    const std::string m2 = expectErrorAt(dir, malformed, "4o", "sensor 'perspective'", "number.xml");
    EXPECT_TRUE(contains(m2, "'4o' is not a number")) << m2;
    expectErrorAt(dir, test::mitsubaSceneText("    <shape type=\"rectangle\">\n        <transform name=\"to_world\"><translate x=\"1e\"/></transform>\n    </shape>\n"),
                  "1e", "shape 'rectangle'", "number2.xml");
    expectErrorAt(dir, test::mitsubaSceneText("    <shape type=\"rectangle\">\n        <bsdf type=\"diffuse\"><rgb name=\"reflectance\" value=\"0.1, 0.2\"/></bsdf>\n    </shape>\n"),
                  "0.1, 0.2", "bsdf 'diffuse'", "number3.xml");
    expectErrorAt(dir, test::mitsubaSceneText("    <shape type=\"rectangle\">\n        <boolean name=\"flip_normals\" value=\"yes\"/>\n    </shape>\n"),
                  "yes", "shape 'rectangle'", "bool.xml");
    // Missing file.
    const std::string m3 = expectErrorAt(
        dir, test::mitsubaSceneText("    <shape type=\"obj\">\n        <string name=\"filename\" value=\"nosuch.obj\"/>\n    </shape>\n"),
        "nosuch.obj", "shape 'obj'", "file.xml");
    EXPECT_TRUE(contains(m3, "nosuch.obj")) << m3;
    // Missing ref id.
    const std::string m4 = expectErrorAt(
        dir, test::mitsubaSceneText("    <shape type=\"rectangle\">\n        <ref id=\"nosuch\"/>\n    </shape>\n"), "nosuch",
        "shape 'rectangle'", "ref.xml");
    EXPECT_TRUE(contains(m4, "unknown id 'nosuch'")) << m4;
    // A reference to the wrong kind of object.
    expectErrorAt(dir, test::mitsubaSceneText("    <texture type=\"checkerboard\" id=\"t\"/>\n    <shape type=\"rectangle\">\n"
                                 "        <ref id=\"t\"/>\n    </shape>\n"),
                  "<ref id=\"t\"/>", "shape 'rectangle'", "kind.xml");
    // Objects that reach themselves through references.
    const std::string cycle = test::mitsubaSceneText("    <bsdf type=\"twosided\" id=\"a\"><ref id=\"b\"/></bsdf>\n"
                                        "    <bsdf type=\"twosided\" id=\"b\"><ref id=\"a\"/></bsdf>\n");
    expectErrorAt(dir, cycle, "id=\"a\"", "bsdf 'twosided'", "cycle.xml");
    // Misspelt attribute, unknown element, XML syntax, duplicate id, missing or old version.
    expectErrorAt(dir, test::mitsubaSceneText("    <shape type=\"rectangle\">\n        <float nam=\"x\" value=\"1\"/>\n    </shape>\n"),
                  "nam=", "shape 'rectangle'", "attr.xml");
    expectErrorAt(dir, test::mitsubaSceneText("    <shape type=\"rectangle\">\n        <animation/>\n    </shape>\n"), "animation",
                  "shape 'rectangle'", "element.xml");
    const std::string syntax = test::mitsubaSceneText("    <shape type=\"rectangle\">\n    </shap>\n");
    const fs::path syntaxPath = writeFile(dir / "syntax.xml", syntax);
    const std::string m5 = loadError(syntaxPath).what();
    EXPECT_TRUE(contains(m5, syntaxPath.string() + ":" + std::to_string(lineOf(syntax, "</shap>")) + ":")) << m5;
    const std::string twice = test::mitsubaSceneText("    <bsdf type=\"null\" id=\"x\"/>\n    <bsdf type=\"null\" id=\"x\"/>\n");
    const fs::path twicePath = writeFile(dir / "twice.xml", twice);
    EXPECT_TRUE(contains(loadError(twicePath).what(), twicePath.string() + ":7:")) << loadError(twicePath).what();
    EXPECT_TRUE(contains(loadError(writeFile(dir / "nover.xml", "<scene>\n</scene>\n")).what(), "version"));
    EXPECT_TRUE(contains(loadError(writeFile(dir / "v4.xml", "<scene version=\"0.4.0\">\n</scene>\n")).what(), "0.4.0"));
    // Parameters fluxgraph cannot honour are errors, not silently dropped.
    expectErrorAt(dir, test::mitsubaSceneText("    <bsdf type=\"plastic\" id=\"p\">\n        <rgb name=\"specular_reflectance\" value=\"0.5\"/>\n    </bsdf>\n"),
                  "specular_reflectance", "bsdf 'plastic'", "unsupported.xml");
    expectErrorAt(dir, "<scene version=\"3.0.0\">\n    <sensor type=\"thinlens\"/>\n</scene>\n", "thinlens",
                  "sensor 'thinlens'", "sensor.xml");
    EXPECT_TRUE(contains(loadError(writeFile(dir / "nosensor.xml", "<scene version=\"3.0.0\">\n</scene>\n")).what(), "no <sensor>"));
}

// ---- job files and the command line -----------------------------------------------------

TEST(SceneXml, JobSceneDefinesAndDefineOverrides) {
    const std::string text = "scene = \"cbox.xml\"\npipeline = \"pt\"\nscene_defines = { spp = 32, res = \"64\", scale = 0.5, on = true }\n";
    Job job = parseJob(text, "/jobs/job.toml");
    EXPECT_EQ(job.sceneDefines, (std::map<std::string, std::string>{{"spp", "32"}, {"res", "64"}, {"scale", "0.5"}, {"on", "true"}}));
    JobOverrides overrides;
    overrides.defines = {"spp=4", "extra=a=b"};
    job = parseJob(text, "/jobs/job.toml", overrides);
    EXPECT_EQ(job.sceneDefines.at("spp"), "4") << "--define wins over scene_defines";
    EXPECT_EQ(job.sceneDefines.at("extra"), "a=b");
    overrides.defines = {"novalue"};
    EXPECT_THROW(parseJob(text, "/jobs/job.toml", overrides), InputError);
    try {
        parseJob("scene = \"s.xml\"\npipeline = \"pt\"\nscene_defines = { spp = [1] }\n", "/jobs/job.toml");
        ADD_FAILURE() << "an array define is not a scene parameter";
    } catch (const InputError& e) {
        EXPECT_TRUE(contains(e.what(), "/jobs/job.toml:3")) << e.what();
    }
}

}  // namespace
}  // namespace fg

namespace fg {
namespace {

// A scene's sample_count and max_depth fill in pass parameters the job leaves
// unset; values in the job file win.
TEST(SceneXml, RenderHintsFillUnsetPassParameters) {
    const fs::path dir = scratchDir();
    writeFile(dir / "scene.xml", R"(<scene version="3.0.0">
  <integrator type="path"><integer name="max_depth" value="3"/></integrator>
  <sensor type="perspective">
    <float name="fov" value="40"/>
    <sampler type="independent"><integer name="sample_count" value="3"/></sampler>
    <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="6"/></film>
  </sensor>
  <emitter type="constant"><rgb name="radiance" value="1, 1, 1"/></emitter>
</scene>)");
    const auto render = [&](const std::string& extra) {
        Job job = parseJob("scene = \"scene.xml\"\npipeline = \"pt\"\n[output]\ndirectory = \"" + (dir / "out").string() +
                               "\"\npng = false\nexr = false\n" + extra,
                           (dir / "job.toml").string());
        return renderJob(job, {});
    };
    const RenderOutcome fromHints = render("");
    EXPECT_EQ(fromHints.run.stats.front().items, 8 * 6 * 3);
    const RenderOutcome fromJob = render("[passes.pt]\nspp = 5\n");
    EXPECT_EQ(fromJob.run.stats.front().items, 8 * 6 * 5);
}

}  // namespace
}  // namespace fg

namespace fg {
namespace {

// Every problem of a scene is reported by one load, each on its own line with
// its file:line and plugin; a broken shared object is reported once.
TEST(SceneXml, ReportsEveryProblemAtOnce) {
    const fs::path dir = scratchDir();
    const std::string text = test::mitsubaSceneText(R"(    <bsdf type="diffuse" id="shared"><float name="roughness" value="1"/></bsdf>
    <shape type="sphere"><ref id="shared"/></shape>
    <shape type="sphere"><ref id="shared"/></shape>
    <shape type="hyperboloid"/>
    <emitter type="point"><rgb name="intensity" value="-1"/></emitter>
    <emitter type="constant"><rgb name="radiance" value="1"/></emitter>
    <texture type="bitmap" id="unused"/>
)");
    const fs::path path = writeFile(dir / "scene.xml", text);
    const InputError error = loadError(path);
    const std::vector<std::string>& problems = error.problems();
    ASSERT_EQ(problems.size(), 4u) << error.what();
    const std::string file = path.string() + ":";
    EXPECT_TRUE(contains(problems[0], file + std::to_string(lineOf(text, "roughness")) + ": bsdf 'diffuse'")) << problems[0];
    EXPECT_TRUE(contains(problems[1], file + std::to_string(lineOf(text, "hyperboloid")) + ": shape 'hyperboloid'")) << problems[1];
    EXPECT_TRUE(contains(problems[2], file + std::to_string(lineOf(text, "\"-1\"")) + ": emitter 'point'")) << problems[2];
    EXPECT_TRUE(contains(problems[3], file + std::to_string(lineOf(text, "<texture")) + ": texture 'bitmap'")) << problems[3];
    // what() holds the same lines.
    const std::string all = error.what();
    EXPECT_EQ(std::count(all.begin(), all.end(), '\n'), 3);
}

// One problem keeps the single-error form (file and line of the element).
TEST(SceneXml, OneProblemIsOneError) {
    const fs::path dir = scratchDir();
    const std::string text = test::mitsubaSceneText("    <shape type=\"hyperboloid\"/>\n");
    const fs::path path = writeFile(dir / "scene.xml", text);
    const InputError error = loadError(path);
    EXPECT_TRUE(error.problems().empty());
    EXPECT_EQ(error.line(), lineOf(text, "hyperboloid"));
}

// A scene with more problems than anyone reads stops at a cap, saying so.
TEST(SceneXml, ProblemReportIsCapped) {
    const fs::path dir = scratchDir();
    std::string body;
    for (int i = 0; i < 80; ++i) body += "    <shape type=\"hyperboloid" + std::to_string(i) + "\"/>\n";
    const fs::path path = writeFile(dir / "scene.xml", test::mitsubaSceneText(body));
    const InputError error = loadError(path);
    ASSERT_EQ(error.problems().size(), 51u);
    EXPECT_TRUE(contains(error.problems().back(), "stopped after 50 problems")) << error.problems().back();
}

}  // namespace
}  // namespace fg
