// Guided path tracing (Vorba et al. 2014): the guided image has the unguided
// one's mean (4x4-pixel blocks within 3 sigma of the difference, sigma from
// independent seeds), the furnace sphere still gives radiance 1, and the
// trained caches and the image are the same at 1 and 2 threads.
#include "engine/core/job.h"
#include "engine/guiding/guiding_cache.h"
#include "engine/scene/scene_loader.h"
#include "engine/shading/bsdf.h"
#include "engine/shading/light.h"
#include "passes/passes.h"
#include "tests/support/cli_helpers.h"
#include "tests/support/pass_helpers.h"

#include <gtest/gtest.h>

#include <cmath>
#include <algorithm>
#include <cstring>

namespace fg {
namespace {

// The guided-pt pipeline with a short training block.
Pipeline guidedPipeline(int trainingPasses, const std::string& result) {
    const std::string text = "[pipeline]\nname = \"guided-pt-test\"\nresults = [\"" + result +
                             "\"]\n[[pipeline.repeat]]\nname = \"train\"\ncount = " + std::to_string(trainingPasses) +
                             R"(
carry = { radiance_cache = "radiance_cache" }
[[pipeline.repeat.pass]]
pass = "photon"
outputs = { global_photons = "training_photons" }
[[pipeline.repeat.pass]]
pass = "photon_index"
name = "training_index"
inputs = { photons = "training_photons" }
outputs = { index = "training_index" }
[[pipeline.repeat.pass]]
pass = "cache_update"
name = "radiance_update"
inputs = { photons = "training_photons", index = "training_index", previous = "radiance_cache" }
outputs = { cache = "radiance_cache" }
[[pipeline.pass]]
pass = "pt"
inputs = { radiance_cache = "radiance_cache" }
)";
    return parsePipelineFile(text, "guided-pt-test.toml");
}

std::map<std::string, ParamValue> trainingParams(std::int64_t photons, std::int64_t spp) {
    return {{"photon.photons", photons},       {"photon.store", std::string("global")},
            {"photon.differentials", false},    {"pt.spp", spp},
            {"pt.max_depth", std::int64_t{12}},
            // Fewer training particles and a looser off-line EM than the paper's, to keep the tests short.
            {"radiance_update.training_particles", std::int64_t{64}},
            {"radiance_update.tolerance", 1e-3}};
}

FilmSettings film(int w, int h) {
    FilmSettings f;
    f.width = w;
    f.height = h;
    return f;
}

std::vector<Rgb> pixels(const Film& image) { return image.resolve(); }

TEST(GuidedPt, FurnaceSphereHasUnitRadiance) {
    Scene scene;
    Shape sphere;
    sphere.geometry = Sphere{Vec3(0.0f), 1.0f};
    sphere.flipNormals = true;
    scene.bsdfs.push_back(makeDiffuse(makeConstantTexture(Rgb(0.5f))));
    sphere.bsdf = 0;
    scene.shapes.push_back(sphere);
    scene.lights.push_back(makePointLight(Vec3(0.0f), Rgb(kPi)));
    scene.lightShape.push_back(-1);
    scene.camera.eye = Vec3(0.0f, 0.0f, 0.3f);
    scene.camera.target = Vec3(0.3f, 0.2f, -1.0f);
    scene.camera.fovYDegrees = 90.0f;
    scene.finalize();
    auto params = trainingParams(4000, 32);
    params["pt.max_depth"] = std::int64_t{1000};
    const BufferHandle image =
        test::runPipeline(scene, guidedPipeline(2, "image"), builtinRegistry().passes, params, film(16, 16), "image");
    const std::vector<Rgb> px = pixels(test::bufferAs<Film>(image));
    double sum = 0.0;
    for (const Rgb& p : px) sum += p.y;
    EXPECT_NEAR(sum / px.size(), 1.0, 0.01);
}

TEST(GuidedPt, SameMeanAsPtOnCornellBox) {
    const Scene scene = loadScene(test::sourcePath("data/cornell-box/cornell-box.toml"));
    constexpr int kSize = 16, kBlock = 4, kSeeds = 10;
    const auto blockMeans = [&](const Film& image) {
        std::vector<double> means((kSize / kBlock) * (kSize / kBlock), 0.0);
        const std::vector<Rgb> px = pixels(image);
        for (int y = 0; y < kSize; ++y)
            for (int x = 0; x < kSize; ++x) {
                const Rgb& p = px[static_cast<std::size_t>(y * kSize + x)];
                means[static_cast<std::size_t>((y / kBlock) * (kSize / kBlock) + x / kBlock)] +=
                    (p.x + p.y + p.z) / (3.0 * kBlock * kBlock);
            }
        return means;
    };
    const Pipeline guided = guidedPipeline(3, "image");
    const Pipeline& plain = *std::find_if(builtinPipelines().begin(), builtinPipelines().end(),
                                          [](const Pipeline& p) { return p.name == "pt"; });
    std::vector<std::vector<double>> a, b;
    for (int seed = 1; seed <= kSeeds; ++seed) {
        a.push_back(blockMeans(test::bufferAs<Film>(test::runPipeline(
            scene, guided, builtinRegistry().passes, trainingParams(4000, 16), film(kSize, kSize), "image",
            static_cast<std::uint64_t>(seed)))));
        b.push_back(blockMeans(test::bufferAs<Film>(test::runPipeline(
            scene, plain, builtinRegistry().passes, {{"pt.spp", std::int64_t{16}}, {"pt.max_depth", std::int64_t{12}}},
            film(kSize, kSize), "image", static_cast<std::uint64_t>(seed)))));
    }
    for (std::size_t k = 0; k < a[0].size(); ++k) {
        double ma = 0, mb = 0, va = 0, vb = 0;
        for (int s = 0; s < kSeeds; ++s) ma += a[s][k] / kSeeds, mb += b[s][k] / kSeeds;
        for (int s = 0; s < kSeeds; ++s) va += (a[s][k] - ma) * (a[s][k] - ma), vb += (b[s][k] - mb) * (b[s][k] - mb);
        const double sigma = std::sqrt((va + vb) / (kSeeds - 1) / kSeeds);
        EXPECT_LE(std::abs(ma - mb), 3.0 * sigma + 1e-6) << "block " << k << ": guided " << ma << ", pt " << mb;
    }
}

TEST(GuidedPt, CacheAndImageIdenticalAtOneAndTwoThreads) {
    const Scene scene = loadScene(test::sourcePath("data/cornell-box/cornell-box.toml"));
    const auto params = trainingParams(4000, 4);
    const auto cache1 = test::runPipeline(scene, guidedPipeline(2, "radiance_cache"), builtinRegistry().passes, params,
                                          film(16, 16), "radiance_cache", 3, 1);
    const auto cache2 = test::runPipeline(scene, guidedPipeline(2, "radiance_cache"), builtinRegistry().passes, params,
                                          film(16, 16), "radiance_cache", 3, 2);
    const GuidingCache& c1 = test::bufferAs<GuidingCache>(cache1);
    const GuidingCache& c2 = test::bufferAs<GuidingCache>(cache2);
    ASSERT_GT(c1.records.size(), 10u);
    ASSERT_EQ(c1.records.size(), c2.records.size());
    const auto bytesEqual = [](auto a, auto b) { return std::memcmp(a.data(), b.data(), a.size_bytes()) == 0; };
    EXPECT_TRUE(bytesEqual(c1.records.column<GuidePosition>(), c2.records.column<GuidePosition>()));
    EXPECT_TRUE(bytesEqual(c1.records.column<GuideValidityRadius>(), c2.records.column<GuideValidityRadius>()));
    EXPECT_TRUE(bytesEqual(c1.records.column<GuideMixture>(), c2.records.column<GuideMixture>()));
    EXPECT_TRUE(bytesEqual(c1.records.column<GuideStatistics>(), c2.records.column<GuideStatistics>()));

    const auto image1 = test::runPipeline(scene, guidedPipeline(2, "image"), builtinRegistry().passes, params,
                                          film(16, 16), "image", 3, 1);
    const auto image2 = test::runPipeline(scene, guidedPipeline(2, "image"), builtinRegistry().passes, params,
                                          film(16, 16), "image", 3, 2);
    const std::vector<Rgb> p1 = pixels(test::bufferAs<Film>(image1)), p2 = pixels(test::bufferAs<Film>(image2));
    ASSERT_EQ(p1.size(), p2.size());
    EXPECT_EQ(std::memcmp(p1.data(), p2.data(), p1.size() * sizeof(Rgb)), 0);
}

}  // namespace
}  // namespace fg
