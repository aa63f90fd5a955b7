// Guided bidirectional path tracing (Vorba et al. 2014, Fig. 1): bdpt with
// camera subpaths guided by the radiance cache and light subpaths by the
// importance cache has unguided bdpt's mean (4x4 blocks and the image mean,
// z from independent seeds, in the occluded room and the Cornell box, at the
// default alpha and at a mixture that draws 95 % of its directions from the
// GMMs), and the guided-bdpt image is the same at 1 and 2 threads.
#include "engine/accel/ray_query.h"
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

Scene ajarRoom() { return test::loadAjarRoom("guided-bdpt"); }

struct Caches {
    BufferHandle radiance, importance;
};

// Both caches of the built-in training block (the same run twice: training is deterministic).
Caches trainedCaches(const Scene& scene, std::int64_t photons, std::uint64_t seed) {
    const auto train = [&](const std::string& result) {
        return test::runPipeline(scene, test::guidedTrainingPipeline(2, result), builtinRegistry().passes,
                                 test::bothCachesTrainingParams(photons), test::smallFilm(kSize, kSize), result, seed);
    };
    Caches caches{train("radiance_cache"), train("importance_cache")};
    EXPECT_GT(test::bufferAs<GuidingCache>(caches.radiance).records.size(), 10u);
    EXPECT_GT(test::bufferAs<GuidingCache>(caches.importance).records.size(), 10u);
    return caches;
}

std::vector<double> means(const BufferHandle& image) { return test::blockMeans(test::bufferAs<Film>(image)); }

std::map<std::string, ParamValue> bdptParams(std::int64_t spp) {
    return {{"spp", spp}, {"max_depth", std::int64_t{13}}};
}

// Guided bdpt with caches trained once against bdpt, over `seeds` independent
// renders of each (guiding must be unbiased for any caches). Per 4x4 block
// and for the whole image, z = difference of the means / its standard error
// from the seeds' spread.
test::MeanComparison compareMeans(const Scene& scene, const Caches& caches, int seeds, std::int64_t spp, double alpha) {
    const RayQuery rays(scene);
    const PassRegistration bdpt = bdptPass();
    auto guidedParams = bdptParams(spp);
    guidedParams["guiding_bsdf_probability"] = alpha;
    std::vector<std::vector<double>> a, b;
    for (int seed = 1; seed <= seeds; ++seed) {
        const auto s = static_cast<std::uint64_t>(seed);
        a.push_back(means(test::runPass(bdpt, scene, &rays, test::smallFilm(kSize, kSize),
                                        {{"radiance_cache", caches.radiance}, {"importance_cache", caches.importance}},
                                        guidedParams, s)
                              .at("image")));
        b.push_back(means(test::runPass(bdpt, scene, &rays, test::smallFilm(kSize, kSize), {}, bdptParams(spp), s + 1000)
                              .at("image")));
    }
    return test::compareSeedMeans(a, b);
}

void expectSameMean(const test::MeanComparison& c, const char* what) { test::expectSameMean(c, what, "guided", "bdpt"); }

// The caches must change the paths for the mean tests to mean anything: with
// the same seed, each cache alone changes the image.
void expectEachCacheChangesImage(const Scene& scene, const Caches& caches) {
    const RayQuery rays(scene);
    const PassRegistration bdpt = bdptPass();
    const auto render = [&](std::map<std::string, BufferHandle> inputs) {
        return test::bufferAs<Film>(
                   test::runPass(bdpt, scene, &rays, test::smallFilm(kSize, kSize), std::move(inputs), bdptParams(2), 7)
                       .at("image"))
            .resolve();
    };
    const std::vector<Rgb> plain = render({});
    const std::vector<Rgb> radiance = render({{"radiance_cache", caches.radiance}});
    const std::vector<Rgb> importance = render({{"importance_cache", caches.importance}});
    EXPECT_NE(std::memcmp(plain.data(), radiance.data(), plain.size() * sizeof(Rgb)), 0);
    EXPECT_NE(std::memcmp(plain.data(), importance.data(), plain.size() * sizeof(Rgb)), 0);
}

TEST(GuidedBdpt, SameMeanAsBdptInOccludedRoom) {
    const Scene scene = ajarRoom();
    const Caches caches = trainedCaches(scene, 20000, 31);
    expectEachCacheChangesImage(scene, caches);
    expectSameMean(compareMeans(scene, caches, 20, 8, 0.5), "occluded room, alpha 0.5");
}

// A mixture that draws 95 % of its directions from the GMMs: the mixture
// densities differ most from the BSDF's, in the weights f cos / p_mix and in
// the MIS weights, so a density from the wrong cache or side moves the mean.
TEST(GuidedBdpt, SameMeanAsBdptWithStrongMixture) {
    const Scene scene = ajarRoom();
    const Caches caches = trainedCaches(scene, 20000, 32);
    expectSameMean(compareMeans(scene, caches, 20, 8, 0.05), "occluded room, alpha 0.05");
}

TEST(GuidedBdpt, SameMeanAsBdptOnCornellBox) {
    const Scene scene = loadScene(test::sourcePath("data/cornell-box/cornell-box.toml"));
    const Caches caches = trainedCaches(scene, 4000, 33);
    expectSameMean(compareMeans(scene, caches, 20, 4, 0.5), "cornell-box, alpha 0.5");
}

// The built-in guided-bdpt pipeline with 2 training passes instead of its 30.
Pipeline builtinGuidedBdpt() {
    std::string text = test::readText(test::sourcePath("passes/pipelines/guided-bdpt.toml"));
    const std::string count = "count = 30";
    const std::size_t at = text.find(count);
    EXPECT_NE(at, std::string::npos) << "guided-bdpt.toml no longer trains 30 passes";
    if (at != std::string::npos) text.replace(at, count.size(), "count = 2");
    return parsePipelineFile(text, "guided-bdpt.toml");
}

TEST(GuidedBdpt, ImageIdenticalAtOneAndTwoThreads) {
    const Scene scene = ajarRoom();
    auto params = test::bothCachesTrainingParams(20000);
    params["bdpt.spp"] = std::int64_t{4};
    const auto render = [&](int threads) {
        const BufferHandle image = test::runPipeline(scene, builtinGuidedBdpt(), builtinRegistry().passes, params,
                                                     test::smallFilm(kSize, kSize), "image", 5, threads);
        return test::bufferAs<Film>(image).resolve();
    };
    test::expectSameNonBlackImage(render(1), render(2));
}

}  // namespace
}  // namespace fg
