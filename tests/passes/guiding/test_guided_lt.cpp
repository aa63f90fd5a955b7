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

Scene ajarRoom() {
    const std::filesystem::path dir = test::scratchDirectory("guided-lt");
    test::writeText(dir / "ajar-room.toml", test::kAjarRoom);
    return loadScene((dir / "ajar-room.toml").string());
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
    double imageRelativeSigma = 0.0;       // standard error of the difference of the image means / lt's mean
    double imageRelativeDifference = 0.0;  // (guided - lt) / lt of the image means
    double varianceRatio = 0.0;            // guided / lt variance of the block means, summed over blocks
};

// Guided lt with one trained cache against lt, over `seeds` independent
// renders of each (guiding must be unbiased for every cache, so the cache is
// trained once). Per 4x4 block and for the whole image, z = difference of the
// means / its standard error from the seeds' spread.
MeanComparison compareMeans(const Scene& scene, const BufferHandle& cache, int seeds, std::int64_t photons, double alpha) {
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
    std::printf("%s: worst block z %.2f, image z %.2f (guided - lt: %+.4f of the mean, sigma %.4f), guided/lt variance %.3f\n",
                what, c.worstBlockZ, c.imageZ, c.imageRelativeDifference, c.imageRelativeSigma, c.varianceRatio);
}

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
    const std::vector<Rgb> one = render(1), two = render(2);
    ASSERT_EQ(one.size(), two.size());
    double sum = 0.0;
    for (const Rgb& p : one) sum += p.x + p.y + p.z;
    EXPECT_GT(sum, 0.0);
    EXPECT_EQ(std::memcmp(one.data(), two.data(), one.size() * sizeof(Rgb)), 0);
}

}  // namespace
}  // namespace fg
