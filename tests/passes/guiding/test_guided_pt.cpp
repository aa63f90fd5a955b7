// Guided path tracing (Vorba et al. 2014): the guided image has the unguided
// one's mean (4x4-pixel blocks and the image mean, z from independent seeds,
// on the Cornell box and an occluded room), the furnace sphere still gives radiance 1, and the
// trained caches and the image are the same at 1 and 2 threads.
#include "engine/core/codec.h"
#include "engine/core/error.h"
#include "engine/core/job.h"
#include "engine/accel/ray_query.h"
#include "engine/guiding/guiding_cache.h"
#include "engine/guiding/importons.h"
#include "engine/scene/scene_loader.h"
#include "engine/shading/bsdf.h"
#include "engine/shading/light.h"
#include "passes/passes.h"
#include "tests/support/cli_helpers.h"
#include "tests/support/guiding_pipeline.h"
#include "tests/support/pass_helpers.h"
#include "tests/support/render_helpers.h"
#include "tests/support/seed_means.h"
#include "tests/passes/guiding/ajar_room.h"

#include <gtest/gtest.h>

#include <cmath>
#include <algorithm>
#include <cstdio>
#include <string>
#include <cstring>
#include <filesystem>

namespace fg {
namespace {

using test::guidedPipeline;
using test::RecordsAt;
using test::trainingParams;

std::vector<Rgb> pixels(const Film& image) { return image.resolve(); }

TEST(GuidedPt, FurnaceSphereHasUnitRadiance) {
    const Scene scene = test::furnaceSphereScene();
    auto params = trainingParams(4000, 32);
    params["pt.max_depth"] = std::int64_t{1000};
    const BufferHandle image =
        test::runPipeline(scene, guidedPipeline(2, "image"), builtinRegistry().passes, params, test::smallFilm(16, 16), "image");
    const std::vector<Rgb> px = pixels(test::bufferAs<Film>(image));
    double sum = 0.0;
    for (const Rgb& p : px) sum += p.y;
    EXPECT_NEAR(sum / px.size(), 1.0, 0.01);
}


// Guided pt with a cache trained once, against pt, over `seeds` independent
// renders of each. Guided pt must be unbiased for every cache, so one cache
// serves all seeds and the training is paid once.
test::MeanComparison compareMeans(const Scene& scene, int size, int seeds, std::int64_t spp, std::int64_t photons,
                                  const std::string& decision = "always") {
    auto training = trainingParams(photons, spp);
    training["radiance_update.guide_decision"] = decision;
    const BufferHandle cache = test::runPipeline(scene, guidedPipeline(2, "radiance_cache"), builtinRegistry().passes,
                                                 training, test::smallFilm(size, size), "radiance_cache", 99);
    const GuidingCache& trained = test::bufferAs<GuidingCache>(cache);
    EXPECT_GT(trained.records.size(), 10u);
    std::size_t bsdfOnly = 0;
    for (std::uint32_t flag : trained.records.column<GuideBsdfOnly>()) bsdfOnly += flag;
    std::printf("%zu records, %zu left to BSDF sampling\n", trained.records.size(), bsdfOnly);
    // With the per-record decision, both kinds of record must be there for the comparison to test their mix.
    if (decision == "variance") {
        EXPECT_GT(bsdfOnly, 0u);
        EXPECT_LT(bsdfOnly, trained.records.size());
    }
    const RayQuery rays(scene);
    const PassRegistration pt = pathTracerPass();
    const std::map<std::string, ParamValue> params{{"spp", spp}, {"max_depth", std::int64_t{12}}};
    const auto means = [](const BufferHandle& image) { return test::blockMeans(test::bufferAs<Film>(image)); };
    std::vector<std::vector<double>> a, b;
    for (int seed = 1; seed <= seeds; ++seed) {
        const auto s = static_cast<std::uint64_t>(seed);
        a.push_back(means(test::runPass(pt, scene, &rays, test::smallFilm(size, size), {{"radiance_cache", cache}}, params, s).at("image")));
        b.push_back(means(test::runPass(pt, scene, &rays, test::smallFilm(size, size), {}, params, s + 1000).at("image")));
    }
    return test::compareSeedMeans(a, b);
}

void expectSameMean(const test::MeanComparison& c, const char* scene) { test::expectSameMean(c, scene, "guided", "pt"); }

TEST(GuidedPt, SameMeanAsPtOnCornellBox) {
    const Scene scene = loadScene(test::sourcePath("data/cornell-box/cornell-box.toml"));
    expectSameMean(compareMeans(scene, 16, 40, 64, 4000), "cornell-box");
}

TEST(GuidedPt, SameMeanAsPtInOccludedRoom) {
    const Scene scene = test::loadAjarRoom("guided-pt");
    expectSameMean(compareMeans(scene, 16, 20, 32, 20000), "occluded room");
}

// Records left to BSDF sampling by the training-time decision (a fixed α of 1
// at their points) beside records that guide: still pt's mean.
TEST(GuidedPt, SameMeanAsPtWithPerRecordDecision) {
    const Scene scene = test::loadAjarRoom("guided-pt-decision");
    expectSameMean(compareMeans(scene, 16, 20, 32, 20000, "variance"), "occluded room, per-record decision");
}

// The cache's file bytes: every column, the index and the counters, as --save writes them.
std::string cacheBytes(const BufferHandle& cache, const std::filesystem::path& path) {
    saveBuffer(cache, path.string(), "");
    return test::readText(path);
}

// A new record keeps query points (here the particles) within new_record_spacing x its training
// radius from becoming records of their own: doubling the spacing must cut the
// records of a training pass to well under half (a disk holds a quarter of
// the particles of one twice as wide), and fewer off-line sweeps cannot make
// more records.
TEST(GuidedPt, NewRecordSpacingSetsRecordCount) {
    const Scene scene = loadScene(test::sourcePath("data/cornell-box/cornell-box.toml"));
    const auto recordsWith = [&](double spacing, std::int64_t maxSweeps) {
        auto params = trainingParams(4000, 1);
        params["radiance_update.new_record_spacing"] = spacing;
        params["radiance_update.max_sweeps"] = maxSweeps;
        const auto cache = test::runPipeline(scene, guidedPipeline(1, "radiance_cache", RecordsAt::Photons),
                                             builtinRegistry().passes, params, test::smallFilm(8, 8), "radiance_cache", 5);
        return test::bufferAs<GuidingCache>(cache).records.size();
    };
    const std::size_t dense = recordsWith(0.5, 12), sparse = recordsWith(1.0, 12);
    EXPECT_GT(sparse, 10u);
    EXPECT_LT(2 * sparse, dense);
    // Record creation does not depend on the EM: the same records for any sweep limit.
    EXPECT_EQ(recordsWith(1.0, 1), sparse);
}

TEST(GuidedPt, CacheAndImageIdenticalAtOneAndTwoThreads) {
    const Scene scene = loadScene(test::sourcePath("data/cornell-box/cornell-box.toml"));
    const std::filesystem::path dir = test::scratchDirectory("guided-pt");
    const auto params = trainingParams(4000, 4);
    const auto cache1 = test::runPipeline(scene, guidedPipeline(2, "radiance_cache"), builtinRegistry().passes, params,
                                          test::smallFilm(16, 16), "radiance_cache", 3, 1);
    const auto cache2 = test::runPipeline(scene, guidedPipeline(2, "radiance_cache"), builtinRegistry().passes, params,
                                          test::smallFilm(16, 16), "radiance_cache", 3, 2);
    ASSERT_GT(test::bufferAs<GuidingCache>(cache1).records.size(), 10u);
    const std::string bytes1 = cacheBytes(cache1, dir / "cache1.fgbuf");
    const std::string bytes2 = cacheBytes(cache2, dir / "cache2.fgbuf");
    EXPECT_GT(bytes1.size(), test::bufferAs<GuidingCache>(cache1).records.size() * sizeof(DirectionalGmm));
    EXPECT_TRUE(bytes1 == bytes2) << "the caches trained at 1 and 2 threads differ";

    const auto image1 = test::runPipeline(scene, guidedPipeline(2, "image"), builtinRegistry().passes, params,
                                          test::smallFilm(16, 16), "image", 3, 1);
    const auto image2 = test::runPipeline(scene, guidedPipeline(2, "image"), builtinRegistry().passes, params,
                                          test::smallFilm(16, 16), "image", 3, 2);
    const std::vector<Rgb> p1 = pixels(test::bufferAs<Film>(image1)), p2 = pixels(test::bufferAs<Film>(image2));
    ASSERT_EQ(p1.size(), p2.size());
    EXPECT_EQ(std::memcmp(p1.data(), p2.data(), p1.size() * sizeof(Rgb)), 0);
}

// The depth-first (tile) schedule adds a guided vertex's light sample itself,
// the wavefront schedule in its shadow-ray stream; both evaluate the sample's
// deferred MIS weight (DeferredGuidedWeight) only for an unblocked ray and must
// give the same image. The unguided image differs, so the cache is in use.
TEST(GuidedPt, WavefrontAndTileSchedulesGiveSameImage) {
    const Scene scene = loadScene(test::sourcePath("data/cornell-box/cornell-box.toml"));
    const BufferHandle cache = test::runPipeline(scene, guidedPipeline(2, "radiance_cache"), builtinRegistry().passes,
                                                 trainingParams(4000, 4), test::smallFilm(16, 16), "radiance_cache", 7);
    ASSERT_GT(test::bufferAs<GuidingCache>(cache).records.size(), 10u);
    const RayQuery rays(scene);
    const PassRegistration pt = pathTracerPass();
    const auto render = [&](const std::string& schedule, bool guided) {
        const std::map<std::string, ParamValue> params{
            {"spp", std::int64_t{8}}, {"max_depth", std::int64_t{12}}, {"schedule", schedule}};
        std::map<std::string, BufferHandle> inputs;
        if (guided) inputs["radiance_cache"] = cache;
        return pixels(test::bufferAs<Film>(test::runPass(pt, scene, &rays, test::smallFilm(16, 16), inputs, params, 11).at("image")));
    };
    const std::vector<Rgb> wavefront = render("wavefront", true), tile = render("tile", true);
    const std::vector<Rgb> unguided = render("wavefront", false);
    ASSERT_EQ(wavefront.size(), tile.size());
    EXPECT_EQ(std::memcmp(wavefront.data(), tile.data(), wavefront.size() * sizeof(Rgb)), 0);
    EXPECT_NE(std::memcmp(wavefront.data(), unguided.data(), wavefront.size() * sizeof(Rgb)), 0);
}

// Train once, render many times: a saved cache, loaded again, is the same
// cache (its bytes), and pt on it renders the image the trained run rendered.
TEST(GuidedPt, SavedAndImportedCacheRendersSameImage) {
    const Scene scene = loadScene(test::sourcePath("data/cornell-box/cornell-box.toml"));
    const std::filesystem::path dir = test::scratchDirectory("guided-pt");
    const auto params = trainingParams(4000, 4);
    const auto trained = test::runPipeline(scene, guidedPipeline(2, "radiance_cache"), builtinRegistry().passes,
                                           params, test::smallFilm(16, 16), "radiance_cache", 5);
    const std::string saved = cacheBytes(trained, dir / "cache.fgbuf");
    const BufferHandle loaded = loadBuffer((dir / "cache.fgbuf").string(), "GuidingCache");
    EXPECT_TRUE(cacheBytes(loaded, dir / "again.fgbuf") == saved);

    const auto image = test::runPipeline(scene, guidedPipeline(2, "image"), builtinRegistry().passes, params,
                                         test::smallFilm(16, 16), "image", 5);
    // pt alone on the loaded cache: same seed and instance name as in the pipeline, so the same random numbers.
    const RayQuery rays(scene);
    const auto rendered = test::runPass(pathTracerPass(), scene, &rays, test::smallFilm(16, 16), {{"radiance_cache", loaded}},
                                        {{"spp", std::int64_t{4}}, {"max_depth", std::int64_t{12}}}, 5);
    const std::vector<Rgb> a = pixels(test::bufferAs<Film>(image)), b = pixels(test::bufferAs<Film>(rendered.at("image")));
    ASSERT_EQ(a.size(), b.size());
    EXPECT_EQ(std::memcmp(a.data(), b.data(), a.size() * sizeof(Rgb)), 0);
}

// Sampling picks a component by counting cdf lanes below u: a file whose lanes
// do not follow from its components (here a cdf that never reaches u) is
// refused on loading, not sampled out of bounds.
TEST(GuidedPt, CacheWhoseLanesDisagreeWithItsComponentsIsRefused) {
    const Scene scene = loadScene(test::sourcePath("data/cornell-box/cornell-box.toml"));
    const std::filesystem::path dir = test::scratchDirectory("guided-pt");
    const auto trained = test::runPipeline(scene, guidedPipeline(1, "radiance_cache"), builtinRegistry().passes,
                                           trainingParams(4000, 4), test::smallFilm(8, 8), "radiance_cache", 5);
    auto& cache = const_cast<GuidingCache&>(test::bufferAs<GuidingCache>(trained));
    auto gmms = cache.records.column<GuideMixture>();
    std::size_t usable = 0;
    while (usable < gmms.size() && !gmms[usable].usable()) ++usable;
    ASSERT_LT(usable, gmms.size());
    const std::string path = (dir / "bad-lanes.fgbuf").string();
    saveBuffer(trained, path, "");
    EXPECT_NO_THROW(loadBuffer(path, "GuidingCache"));

    gmms[usable].lanes.cdf.fill(0.25f);
    saveBuffer(trained, path, "");
    try {
        loadBuffer(path, "GuidingCache");
        ADD_FAILURE() << "a cache with inconsistent lanes was accepted";
    } catch (const InputError& error) {
        EXPECT_NE(std::string(error.what()).find("guiding record " + std::to_string(usable)), std::string::npos)
            << error.what();
    }
}


// Records are made where camera paths query the cache (§4.1): in the occluded
// room, whose light is behind the partition (x > 0.32) and whose camera looks
// at the near side, records made at importons lie far more often on the
// camera's side (the rest where camera paths go through the gap) than records
// made at photons, which lie mostly next to the light (measured: 42 % and 8 %;
// 60 % and 14 % while a record's training particles counted those on the far
// face of the partition, whose short training radius made the near side's
// records small and many).
TEST(GuidedPt, RecordsFollowCameraPathsInOccludedRoom) {
    const Scene scene = test::loadAjarRoom("guided-pt");
    const auto cameraSideShare = [&](RecordsAt at) {
        const auto cache = test::runPipeline(scene, guidedPipeline(2, "radiance_cache", at), builtinRegistry().passes,
                                             trainingParams(20000, 1), test::smallFilm(16, 16), "radiance_cache", 11);
        const GuidingRecordBuffer& records = test::bufferAs<GuidingCache>(cache).records;
        EXPECT_GT(records.size(), 5u);
        std::size_t cameraSide = 0;
        for (const Vec3& p : records.column<GuidePosition>()) cameraSide += p.x < test::kAjarPartitionX ? 1 : 0;
        const double share = static_cast<double>(cameraSide) / static_cast<double>(std::max<std::size_t>(1, records.size()));
        std::printf("records at %s: %zu, %.0f %% on the camera's side\n", at == RecordsAt::Importons ? "importons" : "photons",
                    records.size(), 100.0 * share);
        return share;
    };
    const double importons = cameraSideShare(RecordsAt::Importons), photons = cameraSideShare(RecordsAt::Photons);
    EXPECT_GT(importons, 0.3);
    EXPECT_GT(importons, 3.0 * photons);
}

}  // namespace
}  // namespace fg
