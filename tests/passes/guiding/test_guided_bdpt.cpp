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

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>

namespace fg {
namespace {

constexpr int kSize = 16;
constexpr int kBlock = 4;

std::map<std::string, ParamValue> trainingParams(std::int64_t photons) {
    return {{"importon.spp", std::int64_t{4}},
            {"photon.photons", photons},
            {"photon.store", std::string("global")},
            {"photon.differentials", false},
            // Fewer training particles than the paper's 250, to keep the tests short.
            {"radiance_update.training_particles", std::int64_t{64}},
            {"importance_update.training_particles", std::int64_t{64}}};
}

Scene ajarRoom() {
    const std::filesystem::path dir = test::scratchDirectory("guided-bdpt");
    test::writeText(dir / "ajar-room.toml", test::kAjarRoom);
    return loadScene((dir / "ajar-room.toml").string());
}

struct Caches {
    BufferHandle radiance, importance;
};

// Both caches of the built-in training block (the same run twice: training is deterministic).
Caches trainedCaches(const Scene& scene, std::int64_t photons, std::uint64_t seed) {
    const auto train = [&](const std::string& result) {
        return test::runPipeline(scene, test::guidedTrainingPipeline(2, result), builtinRegistry().passes,
                                 trainingParams(photons), test::smallFilm(kSize, kSize), result, seed);
    };
    Caches caches{train("radiance_cache"), train("importance_cache")};
    EXPECT_GT(test::bufferAs<GuidingCache>(caches.radiance).records.size(), 10u);
    EXPECT_GT(test::bufferAs<GuidingCache>(caches.importance).records.size(), 10u);
    return caches;
}

// Per image: the 4x4-block means, then the image mean as one more entry.
std::vector<double> means(const BufferHandle& image) {
    const int blocksPerSide = kSize / kBlock;
    std::vector<double> m(static_cast<std::size_t>(blocksPerSide * blocksPerSide) + 1, 0.0);
    const std::vector<Rgb> px = test::bufferAs<Film>(image).resolve();
    for (int y = 0; y < kSize; ++y)
        for (int x = 0; x < kSize; ++x) {
            const Rgb& p = px[static_cast<std::size_t>(y * kSize + x)];
            const double v = (p.x + p.y + p.z) / 3.0;
            m[static_cast<std::size_t>((y / kBlock) * blocksPerSide + x / kBlock)] += v / (kBlock * kBlock);
            m.back() += v / (kSize * kSize);
        }
    return m;
}

struct MeanComparison {
    double worstBlockZ = 0.0;
    double imageZ = 0.0;
    double imageRelativeSigma = 0.0;       // standard error of the difference of the image means / bdpt's mean
    double imageRelativeDifference = 0.0;  // (guided - bdpt) / bdpt of the image means
    double varianceRatio = 0.0;            // guided / bdpt variance of the block means, summed over blocks
};

std::map<std::string, ParamValue> bdptParams(std::int64_t spp) {
    return {{"spp", spp}, {"max_depth", std::int64_t{13}}};
}

// Guided bdpt with caches trained once against bdpt, over `seeds` independent
// renders of each (guiding must be unbiased for any caches). Per 4x4 block
// and for the whole image, z = difference of the means / its standard error
// from the seeds' spread.
MeanComparison compareMeans(const Scene& scene, const Caches& caches, int seeds, std::int64_t spp, double alpha) {
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
    MeanComparison result;
    double varianceA = 0.0, varianceB = 0.0;
    const std::size_t blocks = a.front().size() - 1;
    for (std::size_t k = 0; k <= blocks; ++k) {
        double ma = 0, mb = 0, va = 0, vb = 0;
        for (int i = 0; i < seeds; ++i) ma += a[i][k] / seeds, mb += b[i][k] / seeds;
        for (int i = 0; i < seeds; ++i) va += sqr(a[i][k] - ma), vb += sqr(b[i][k] - mb);
        va /= seeds - 1;
        vb /= seeds - 1;
        const double sigma = std::sqrt((va + vb) / seeds);
        const double z = std::abs(ma - mb) / std::max(sigma, 1e-12);
        if (k == blocks) {
            result.imageZ = z;
            result.imageRelativeSigma = sigma / mb;
            result.imageRelativeDifference = (ma - mb) / mb;
        } else {
            result.worstBlockZ = std::max(result.worstBlockZ, z);
            varianceA += va;
            varianceB += vb;
        }
    }
    result.varianceRatio = varianceA / varianceB;
    return result;
}

// Thresholds as guided pt's: 16 blocks at |z| < 4.5 fail together with
// probability about 16 x 7e-5 (t with 38 degrees of freedom) when both means
// are the same; the image mean at |z| < 4 with about 1e-4.
void expectSameMean(const MeanComparison& c, const char* what) {
    EXPECT_LT(c.worstBlockZ, 4.5) << what;
    EXPECT_LT(c.imageZ, 4.0) << what << ": image means differ by " << c.imageZ << " sigma (sigma = " << c.imageRelativeSigma
                             << " of the mean)";
    std::printf("%s: worst block z %.2f, image z %.2f (guided - bdpt: %+.4f of the mean, sigma %.4f), guided/bdpt variance %.3f\n",
                what, c.worstBlockZ, c.imageZ, c.imageRelativeDifference, c.imageRelativeSigma, c.varianceRatio);
}

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
    auto params = trainingParams(20000);
    params["bdpt.spp"] = std::int64_t{4};
    const auto render = [&](int threads) {
        const BufferHandle image = test::runPipeline(scene, builtinGuidedBdpt(), builtinRegistry().passes, params,
                                                     test::smallFilm(kSize, kSize), "image", 5, threads);
        return test::bufferAs<Film>(image).resolve();
    };
    const std::vector<Rgb> one = render(1), two = render(2);
    ASSERT_EQ(one.size(), two.size());
    double sum = 0.0;
    for (const Rgb& p : one) sum += p.x + p.y + p.z;
    EXPECT_GT(sum, 0.0);
    EXPECT_EQ(std::memcmp(one.data(), two.data(), one.size() * sizeof(Rgb)), 0);
}

}  // namespace
}  // namespace fg
