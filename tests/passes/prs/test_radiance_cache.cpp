// The radiance cache of photon ray splatting (Herzog et al. 2007, §8.3;
// passes/prs/radiance_cache.h): placement on a sphere seen by a camera (the
// coverage counted through the records' image windows equals a brute-force
// count over all records, so no window cuts off a pixel a record is valid
// at; pixels short of min_records are exactly the reported ones; the record
// count grows as ε shrinks), and the prs-rc pipeline: the same image on 1 and
// 2 threads, close to the uncached image in the furnace sphere, the same
// image from a map of c_00 alone as from all bands, parameters checked
// (ranges when the job is read, the rest in preflight); the dense mode
// (records placed by radiance_cache itself from a map of every vertex) the
// same on 1 and 2 threads and close to the uncached image too.
#include "passes/prs/radiance_cache.h"

#include "engine/core/error.h"
#include "engine/scene/scene_loader.h"
#include "engine/core/job.h"
#include "passes/passes.h"
#include "tests/support/pass_helpers.h"
#include "tests/support/render_helpers.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <map>
#include <string>

namespace fg {
namespace {

constexpr int kImageSize = 128;

Camera sphereCamera() {
    Camera camera;
    camera.eye = Vec3(0.0f, 0.0f, 4.0f);
    camera.target = Vec3(0.0f);
    camera.fovYDegrees = 40.0f;
    camera.width = kImageSize;
    camera.height = kImageSize;
    return camera;
}

// One sample per pixel: the front of a unit sphere at the origin through the
// pixel's centre (about 40 % of the image; the rest is background), with a
// radius that varies across the sphere as a harmonic mean distance would.
std::vector<CachePixelSample> sphereSamples(const Camera& camera) {
    std::vector<CachePixelSample> samples(static_cast<std::size_t>(camera.width * camera.height));
    for (int y = 0; y < camera.height; ++y)
        for (int x = 0; x < camera.width; ++x) {
            const Ray ray = camera.generateRay(Vec2(static_cast<float>(x) + 0.5f, static_cast<float>(y) + 0.5f));
            const Vec3 d = glm::normalize(ray.direction);
            const float b = glm::dot(ray.origin, d), c = glm::dot(ray.origin, ray.origin) - 1.0f;
            const float discriminant = b * b - c;
            if (discriminant <= 0.0f) continue;
            CachePixelSample& s = samples[static_cast<std::size_t>(y * camera.width + x)];
            s.position = ray.origin + (-b - std::sqrt(discriminant)) * d;
            s.normal = glm::normalize(s.position);
            s.radius = 0.4f + 0.3f * (s.position.x + 1.0f);
            s.coefficients[0] = Rgb(1.0f + s.position.y);
            s.valid = true;
        }
    return samples;
}

TEST(PrsRadianceCache, WindowsMissNoValidPixelAndShortPixelsAreReported) {
    const Camera camera = sphereCamera();
    const std::vector<CachePixelSample> samples = sphereSamples(camera);
    for (const float error : {0.7f, 0.3f}) {
        RadianceCacheSettings settings;
        settings.error = error;
        const RadianceCachePlacement placement = placeCacheRecords(samples, camera, settings);
        ASSERT_GT(placement.recordPixels.size(), 0u);
        std::vector<std::uint32_t> reported;
        for (std::size_t pixel = 0; pixel < samples.size(); ++pixel) {
            const CachePixelSample& at = samples[pixel];
            if (!at.valid) {
                EXPECT_EQ(placement.coverage[pixel], 0u);
                continue;
            }
            std::uint32_t covering = 0;
            for (std::uint32_t recordPixel : placement.recordPixels) {
                const CachePixelSample& record = samples[recordPixel];
                if (wardDenominator(at.position, at.normal, record.position, record.normal, record.radius) < error)
                    ++covering;
            }
            ASSERT_EQ(placement.coverage[pixel], covering) << "pixel " << pixel << ", error " << error;
            if (covering < static_cast<std::uint32_t>(settings.minRecords)) reported.push_back(static_cast<std::uint32_t>(pixel));
        }
        EXPECT_EQ(placement.undercoveredPixels, reported);
        // Refinement: a valid pixel of the last grid left short must hold a record.
        const int step = settings.grid >> (settings.passes - 1);
        for (std::uint32_t pixel : reported) {
            const int x = static_cast<int>(pixel) % kImageSize, y = static_cast<int>(pixel) / kImageSize;
            if (x % step != step / 2 || y % step != step / 2) continue;
            EXPECT_NE(std::find(placement.recordPixels.begin(), placement.recordPixels.end(), pixel),
                      placement.recordPixels.end());
        }
        std::printf("error %.1f: %zu records (%zu, %zu, %zu per pass), %zu of %zu sphere pixels short of %d\n", error,
                    placement.recordPixels.size(), placement.recordsPerPass[0], placement.recordsPerPass[1],
                    placement.recordsPerPass[2], reported.size(),
                    static_cast<std::size_t>(std::count_if(samples.begin(), samples.end(),
                                                           [](const CachePixelSample& s) { return s.valid; })),
                    settings.minRecords);
    }
}

TEST(PrsRadianceCache, RecordCountGrowsAsErrorShrinks) {
    const Camera camera = sphereCamera();
    const std::vector<CachePixelSample> samples = sphereSamples(camera);
    // Four passes (down to a 4-pixel grid), so that no ε here runs out of grid pixels.
    std::size_t previous = 0;
    for (const float error : {0.9f, 0.7f, 0.5f, 0.3f, 0.2f}) {
        RadianceCacheSettings settings;
        settings.error = error;
        settings.passes = 4;
        const std::size_t count = placeCacheRecords(samples, camera, settings).recordPixels.size();
        std::printf("error %.1f: %zu records\n", error, count);
        EXPECT_GT(count, previous) << "error " << error;
        previous = count;
    }
}

std::map<std::string, ParamValue> prsParams(std::int64_t photons) {
    return {
        {"eye.spp", std::int64_t{1}},
        {"eye.direct_light", false},
        {"photon.photons", photons},
        {"photon.photon_rays", true},
        {"photon.store", std::string("none")},
        {"ray_splat.glossy", std::string("sh_map")},
        {"ray_splat.lambertian", std::string("sh_map")},
    };
}

TEST(PrsRadianceCache, SameImageOnOneAndTwoThreads) {
    const Scene scene = loadScene(
        (std::filesystem::path(FLUXGRAPH_SOURCE_DIR) / "data/cornell-box/cornell-box-glossy.toml").string());
    const FilmSettings film = test::smallFilm(32, 32);
    test::expectSameImageAtOneAndTwoThreads(scene, "prs-rc", prsParams(20000), film);
}

TEST(PrsRadianceCache, CloseToTheUncachedImageInTheFurnace) {
    // Every bounce of the furnace sphere adds the same radiance everywhere, so
    // what the cache changes is noise alone: its records are means of
    // neighbouring estimates of one value. The uncached image is prs with the
    // same map (lambertian = sh_map) integrated directly. The cached mean may
    // move only through the weights' uneven spread over the noise (0.2 % seen
    // at 20k photons); 1 % is five times that. The pixel spread about the
    // mean must fall (0.020 -> 0.015 seen): the cache filters.
    const Scene scene = test::furnaceSphereScene();
    const FilmSettings film = test::smallFilm(48, 48);
    const test::RenderedImage uncached = test::renderPipeline(scene, "prs", prsParams(20000), film);
    const test::RenderedImage cached = test::renderPipeline(scene, "prs-rc", prsParams(20000), film);
    double sumUncached = 0.0, sumCached = 0.0, squaredUncached = 0.0, squaredCached = 0.0;
    const double n = static_cast<double>(cached.pixels.size());
    for (std::size_t i = 0; i < cached.pixels.size(); ++i) {
        sumUncached += uncached.pixels[i].y;
        sumCached += cached.pixels[i].y;
    }
    const double meanUncached = sumUncached / n, meanCached = sumCached / n;
    for (std::size_t i = 0; i < cached.pixels.size(); ++i) {
        squaredUncached += std::pow(uncached.pixels[i].y - meanUncached, 2.0);
        squaredCached += std::pow(cached.pixels[i].y - meanCached, 2.0);
    }
    const double spreadUncached = std::sqrt(squaredUncached / n), spreadCached = std::sqrt(squaredCached / n);
    std::printf("furnace indirect: uncached mean %.5f (spread %.5f), cached mean %.5f (spread %.5f)\n", meanUncached,
                spreadUncached, meanCached, spreadCached);
    EXPECT_NEAR(meanCached, meanUncached, 0.01 * meanUncached);
    EXPECT_LT(spreadCached, spreadUncached);
}

// prs-rc as it was before cache_select: every eye vertex splatted into the
// map, records placed by radiance_cache from it.
Pipeline densePipeline() {
    return parsePipelineFile(R"([pipeline]
name = "prs-rc-dense"
results = ["image"]
[[pipeline.pass]]
pass = "eye"
[[pipeline.pass]]
pass = "photon"
[[pipeline.pass]]
pass = "ray_bandwidth"
[[pipeline.pass]]
pass = "splat_index"
[[pipeline.pass]]
pass = "ray_splat"
outputs = { radiance = "splatted" }
[[pipeline.pass]]
pass = "radiance_cache"
[[pipeline.pass]]
pass = "radiance_integrate"
inputs = { radiance_map = "cached_map" }
outputs = { radiance = "global" }
[[pipeline.pass]]
pass = "composite"
)",
                             "prs-rc-dense.toml");
}

std::vector<Rgb> renderDense(const Scene& scene, const FilmSettings& film, int threads) {
    const BufferHandle image = test::runPipeline(scene, densePipeline(), builtinRegistry().passes, prsParams(20000), film,
                                                 "image", 1, threads);
    return static_cast<const Film*>(image.data.get())->resolve();
}

TEST(PrsRadianceCache, DenseModeSameOnOneAndTwoThreadsAndCloseToUncached) {
    const Scene scene = test::furnaceSphereScene();
    const FilmSettings film = test::smallFilm(48, 48);
    const std::vector<Rgb> one = renderDense(scene, film, 1);
    const std::vector<Rgb> two = renderDense(scene, film, 2);
    ASSERT_EQ(one.size(), two.size());
    for (std::size_t i = 0; i < one.size(); ++i) ASSERT_EQ(one[i], two[i]) << "pixel " << i;
    const test::RenderedImage uncached = test::renderPipeline(scene, "prs", prsParams(20000), film);
    double sumUncached = 0.0, sumDense = 0.0;
    for (std::size_t i = 0; i < one.size(); ++i) {
        sumUncached += uncached.pixels[i].y;
        sumDense += one[i].y;
    }
    EXPECT_GT(sumUncached, 0.0);
    EXPECT_NEAR(sumDense, sumUncached, 0.01 * sumUncached);
}

TEST(PrsRadianceCache, MapWithC00AloneGivesTheSameImage) {
    // Every vertex of the furnace sphere is Lambertian, so ray_splat keeps
    // c_00 alone (map_bands = used): nothing downstream reads the other
    // bands of a Lambertian vertex, and the image must match the all-band
    // map's bit for bit.
    const Scene scene = test::furnaceSphereScene();
    const FilmSettings film = test::smallFilm(32, 32);
    std::map<std::string, ParamValue> allBands = prsParams(10000);
    allBands["ray_splat.map_bands"] = std::string("all");
    const test::RenderedImage used = test::renderPipeline(scene, "prs-rc", prsParams(10000), film);
    const test::RenderedImage all = test::renderPipeline(scene, "prs-rc", allBands, film);
    ASSERT_EQ(used.pixels.size(), all.pixels.size());
    double sum = 0.0;
    for (std::size_t i = 0; i < used.pixels.size(); ++i) {
        ASSERT_EQ(used.pixels[i], all.pixels[i]) << "pixel " << i;
        sum += used.pixels[i].y;
    }
    EXPECT_GT(sum, 0.0);
}

TEST(PrsRadianceCache, ParametersAreChecked) {
    const Scene scene = test::furnaceSphereScene();
    const FilmSettings film = test::smallFilm(8, 8);
    const auto render = [&](const std::string& key, ParamValue value) {
        std::map<std::string, ParamValue> params = prsParams(100);
        params[key] = std::move(value);
        return test::renderPipeline(scene, "prs-rc", params, film);
    };
    EXPECT_THROW(render("radiance_cache.error", 0.0), InputError);
    EXPECT_THROW(render("radiance_cache.error", 1.5), InputError);
    EXPECT_THROW(render("radiance_cache.min_records", std::int64_t{0}), InputError);
    EXPECT_THROW(render("radiance_cache.grid", std::int64_t{0}), InputError);
    EXPECT_THROW(render("radiance_cache.max_radius", 0.0), InputError);
    EXPECT_NO_THROW(render("radiance_cache.grid", std::int64_t{4}));
}

TEST(PrsRadianceCache, PreflightRefusesGridsTooSmallAndUnmappedLambertianVertices) {
    const Scene scene = test::furnaceSphereScene();
    const PassRegistration& cache = *findPass("radiance_cache");
    PassParams params;
    params.set("grid", std::int64_t{32});
    params.set("passes", std::int64_t{3});
    PassParams splat;
    splat.set("lambertian", std::string("sh_map"));
    PreflightContext pf{scene, params, "radiance_cache", "job.toml:3", {}, {}, {}, {}};
    pf.producerParams = [&](const std::string&) { return &splat; };
    std::string recordsProducer;
    pf.producerPass = [&](const std::string& slot) {
        return slot == "radiance_map" ? std::string("ray_splat") : slot == "placed_records" ? recordsProducer : std::string();
    };
    EXPECT_NO_THROW(cache.preflight(pf));
    // Three passes halve the grid twice: 2 pixels cannot be.
    params.set("grid", std::int64_t{2});
    EXPECT_THROW(cache.preflight(pf), InputError);
    params.set("grid", std::int64_t{4});
    EXPECT_NO_THROW(cache.preflight(pf));
    // With records chosen before splatting, glossy vertices must be mapped too.
    splat.set("glossy", std::string("direct"));
    EXPECT_NO_THROW(cache.preflight(pf));
    recordsProducer = "cache_select";
    EXPECT_THROW(cache.preflight(pf), InputError);
    splat.set("glossy", std::string("sh_map"));
    EXPECT_NO_THROW(cache.preflight(pf));
    // Lambertian vertices must be in the map the cache serves.
    splat.set("lambertian", std::string("film"));
    EXPECT_THROW(cache.preflight(pf), InputError);
}

}  // namespace
}  // namespace fg
