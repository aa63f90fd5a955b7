// Guided environment emission (Vorba et al. 2014, §4.4): in a closed box
// under a constant sky whose only opening is a small square in its ceiling,
// importons leave through the opening, the environment sampler trained on
// them sends more photons into the box, and the photon map's flux inside the
// box keeps the unguided map's mean; the model and the guided photons are the
// same at 1 and 2 threads, a saved model loads as saved, and an empty model
// traces the unguided photons bit for bit.
#include "engine/accel/ray_query.h"
#include "engine/buffers/photon_buffers.h"
#include "engine/core/codec.h"
#include "engine/core/job.h"
#include "engine/guiding/environment_guide.h"
#include "engine/guiding/importons.h"
#include "engine/image/image_io.h"
#include "engine/scene/scene_loader.h"
#include "passes/passes.h"
#include "tests/support/cli_helpers.h"
#include "tests/support/pass_helpers.h"
#include "tests/support/render_helpers.h"
#include "tests/support/sun_sky.h"

#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <memory>

namespace fg {
namespace {

constexpr float kHole = 0.25f;  // half the opening's side

// The box [-1, 1]³ of one-sided diffuse walls facing inwards (their outsides
// absorb), its ceiling four rectangles around the opening, the camera inside.
std::string boxText(const char* light) {
    const auto rect = [](const std::string& transform) {
        return "[[shape]]\ntype = \"rectangle\"\nmaterial = \"wall\"\ntransform = [" + transform + "]\n";
    };
    const std::string h = std::to_string(kHole), a = std::to_string(0.5f * (1.0f - kHole)),
                      c = std::to_string(0.5f * (1.0f + kHole));
    std::string text = R"(
[camera]
eye = [0.0, -0.7, -0.4]
target = [0.1, 0.5, -0.9]
fov = 75
[[material]]
name = "wall"
type = "diffuse"
reflectance = 0.7
)";
    text += rect("{ translate = [0, 0, -1] }");
    text += rect("{ rotate = { axis = [0, 1, 0], angle = 90 } }, { translate = [-1, 0, 0] }");
    text += rect("{ rotate = { axis = [0, 1, 0], angle = -90 } }, { translate = [1, 0, 0] }");
    text += rect("{ rotate = { axis = [1, 0, 0], angle = -90 } }, { translate = [0, -1, 0] }");
    text += rect("{ rotate = { axis = [1, 0, 0], angle = 90 } }, { translate = [0, 1, 0] }");
    const std::string flip = "{ rotate = { axis = [1, 0, 0], angle = 180 } }";
    text += rect("{ scale = [" + a + ", 1, 1] }, " + flip + ", { translate = [-" + c + ", 0, 1] }");
    text += rect("{ scale = [" + a + ", 1, 1] }, " + flip + ", { translate = [" + c + ", 0, 1] }");
    text += rect("{ scale = [" + h + ", " + a + ", 1] }, " + flip + ", { translate = [0, -" + c + ", 1] }");
    text += rect("{ scale = [" + h + ", " + a + ", 1] }, " + flip + ", { translate = [0, " + c + ", 1] }");
    return text + light;
}

Scene loadBox(const char* name, const char* light) {
    const std::filesystem::path dir = test::scratchDirectory("guided-environment");
    test::writeText(dir / name, boxText(light));
    return loadScene((dir / name).string());
}

Scene skyBox() { return loadBox("sky-box.toml", "[[light]]\ntype = \"constant\"\nradiance = 1.0\n"); }

// The box under a 256 x 128 sky of radiance about 1 with a sun of 1.5°
// radius 17° from the zenith, holding about 80 % of the sky's radiant
// integral, whose light falls through the opening onto the floor.
Scene sunBox() {
    const std::filesystem::path dir = test::scratchDirectory("guided-environment");
    ImageChannels sky;
    sky.width = 256;
    sky.height = 128;
    sky.rgb = test::sunSkyPixels(sky.width, sky.height, Vec3(0.25f, 0.15f, 0.955f), 1.5f, 20000.0f);
    writeExr((dir / "sun-sky.exr").string(), sky, {});
    test::writeText(dir / "sun-box.toml", boxText("[[light]]\ntype = \"envmap\"\nfile = \"sun-sky.exr\"\n"));
    return loadScene((dir / "sun-box.toml").string());
}

// Training the environment sampler alone: importons, then its update, carried.
Pipeline trainingPipeline(int passes, const std::string& tail = "", const std::string& result = "environment") {
    return parsePipelineFile("[pipeline]\nname = \"env-training\"\nresults = [\"" + result +
                                 "\"]\n[[pipeline.repeat]]\nname = \"train\"\ncount = " + std::to_string(passes) +
                                 R"(
carry = { environment = "environment" }
[[pipeline.repeat.pass]]
pass = "importon"
outputs = { importons = "training_importons", exits = "training_exits" }
[[pipeline.repeat.pass]]
pass = "environment_update"
inputs = { exits = "training_exits", previous = "environment" }
outputs = { environment = "environment" }
)" + tail,
                             "env-training.toml");
}

const std::map<std::string, ParamValue> kTrainingParams{{"importon.spp", std::int64_t{16}}};

BufferHandle trainedModel(const Scene& scene, int passes, std::uint64_t seed, int threads = 0) {
    return test::runPipeline(scene, trainingPipeline(passes), builtinRegistry().passes, kTrainingParams,
                             test::smallFilm(32, 32), "environment", seed, threads);
}

std::map<std::string, ParamValue> photonParams(std::int64_t photons) {
    return {{"photons", photons}, {"store", std::string("global")}, {"store_direct", true}, {"differentials", false}};
}

// Whether a photon was stored inside the box: on a wall's inner face, having
// arrived from the inside (the outer faces sit at the same coordinates).
bool inside(const Vec3& p, const Vec3& incident) {
    for (int axis = 0; axis < 3; ++axis)
        if (std::abs(p[axis]) > 0.999f) return incident[axis] * p[axis] < 0.0f;
    return true;
}

// Regions inside: the floor, the four walls, the ceiling; then all of it.
constexpr int kRegions = 4;
std::array<double, kRegions> regionFlux(const PhotonMap& map, double* entered) {
    std::array<double, kRegions> flux{};
    const auto positions = map.photons.column<PhotonPosition>();
    const auto incident = map.photons.column<PhotonIncident>();
    const auto power = map.photons.column<PhotonPower>();
    const auto classes = map.photons.column<PhotonClassColumn>();
    std::size_t count = 0;
    for (std::size_t i = 0; i < map.photons.size(); ++i) {
        const Vec3& p = positions[i];
        if (!inside(p, incident[i])) continue;
        // A path's first event inside: the photon came in through the opening.
        count += classes[i] == PhotonClass::Direct ? 1 : 0;
        const double phi = (power[i].x + power[i].y + power[i].z) / 3.0;
        const int region = p.z < -0.999f ? 0 : (p.z > 0.999f ? 2 : 1);
        flux[static_cast<std::size_t>(region)] += phi;
        flux[kRegions - 1] += phi;
    }
    *entered = static_cast<double>(count) / static_cast<double>(map.emitted);
    return flux;
}

// The importons that left went through the opening: their lines cross the
// ceiling's plane within it, and their exit points lie on the bounding sphere.
TEST(GuidedEnvironment, ImportonsLeaveThroughTheOpening) {
    const Scene scene = skyBox();
    const RayQuery rays(scene);
    const auto out = test::runPass(importonPass(), scene, &rays, test::smallFilm(16, 16), {},
                                   {{"spp", std::int64_t{16}}}, 3);
    const ImportonExits& exits = test::bufferAs<ImportonExits>(out.at("exits"));
    ASSERT_GT(exits.exits.size(), 50u);
    const Vec3 center = 0.5f * (scene.boundsMin + scene.boundsMax);
    const float radius = glm::length(scene.boundsMax - center);
    const auto position = exits.exits.column<ExitPosition>();
    const auto direction = exits.exits.column<ExitDirection>();
    std::size_t scattered = 0;
    for (std::size_t i = 0; i < exits.exits.size(); ++i) {
        EXPECT_NEAR(glm::length(position[i] - center), radius, 1e-3f * radius);
        ASSERT_GT(direction[i].z, 0.0f);
        const Vec3 atCeiling = position[i] + ((1.0f - position[i].z) / direction[i].z) * direction[i];
        EXPECT_LE(std::abs(atCeiling.x), kHole + 1e-3f);
        EXPECT_LE(std::abs(atCeiling.y), kHole + 1e-3f);
        scattered += exits.exits.column<ExitBounces>()[i] > 0 ? 1 : 0;
    }
    EXPECT_GT(scattered, exits.exits.size() / 2);

    // Without an environment emitter nothing is recorded, and the model is empty.
    const Scene lit = loadBox("lamp-box.toml", "[[light]]\ntype = \"point\"\nposition = [0, 0, 0]\nintensity = 1.0\n");
    const RayQuery litRays(lit);
    const auto none = test::runPass(importonPass(), lit, &litRays, test::smallFilm(16, 16), {},
                                    {{"spp", std::int64_t{4}}}, 3);
    EXPECT_EQ(test::bufferAs<ImportonExits>(none.at("exits")).exits.size(), 0u);
    EXPECT_FALSE(test::bufferAs<EnvironmentGuide>(trainedModel(lit, 1, 3)).guides());
}

// The flux the photon map puts inside the box, per region, over 20
// independent seeds guided by one trained model and 20 unguided: the means
// agree within 3 sigma of their difference. Returns the shares of the guided
// and unguided photon paths that enter the box (their first event inside) and
// the ratio of the guided to the unguided variance of the flux inside.
struct GuidedOutcome {
    double guidedShare = 0.0, plainShare = 0.0, varianceRatio = 0.0;
};
GuidedOutcome expectSameFluxAsUnguided(const Scene& scene, std::uint64_t trainingSeed) {
    const BufferHandle model = trainedModel(scene, 3, trainingSeed);
    const EnvironmentGuide& guide = test::bufferAs<EnvironmentGuide>(model);
    EXPECT_TRUE(guide.guides());
    std::size_t fitted = 0;
    for (std::uint32_t f : guide.cells.column<EnvCellFitted>()) fitted += f;
    EXPECT_GT(fitted, 0u);
    const RayQuery rays(scene);
    const PassRegistration photon = photonPass();
    constexpr int kSeeds = 20;
    std::array<std::array<double, kSeeds>, kRegions> guided{}, plain{};
    GuidedOutcome outcome;
    double& guidedShare = outcome.guidedShare;
    double& plainShare = outcome.plainShare;
    for (int s = 0; s < kSeeds; ++s) {
        const auto seed = static_cast<std::uint64_t>(200 + s);
        const auto withModel = test::runPass(photon, scene, &rays, test::smallFilm(8, 8), {{"environment", model}},
                                             photonParams(20000), seed);
        const auto without = test::runPass(photon, scene, &rays, test::smallFilm(8, 8), {}, photonParams(20000),
                                           seed + 1000);
        double gs = 0.0, ps = 0.0;
        const auto fg = regionFlux(test::bufferAs<PhotonMap>(withModel.at("global_photons")), &gs);
        const auto fp = regionFlux(test::bufferAs<PhotonMap>(without.at("global_photons")), &ps);
        for (int r = 0; r < kRegions; ++r) guided[r][s] = fg[r], plain[r][s] = fp[r];
        guidedShare += gs / kSeeds;
        plainShare += ps / kSeeds;
    }
    for (int r = 0; r < kRegions; ++r) {
        double mg = 0, mp = 0, vg = 0, vp = 0;
        for (int s = 0; s < kSeeds; ++s) mg += guided[r][s] / kSeeds, mp += plain[r][s] / kSeeds;
        for (int s = 0; s < kSeeds; ++s) vg += sqr(guided[r][s] - mg), vp += sqr(plain[r][s] - mp);
        vg /= kSeeds - 1;
        vp /= kSeeds - 1;
        const double sigma = std::sqrt((vg + vp) / kSeeds);
        EXPECT_GT(mp, 0.0) << "region " << r;
        const double z = std::abs(mg - mp) / std::max(sigma, 1e-12);
        std::printf("region %d: guided %.5f unguided %.5f (sigma of the difference %.2f %% of the mean, z %.2f, "
                    "guided/unguided variance %.3f)\n",
                    r, mg, mp, 100.0 * sigma / mp, z, vg / vp);
        EXPECT_LT(z, 3.0) << "region " << r << ": guided " << mg << ", unguided " << mp;
        outcome.varianceRatio = vg / vp;
    }
    std::printf("emitted photon paths entering the box: guided %.2f %%, unguided %.2f %%\n", 100.0 * guidedShare,
                100.0 * plainShare);
    return outcome;
}

// Under a constant sky a larger share of the guided photon paths enters the box.
TEST(GuidedEnvironment, SameFluxAsUnguidedAndMorePhotonsInside) {
    const GuidedOutcome outcome = expectSameFluxAsUnguided(skyBox(), 11);
    EXPECT_GT(outcome.guidedShare, 10.0 * outcome.plainShare);
}

// Under a sky with a small sun, most of whose light enters through the
// opening, the product p_W p_L follows the sun inside its bitmap cell. When
// the product took the cell's mean luminance at 4 points instead, the sun was
// reached only through the p_L half of the mixture: with this model 32.8 % of
// the guided paths entered the box (unguided 2.2 %), and the variance of the
// flux inside was 0.67 of the unguided one; following the sun, 35.1 % and 0.25.
TEST(GuidedEnvironment, SameFluxAsUnguidedUnderASmallSun) {
    const GuidedOutcome outcome = expectSameFluxAsUnguided(sunBox(), 11);
    EXPECT_GT(outcome.guidedShare, 0.328);
    EXPECT_LT(outcome.varianceRatio, 0.5);
}

// An empty model (a scene without environment emitter makes one) guides
// nothing: the photons are those of the pass without the input, bit for bit.
TEST(GuidedEnvironment, EmptyModelTracesUnguidedPhotons) {
    const Scene scene = skyBox();
    const RayQuery rays(scene);
    const PassRegistration photon = photonPass();
    const BufferHandle empty = test::makeBuffer(std::make_shared<EnvironmentGuide>());
    const std::filesystem::path dir = test::scratchDirectory("guided-environment");
    const auto a = test::runPass(photon, scene, &rays, test::smallFilm(8, 8), {{"environment", empty}},
                                 photonParams(20000), 3);
    const auto b = test::runPass(photon, scene, &rays, test::smallFilm(8, 8), {}, photonParams(20000), 3);
    ASSERT_GT(test::bufferAs<PhotonMap>(b.at("global_photons")).photons.size(), 100u);
    saveBuffer(a.at("global_photons"), (dir / "empty.fgbuf").string(), "");
    saveBuffer(b.at("global_photons"), (dir / "none.fgbuf").string(), "");
    EXPECT_TRUE(test::readText(dir / "empty.fgbuf") == test::readText(dir / "none.fgbuf"));
}

// The trained model and the photons it guides are the same bytes at 1 and 2
// threads; the saved model loads as saved.
TEST(GuidedEnvironment, IdenticalAtOneAndTwoThreadsAndLoadsAsSaved) {
    const Scene scene = skyBox();
    const std::filesystem::path dir = test::scratchDirectory("guided-environment");
    const Pipeline withPhotons = trainingPipeline(2, R"([[pipeline.pass]]
pass = "photon"
inputs = { environment = "environment" }
outputs = { global_photons = "photons" }
)",
                                                  "photons");
    std::map<std::string, ParamValue> params = kTrainingParams;
    for (const auto& [name, value] : photonParams(20000)) params["photon." + name] = value;
    const auto bytes = [&](const std::string& name, const BufferHandle& buffer) {
        const std::filesystem::path path = dir / (name + ".fgbuf");
        saveBuffer(buffer, path.string(), "");
        return test::readText(path);
    };
    const std::string model1 = bytes("model1", trainedModel(scene, 2, 5, 1));
    const std::string model2 = bytes("model2", trainedModel(scene, 2, 5, 2));
    EXPECT_GT(model1.size(), 1000u);
    EXPECT_TRUE(model1 == model2) << "the environment samplers trained at 1 and 2 threads differ";
    const auto photons = [&](int threads) {
        return test::runPipeline(scene, withPhotons, builtinRegistry().passes, params, test::smallFilm(16, 16),
                                 "photons", 5, threads);
    };
    EXPECT_TRUE(bytes("photons1", photons(1)) == bytes("photons2", photons(2)))
        << "the guided photons traced at 1 and 2 threads differ";

    const BufferHandle loaded = loadBuffer((dir / "model1.fgbuf").string(), "EnvironmentGuide");
    EXPECT_TRUE(bytes("model1-again", loaded) == model1);
}

}  // namespace
}  // namespace fg
