// Guided light tracing (Vorba et al. 2014, the light half of the Fig. 1
// loop): the built-in guided-lt pipeline trains an importance cache on
// importons, the photon pass draws the light subpaths from the mixture
// alpha p_bsdf + (1 - alpha) p_gmm weighted by f cos / p_mix, and light_trace
// connects them to the camera. The guided image has lt's mean (4x4 blocks and
// the image mean, z from independent seeds, in the occluded room and the
// Cornell box, at the default alpha and at a mixture that draws 95 % of its
// directions from the GMMs, where a wrong weight shows at once), and the
// guided-lt image is the same at 1 and 2 threads.
#include "engine/accel/ray_query.h"
#include "engine/buffers/photon_buffers.h"
#include "engine/core/job.h"
#include "engine/guiding/guiding_cache.h"
#include "engine/scene/scene_loader.h"
#include "passes/passes.h"
#include "tests/passes/guiding/ajar_room.h"
#include "tests/support/cli_helpers.h"
#include "tests/support/guiding_pipeline.h"
#include "tests/support/pass_helpers.h"
#include "tests/support/render_helpers.h"
#include "tests/support/seed_means.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>

namespace fg {
namespace {

constexpr int kSize = 16;

// The built-in guided-lt pipeline (passes/pipelines/guided-lt.toml) with
// `trainingPasses` instead of its 30 training passes.
Pipeline builtinGuidedLt(int trainingPasses) {
    std::string text = test::readText(test::sourcePath("passes/pipelines/guided-lt.toml"));
    const std::string count = "count = 30";
    const std::size_t at = text.find(count);
    EXPECT_NE(at, std::string::npos) << "guided-lt.toml no longer trains 30 passes";
    if (at != std::string::npos) text.replace(at, count.size(), "count = " + std::to_string(trainingPasses));
    return parsePipelineFile(text, "guided-lt.toml");
}

std::map<std::string, ParamValue> lightPathParams(std::int64_t photons) {
    return {{"photons", photons}, {"store", std::string("surface")}, {"store_direct", true}, {"differentials", false}};
}

std::map<std::string, ParamValue> pipelineParams(std::int64_t trainingPhotons, std::int64_t photons) {
    std::map<std::string, ParamValue> params{{"importon.spp", std::int64_t{4}},
                                             {"training_photon.photons", trainingPhotons},
                                             {"training_photon.store", std::string("global")},
                                             {"training_photon.store_direct", true},
                                             {"training_photon.differentials", false},
                                             // Fewer training particles than the paper's 250, to keep the tests short.
                                             {"importance_update.training_particles", std::int64_t{64}}};
    for (const auto& [key, value] : lightPathParams(photons)) params["photon." + key] = value;
    return params;
}

Scene ajarRoom() { return test::loadAjarRoom("guided-lt"); }

std::vector<double> means(const BufferHandle& image) { return test::blockMeans(test::bufferAs<Film>(image)); }

// Guided lt with one trained cache against lt, over `seeds` independent
// renders of each (guiding must be unbiased for every cache, so the cache is
// trained once). Per 4x4 block and for the whole image, z = difference of the
// means / its standard error from the seeds' spread.
test::MeanComparison compareMeans(const Scene& scene, const BufferHandle& cache, int seeds, std::int64_t photons, double alpha) {
    const RayQuery rays(scene);
    const PassRegistration photon = photonPass(), connect = lightTracePass();
    auto guidedParams = lightPathParams(photons);
    guidedParams["guiding_bsdf_probability"] = alpha;
    const auto render = [&](bool guided, std::uint64_t seed) {
        std::map<std::string, BufferHandle> inputs;
        if (guided) inputs["importance_cache"] = cache;
        const auto maps = test::runPass(photon, scene, &rays, test::smallFilm(kSize, kSize), inputs,
                                        guided ? guidedParams : lightPathParams(photons), seed);
        return test::runPass(connect, scene, &rays, test::smallFilm(kSize, kSize),
                             {{"caustic_photons", maps.at("caustic_photons")}, {"global_photons", maps.at("global_photons")}},
                             {}, seed)
            .at("image");
    };
    std::vector<std::vector<double>> a, b;
    for (int seed = 1; seed <= seeds; ++seed) {
        const auto s = static_cast<std::uint64_t>(seed);
        a.push_back(means(render(true, s)));
        b.push_back(means(render(false, s + 1000)));
    }
    return test::compareSeedMeans(a, b);
}

void expectSameMean(const test::MeanComparison& c, const char* what) { test::expectSameMean(c, what, "guided", "lt"); }

// The importance cache the built-in pipeline's training block makes.
BufferHandle trainedCache(const Scene& scene, std::uint64_t seed) {
    const BufferHandle cache =
        test::runPipeline(scene, builtinGuidedLt(3), builtinRegistry().passes, pipelineParams(20000, 1000),
                          test::smallFilm(kSize, kSize), "importance_cache", seed);
    EXPECT_GT(test::bufferAs<GuidingCache>(cache).records.size(), 10u);
    return cache;
}

// The cache must change the light paths for the mean tests to mean anything:
// with the same seed, the guided photons are not the unguided ones.
void expectGuidingChangesPhotons(const Scene& scene, const BufferHandle& cache) {
    const RayQuery rays(scene);
    const PassRegistration photon = photonPass();
    const auto guided = test::runPass(photon, scene, &rays, test::smallFilm(kSize, kSize), {{"importance_cache", cache}},
                                      lightPathParams(2000), 7);
    const auto plain = test::runPass(photon, scene, &rays, test::smallFilm(kSize, kSize), {}, lightPathParams(2000), 7);
    const auto positions = [](const BufferHandle& map) {
        const auto column = test::bufferAs<PhotonMap>(map).photons.column<PhotonPosition>();
        return std::vector<Vec3>(column.begin(), column.end());
    };
    EXPECT_NE(positions(guided.at("global_photons")), positions(plain.at("global_photons")));
}

TEST(GuidedLt, SameMeanAsLtInOccludedRoom) {
    const Scene scene = ajarRoom();
    const BufferHandle cache = trainedCache(scene, 21);
    expectGuidingChangesPhotons(scene, cache);
    expectSameMean(compareMeans(scene, cache, 20, 20000, 0.5), "occluded room, alpha 0.5");
}

// A mixture that draws 95 % of its directions from the GMMs: the weight
// f cos / p_mix differs most from BSDF sampling's f cos / p_bsdf, so a photon
// weighted by the wrong density (or by the GMM's alone) moves the mean.
TEST(GuidedLt, SameMeanAsLtWithStrongMixture) {
    const Scene scene = ajarRoom();
    const BufferHandle cache = trainedCache(scene, 22);
    expectSameMean(compareMeans(scene, cache, 20, 20000, 0.05), "occluded room, alpha 0.05");
}

TEST(GuidedLt, SameMeanAsLtOnCornellBox) {
    const Scene scene = loadScene(test::sourcePath("data/cornell-box/cornell-box.toml"));
    const BufferHandle cache = trainedCache(scene, 23);
    expectSameMean(compareMeans(scene, cache, 20, 4000, 0.5), "cornell-box, alpha 0.5");
}

TEST(GuidedLt, ImageIdenticalAtOneAndTwoThreads) {
    const Scene scene = ajarRoom();
    const auto render = [&](int threads) {
        const BufferHandle image = test::runPipeline(scene, builtinGuidedLt(2), builtinRegistry().passes,
                                                     pipelineParams(20000, 20000), test::smallFilm(kSize, kSize), "image",
                                                     5, threads);
        return test::bufferAs<Film>(image).resolve();
    };
    test::expectSameNonBlackImage(render(1), render(2));
}

}  // namespace
}  // namespace fg
