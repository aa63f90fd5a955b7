// The pieces of Mitsuba 3 fidelity one at a time: the max_depth convention,
// emitter spectra, and thindielectric as a null event (what Mitsuba's
// statistical test in test_mitsuba_fidelity.cpp relies on). The environment
// map's lookup and sampling convention is tested with the other lights
// (tests/engine/shading/test_light.cpp).
#include "engine/core/error.h"
#include "engine/scene/scene_xml.h"
#include "engine/scene/spectrum.h"
#include "engine/shading/bsdf.h"
#include "engine/shading/light.h"
#include "tests/support/render_helpers.h"

#include <glm/gtc/matrix_transform.hpp>
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <string>

namespace fg {
namespace {

namespace fs = std::filesystem;

fs::path scratch() {
    const fs::path dir = fs::path(FLUXGRAPH_TEST_TMP) / "mitsuba_conversions";
    fs::create_directories(dir);
    return dir;
}

// A scene of `body` (plus a small sensor), written to a file and loaded.
Scene loadBody(const std::string& name, const std::string& body) {
    const fs::path path = scratch() / (name + ".xml");
    std::ofstream(path) << "<scene version=\"3.0.0\">\n" << body
                        << "\n<sensor type=\"perspective\"><film type=\"hdrfilm\"><integer name=\"width\" value=\"4\"/>"
                           "<integer name=\"height\" value=\"4\"/></film></sensor>\n</scene>\n";
    return loadXmlScene(path.string());
}

int depthOf(const std::string& name, const std::string& integrator) { return loadBody(name, integrator).hints.maxDepth; }

// Mitsuba counts path vertices with the camera's, fluxgraph scattering events.
TEST(MitsubaFidelityConversion, MaxDepthCountsScatteringEvents) {
    EXPECT_EQ(depthOf("path2", R"(<integrator type="path"><integer name="max_depth" value="2"/></integrator>)"), 1);
    EXPECT_EQ(depthOf("path16", R"(<integrator type="path"><integer name="max_depth" value="16"/></integrator>)"), 15);
    EXPECT_EQ(depthOf("volpath", R"(<integrator type="volpath"><integer name="max_depth" value="-1"/></integrator>)"), -1);
    EXPECT_EQ(depthOf("unlimited", R"(<integrator type="path"/>)"), -1);
    // `direct` has no max_depth: emission plus direct light, what max_depth = 2 renders.
    EXPECT_EQ(depthOf("direct", R"(<integrator type="direct"/>)"), 1);
    EXPECT_EQ(depthOf("moment_direct", R"(<integrator type="moment"><integrator type="direct"/></integrator>)"), 1);
    EXPECT_EQ(depthOf("moment_path",
                      R"(<integrator type="moment"><integrator type="volpathmis"><integer name="max_depth" value="6"/></integrator></integrator>)"),
              5);
    // 1 (emitters seen directly) has no fluxgraph equivalent: one clear error naming the element.
    try {
        depthOf("emission_only", R"(<integrator type="path">
  <integer name="max_depth" value="1"/></integrator>)");
        ADD_FAILURE() << "max_depth 1 loaded";
    } catch (const InputError& e) {
        const std::string message = e.what();
        EXPECT_NE(message.find("emission_only.xml:3: "), std::string::npos) << message;
        EXPECT_NE(message.find("max_depth"), std::string::npos) << message;
    }
}

// A single <spectrum> value v on an emitter is v * sRGB(XYZ = 1, 1, 1) in Mitsuba 3's RGB mode:
// by hand from the IEC 61966-2-1 rows, (1.2048, 0.9484, 0.9087) per unit; on a BSDF it is grey.
TEST(MitsubaFidelityConversion, SingleValueSpectrumOnAnEmitter) {
    const Scene scene = loadBody("uniform_emitter", R"(
<emitter type="constant"><spectrum name="radiance" value="2"/></emitter>
<shape type="rectangle"><bsdf type="diffuse"><spectrum name="reflectance" value="0.5"/></bsdf></shape>)");
    const Rgb radiance = scene.lights.at(0)->environment(Vec3(0.0f, 0.0f, 1.0f));
    const Rgb expected = 2.0f * Rgb(1.2048f, 0.9484f, 0.9087f);
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(radiance[c], expected[c], 2e-4f) << c;
    const Rgb albedo = scene.bsdfs.at(0)->eval(Vec3(0, 0, 1), Vec3(0, 0, 1), Vec2(0.5f), TransportMode::Radiance) * kPi;
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(albedo[c], 0.5f, 1e-5f) << c;
}

// A sampled spectrum on an emitter is not white-balanced: the same list gives the
// reflectance conversion times the equal-energy white.
TEST(MitsubaFidelityConversion, SampledSpectrumOnAnEmitter) {
    const Scene scene = loadBody("sampled_emitter", R"(
<emitter type="constant"><spectrum name="radiance" value="400:0, 500:0.3, 600:0.8, 700:1.1"/></emitter>)");
    const SpectrumSample samples[] = {{400, 0.0f}, {500, 0.3f}, {600, 0.8f}, {700, 1.1f}};
    const Rgb expected = glm::max(spectrumToRgb(samples) * equalEnergyWhiteSrgb(), Rgb(0.0f));
    const Rgb radiance = scene.lights.at(0)->environment(Vec3(0.0f, 0.0f, 1.0f));
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(radiance[c], expected[c], 1e-4f) << c;
}

// Light crossing a thin slab as a null event: T = 1 - R_slab passes, nothing scatters.
TEST(MitsubaFidelityConversion, ThinDielectricTransmissionIsANullEvent) {
    const auto slab = makeThinDielectric(1.5f);
    EXPECT_TRUE(slab->hasNullLobe());
    EXPECT_FALSE(slab->isNull());
    for (const float cosTheta : {1.0f, 0.6f, 0.2f}) {
        const Vec3 wo(std::sqrt(1.0f - cosTheta * cosTheta), 0.0f, cosTheta);
        const float single = fresnelDielectric(cosTheta, 1.5f);
        const float transmitted = 1.0f - 2.0f * single / (1.0f + single);
        EXPECT_NEAR(slab->nullTransmission(wo, Vec2(0.0f)).x, transmitted, 1e-6f);
        EXPECT_NEAR(slab->nullTransmission(-wo, Vec2(0.0f)).y, transmitted, 1e-6f) << "from below";
        const auto through = slab->sample(wo, Vec2(0.0f), 0.9999f, Vec2(0.5f), TransportMode::Radiance);
        ASSERT_TRUE(through.has_value());
        EXPECT_TRUE(through->lobe & BsdfLobe::Null);
        EXPECT_NEAR(through->pdf, transmitted, 1e-6f);
        const auto reflected = slab->sample(wo, Vec2(0.0f), 0.0f, Vec2(0.5f), TransportMode::Radiance);
        ASSERT_TRUE(reflected.has_value());
        EXPECT_FALSE(reflected->lobe & BsdfLobe::Null);
    }
}

// A white floor (albedo rho) lit by a large disk emitter of radiance L (radius
// r, height h) through a thin glass slab halfway up. Under the disk's centre
// the floor's radiance with direct light only (max_depth = 1) is
//   rho / pi * E,   E = int_0^r L T(h / d) h^2 / d^4 2 pi s ds,   d^2 = h^2 + s^2,
// T(cos) = 1 - 2R / (1 + R) the slab's transmittance: shadow rays must pass
// the slab with T, and light-hitting BSDF samples must cross it without using
// up the one allowed scattering event. (Blocking shadow rays renders only the
// BSDF-sampled share; counting the slab renders only the light-sampled share.)
struct ThinSlabScene {
    static constexpr float kRho = 0.8f, kRadiance = 2.0f, kRadius = 2.0f, kHeight = 1.0f, kEta = 1.5f;
    Scene scene;
    double floorRadiance = 0.0;

    explicit ThinSlabScene(float cameraHeight, float fovDegrees) {
        scene.bsdfs.push_back(makeDiffuse(makeConstantTexture(Rgb(kRho))));
        scene.bsdfs.push_back(makeDiffuse(makeConstantTexture(Rgb(0.0f))));
        scene.bsdfs.push_back(makeThinDielectric(kEta));

        Shape floor;
        TriangleMesh plane = makeRectangleMesh();
        plane.transform(glm::scale(Mat4(1.0f), Vec3(6.0f)));
        floor.geometry = plane;
        floor.bsdf = 0;
        scene.shapes.push_back(floor);

        Shape glass;
        TriangleMesh pane = makeRectangleMesh();
        pane.transform(glm::translate(Mat4(1.0f), Vec3(0, 0, 0.5f * kHeight)) * glm::scale(Mat4(1.0f), Vec3(5.0f)));
        glass.geometry = pane;
        glass.bsdf = 2;
        scene.shapes.push_back(glass);

        Shape disk;
        TriangleMesh diskMesh = makeDiskMesh(512);
        diskMesh.transform(glm::translate(Mat4(1.0f), Vec3(0, 0, kHeight)) *
                           glm::rotate(Mat4(1.0f), kPi, Vec3(1, 0, 0)) * glm::scale(Mat4(1.0f), Vec3(kRadius)));
        disk.geometry = diskMesh;
        disk.bsdf = 1;
        disk.areaLight = 0;
        scene.lights.push_back(makeAreaLight(disk, Rgb(kRadiance)));
        scene.lightShape.push_back(2);
        scene.shapes.push_back(disk);

        // Looking straight down at a small patch under the disk's centre.
        scene.camera.eye = Vec3(0.0f, 0.0f, cameraHeight);
        scene.camera.target = Vec3(0.0f, 0.0f, 0.0f);
        scene.camera.up = Vec3(0, 1, 0);
        scene.camera.fovYDegrees = fovDegrees;
        scene.finalize();

        double irradiance = 0.0;
        constexpr int kSteps = 20000;
        for (int i = 0; i < kSteps; ++i) {
            const double s = kRadius * (i + 0.5) / kSteps;
            const double d2 = kHeight * kHeight + s * s;
            irradiance += kRadiance * transmittance(kHeight / std::sqrt(d2)) * kHeight * kHeight / (d2 * d2) * 2.0 *
                          M_PI * s * (kRadius / kSteps);
        }
        floorRadiance = kRho / M_PI * irradiance;
    }

    static double reflectance(double cosTheta) {
        const double single = fresnelDielectric(static_cast<float>(cosTheta), kEta);
        return 2.0 * single / (1.0 + single);
    }
    static double transmittance(double cosTheta) { return 1.0 - reflectance(cosTheta); }
};

TEST(MitsubaFidelityConversion, ThinSlabPassesDirectLightWithoutCountingDepth) {
    // Between floor and slab: the camera sees the floor directly.
    const ThinSlabScene slab(0.2f, 5.0f);
    FilmSettings film;
    film.width = 8;
    film.height = 8;
    const auto image = test::renderPipeline(slab.scene, "pt",
                                            {{"pt.spp", std::int64_t{1024}}, {"pt.max_depth", std::int64_t{1}}}, film);
    const Rgb mean = image.mean();
    // 65536 samples; the per-sample spread is below the mean, so 1 % is many standard errors.
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(mean[c], slab.floorRadiance, 0.01 * slab.floorRadiance) << "channel " << c;
}

// Seen from above the slab, nearly along its normal (a 10 degree field of
// view: R and T change by under 1e-4 across it), the path tracer shows the
// emitter mirrored by the slab plus the floor through it, R L + T(0) rho E / pi;
// the light tracer connects photons (which crossed the slab without counting a
// bounce) to the camera through the slab, T(0) rho E / pi; a specular
// reflection of the emitter is no photon it can connect.
TEST(MitsubaFidelityConversion, ThinSlabSeenThroughInPathAndLightTracing) {
    const ThinSlabScene slab(0.75f, 10.0f);
    const double throughSlab = ThinSlabScene::transmittance(1.0) * slab.floorRadiance;
    const double mirrored = ThinSlabScene::reflectance(1.0) * ThinSlabScene::kRadiance;
    FilmSettings film;
    film.width = 4;
    film.height = 4;
    const Rgb pt = test::renderPipeline(slab.scene, "pt", {{"pt.spp", std::int64_t{4096}}, {"pt.max_depth", std::int64_t{1}}},
                                        film).mean();
    const std::map<std::string, ParamValue> photons = {{"photon.photons", std::int64_t{4000000}},
                                                       {"photon.store", std::string("global")},
                                                       {"photon.store_direct", true},
                                                       {"photon.max_depth", std::int64_t{1}},
                                                       {"photon.differentials", false}};
    const Rgb lt = test::renderPipeline(slab.scene, "lt", photons, film).mean();
    for (int c = 0; c < 3; ++c) {
        EXPECT_NEAR(pt[c], mirrored + throughSlab, 0.01 * (mirrored + throughSlab)) << "pt, channel " << c;
        EXPECT_NEAR(lt[c], throughSlab, 0.03 * throughSlab) << "lt, channel " << c;
    }
}

}  // namespace
}  // namespace fg
