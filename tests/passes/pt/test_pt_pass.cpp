// The reference path tracer against scenes with known answers.
#include "engine/shading/bsdf.h"
#include "engine/shading/light.h"
#include "engine/scene/scene.h"
#include "engine/scene/scene_loader.h"
#include "tests/support/airlight.h"
#include "tests/support/cli_helpers.h"
#include "tests/support/render_helpers.h"

#include <glm/gtc/matrix_transform.hpp>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <string>

namespace fg {
namespace {

using test::airlight;
using test::renderPipeline;

using test::addDiffuse;
using test::smallFilm;

// Camera inside a diffuse sphere of albedo 0.5 lit by a point light of
// intensity pi at its centre: direct radiance 0.5 / R^2, and every bounce adds
// half the previous, so the radiance is exactly 1 everywhere for R = 1.
TEST(PathTracer, FurnaceSphereHasUnitRadiance) {
    const Scene scene = test::furnaceSphereScene();

    const auto image = renderPipeline(scene, "pt", {{"pt.spp", std::int64_t{64}}, {"pt.max_depth", std::int64_t{1000}}},
                                      smallFilm(24, 24));
    const Rgb mean = image.mean();
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(mean[c], 1.0f, 0.01f) << "channel " << c;
    // Every pixel is an unbiased estimate of 1; 64 samples keep them well inside +-25 %.
    for (const Rgb& p : image.pixels) EXPECT_NEAR(p.y, 1.0f, 0.25f);
}

// In the furnace every path's estimate is exactly 1 - 0.5^(d+1) without
// Russian roulette (each vertex sees the light at the same distance, and
// cosine sampling of the albedo-0.5 BSDF weights every bounce by 0.5), so all
// of the pixels' variance is the roulette's: the mean of rr_threshold < 1
// (Vorba et al. 2014 §4.5) must stay within a few standard errors of 1, like
// the classic roulette's.
TEST(PathTracer, RouletteThresholdKeepsTheFurnaceUnbiased) {
    const Scene scene = test::furnaceSphereScene();
    for (const double threshold : {1.0, 1e-2, 1e-5}) {
        for (const std::uint64_t seed : {1u, 2u, 3u}) {
            const auto image = renderPipeline(scene, "pt",
                                              {{"pt.spp", std::int64_t{16}},
                                               {"pt.max_depth", std::int64_t{1000}},
                                               {"pt.rr_threshold", threshold}},
                                              smallFilm(24, 24), seed);
            double sum = 0.0, sumSquares = 0.0;
            for (const Rgb& p : image.pixels) {
                sum += p.y;
                sumSquares += static_cast<double>(p.y) * p.y;
            }
            const double n = static_cast<double>(image.pixels.size());
            const double mean = sum / n;
            const double standardError = std::sqrt(std::max(0.0, sumSquares / n - mean * mean) / (n - 1.0));
            // Float accumulation over up to 1000 bounces leaves ~1e-6 of bias of its own.
            EXPECT_NEAR(mean, 1.0, 4.0 * standardError + 1e-5) << "rr_threshold " << threshold << ", seed " << seed;
            EXPECT_GT(standardError, 0.0) << "the roulette ran: rr_threshold " << threshold;
        }
    }
}

// A path is not threatened while its throughput stays at or above the
// threshold: with max_depth 16 the furnace's throughput never drops below
// 0.5^16 > 1e-5, so rr_threshold 1e-5 draws no roulette number and gives the
// image of no roulette at all, bit for bit; rr_threshold 1 is the default.
TEST(PathTracer, RouletteThresholdAboveEveryThroughputIsNoRoulette) {
    const Scene scene = test::furnaceSphereScene();
    const auto render = [&](std::map<std::string, ParamValue> params) {
        params["pt.spp"] = std::int64_t{4};
        params["pt.max_depth"] = std::int64_t{16};
        return renderPipeline(scene, "pt", params, smallFilm(16, 16));
    };
    const auto unthreatened = render({{"pt.rr_threshold", 1e-5}});
    const auto off = render({{"pt.rr_depth", std::int64_t{4096}}});
    ASSERT_EQ(unthreatened.pixels.size(), off.pixels.size());
    for (std::size_t i = 0; i < off.pixels.size(); ++i) EXPECT_TRUE(unthreatened.pixels[i] == off.pixels[i]) << i;
    const auto classic = render({});
    const auto explicitOne = render({{"pt.rr_threshold", 1.0}});
    for (std::size_t i = 0; i < classic.pixels.size(); ++i) EXPECT_TRUE(classic.pixels[i] == explicitOne.pixels[i]) << i;
    // The classic roulette does act here (from depth 5), so the first check is not vacuous.
    bool differs = false;
    for (std::size_t i = 0; i < off.pixels.size(); ++i) differs = differs || classic.pixels[i] != off.pixels[i];
    EXPECT_TRUE(differs);
}

// Irradiance below a diffuse disk emitter of radius r and radiance L, at height
// h, at lateral distance l from the axis:
//   E = pi L / 2 * [1 - (h^2 + l^2 - r^2) / sqrt((h^2 + l^2 + r^2)^2 - 4 l^2 r^2)],
// which on the axis reduces to pi L r^2 / (h^2 + r^2). A white diffuse floor
// then reflects E / pi towards the camera (direct light only: max_depth = 1).
double diskIrradiance(double L, double r, double h, double l) {
    const double a = h * h + l * l + r * r;
    return 0.5 * M_PI * L * (1.0 - (h * h + l * l - r * r) / std::sqrt(a * a - 4.0 * l * l * r * r));
}

TEST(PathTracer, DiskLightIrradianceMatchesClosedForm) {
    const float radius = 0.5f, height = 1.0f, radiance = 2.0f;
    Scene scene;
    Shape floor;
    TriangleMesh plane = makeRectangleMesh();
    plane.transform(glm::scale(Mat4(1.0f), Vec3(4.0f)));
    floor.geometry = plane;
    floor.bsdf = addDiffuse(scene, Rgb(1.0f));
    scene.shapes.push_back(floor);

    Shape disk;
    TriangleMesh diskMesh = makeDiskMesh(512);
    // Facing down (-z) at z = height.
    diskMesh.transform(glm::translate(Mat4(1.0f), Vec3(0, 0, height)) *
                       glm::rotate(Mat4(1.0f), kPi, Vec3(1, 0, 0)) * glm::scale(Mat4(1.0f), Vec3(radius)));
    disk.geometry = diskMesh;
    disk.bsdf = addDiffuse(scene, Rgb(0.0f));
    disk.areaLight = 0;
    scene.lights.push_back(makeAreaLight(disk, Rgb(radiance)));
    scene.lightShape.push_back(1);
    scene.shapes.push_back(disk);

    // Looking obliquely at the floor from the side, below the disk's plane.
    scene.camera.eye = Vec3(0.0f, -3.0f, 0.8f);
    scene.camera.target = Vec3(0.0f, 0.0f, 0.0f);
    scene.camera.up = Vec3(0, 0, 1);
    scene.camera.fovYDegrees = 30.0f;
    scene.finalize();

    const int w = 32, h = 32;
    const auto image = renderPipeline(scene, "pt", {{"pt.spp", std::int64_t{256}}, {"pt.max_depth", std::int64_t{1}}},
                                      smallFilm(w, h));
    // Compare 4x4 blocks against the closed form at the block's floor points.
    Camera cam = scene.camera;
    cam.width = w;
    cam.height = h;
    int checked = 0;
    for (int by = 0; by < h; by += 4) {
        for (int bx = 0; bx < w; bx += 4) {
            double measured = 0.0, expected = 0.0;
            int n = 0;
            for (int y = by; y < by + 4; ++y) {
                for (int x = bx; x < bx + 4; ++x) {
                    const Ray ray = cam.generateRay(Vec2(x + 0.5f, y + 0.5f));
                    if (ray.direction.z >= 0.0f) continue;
                    const float t = -ray.origin.z / ray.direction.z;
                    const Vec3 p = ray.origin + t * ray.direction;
                    if (std::abs(p.x) > 3.5f || std::abs(p.y) > 3.5f) continue;
                    const double l = std::hypot(p.x, p.y);
                    expected += diskIrradiance(radiance, radius, height, l) / M_PI;
                    measured += image.at(x, y).y;
                    ++n;
                }
            }
            if (n < 16) continue;  // blocks that straddle the horizon or the floor's edge
            ++checked;
            EXPECT_NEAR(measured / n, expected / n, 0.03 * expected / n + 1e-3) << "block " << bx << "," << by;
        }
    }
    EXPECT_GT(checked, 20);
}

TEST(PathTracer, SingleScatteringMatchesAirlightIntegral) {
    const float sigmaS = 0.4f, sigmaA = 0.1f, intensity = 10.0f;
    const float wallDistance = 3.0f, h = 0.5f, delta = 1.2f;
    Scene scene;
    scene.media.emplace_back(Rgb(sigmaA), Rgb(sigmaS), 0.0f);
    // A black wall ends the camera rays at distance T.
    Shape wall;
    TriangleMesh plane = makeRectangleMesh();
    plane.transform(glm::translate(Mat4(1.0f), Vec3(0, 0, -wallDistance)) * glm::scale(Mat4(1.0f), Vec3(10.0f)));
    wall.geometry = plane;
    wall.bsdf = addDiffuse(scene, Rgb(0.0f));
    scene.shapes.push_back(wall);
    scene.lights.push_back(makePointLight(Vec3(h, 0.0f, -delta), Rgb(intensity)));
    scene.lightShape.push_back(-1);
    scene.camera.eye = Vec3(0.0f);
    scene.camera.target = Vec3(0, 0, -1);
    scene.camera.fovYDegrees = 2.0f;
    scene.camera.medium = 0;
    scene.finalize();

    const auto image = renderPipeline(scene, "pt", {{"pt.spp", std::int64_t{256}}, {"pt.max_depth", std::int64_t{1}}},
                                      smallFilm(16, 16));
    // Average the closed form over the pixels' centre rays (they differ by < 1 degree).
    Camera cam = scene.camera;
    cam.width = cam.height = 16;
    double expected = 0.0;
    for (int y = 0; y < 16; ++y) {
        for (int x = 0; x < 16; ++x) {
            const Ray ray = cam.generateRay(Vec2(x + 0.5f, y + 0.5f));
            const Vec3 d = glm::normalize(ray.direction);
            const double T = wallDistance / -d.z;
            const Vec3 light(h, 0.0f, -delta);
            const double foot = glm::dot(light, d);
            const double perp = glm::length(light - static_cast<float>(foot) * d);
            expected += airlight(sigmaS, sigmaS + sigmaA, intensity, perp, foot, T);
        }
    }
    expected /= 256.0;
    EXPECT_NEAR(image.mean().y, expected, 0.01 * expected);
}

// A chain of two schedules over the same random streams gives the same image,
// and so do 1 and 2 threads.
TEST(PathTracer, WavefrontAndTileAgreeAndThreadCountDoesNotMatter) {
    Scene scene;
    Shape sphere;
    sphere.geometry = Sphere{Vec3(0.0f), 1.0f};
    sphere.flipNormals = true;
    sphere.bsdf = addDiffuse(scene, Rgb(0.7f, 0.5f, 0.3f));
    scene.shapes.push_back(sphere);
    Shape glass;
    glass.geometry = Sphere{Vec3(0.2f, 0.0f, -0.4f), 0.25f};
    scene.bsdfs.push_back(makeDielectric(1.5f));
    glass.bsdf = static_cast<int>(scene.bsdfs.size()) - 1;
    scene.shapes.push_back(glass);
    scene.lights.push_back(makePointLight(Vec3(0.0f, 0.5f, 0.0f), Rgb(3.0f)));
    scene.lightShape.push_back(-1);
    scene.camera.eye = Vec3(0.0f, 0.0f, 0.5f);
    scene.camera.target = Vec3(0.0f, 0.0f, -1.0f);
    scene.camera.fovYDegrees = 70.0f;
    scene.finalize();

    FilmSettings film = smallFilm(20, 16);
    film.filter = FilterKind::Gaussian;
    film.filterRadius = 1.5f;
    const std::map<std::string, ParamValue> wave = {{"pt.spp", std::int64_t{8}}, {"pt.wave_size", std::int64_t{100}}};
    std::map<std::string, ParamValue> tile = wave;
    tile["pt.schedule"] = std::string("tile");
    const auto a = renderPipeline(scene, "pt", wave, film, 7, 1);
    const auto b = renderPipeline(scene, "pt", wave, film, 7, 2);
    const auto c = renderPipeline(scene, "pt", tile, film, 7, 2);
    ASSERT_EQ(a.pixels.size(), b.pixels.size());
    bool anyNonZero = false;
    for (std::size_t i = 0; i < a.pixels.size(); ++i) {
        EXPECT_EQ(a.pixels[i], b.pixels[i]) << "pixel " << i;
        EXPECT_EQ(a.pixels[i], c.pixels[i]) << "pixel " << i;
        anyNonZero |= a.pixels[i].x > 0.0f;
    }
    EXPECT_TRUE(anyNonZero);
    // A different seed changes the image.
    const auto d = renderPipeline(scene, "pt", wave, film, 8, 2);
    EXPECT_NE(a.pixels, d.pixels);
}

// Meshes whose triangles tie: the Cornell box's ceiling holds the light
// opening as a second, coplanar quad, and the conference scene repeats faces
// across shapes, so a camera ray can hit two triangles at the same t. The
// schedules must pick the same one; they did not while camera streams went
// through Embree's coherent packet kernels and single rays through its
// single-ray kernels.
void expectSchedulesAgree(const Scene& scene, const std::string& what) {
    const FilmSettings film = smallFilm(32, 32);
    const std::map<std::string, ParamValue> wave = {{"pt.spp", std::int64_t{4}}, {"pt.max_depth", std::int64_t{8}}};
    std::map<std::string, ParamValue> tile = wave;
    tile["pt.schedule"] = std::string("tile");
    const auto waveOne = renderPipeline(scene, "pt", wave, film, 1, 1);
    const auto waveTwo = renderPipeline(scene, "pt", wave, film, 1, 2);
    const auto tileOne = renderPipeline(scene, "pt", tile, film, 1, 1);
    const auto tileTwo = renderPipeline(scene, "pt", tile, film, 1, 2);
    std::size_t differing = 0, lit = 0;
    for (std::size_t i = 0; i < waveOne.pixels.size(); ++i) {
        const bool same = waveOne.pixels[i] == waveTwo.pixels[i] && waveOne.pixels[i] == tileOne.pixels[i] &&
                          waveOne.pixels[i] == tileTwo.pixels[i];
        if (!same && differing++ == 0) ADD_FAILURE() << what << ": first differing pixel " << i;
        lit += waveOne.pixels[i].y > 0.0f ? 1 : 0;
    }
    EXPECT_EQ(differing, 0u) << what;
    EXPECT_GT(lit, waveOne.pixels.size() / 2) << what;
}

TEST(PathTracer, SchedulesAgreeOnTheConferenceScene) {
    expectSchedulesAgree(loadScene(test::sourcePath("data/conference/conference.xml")), "conference");
}

// The scene of tools/bench_vs_embree.sh: Mitsuba's Cornell-box meshes, white
// diffuse, one point light under the ceiling.
TEST(PathTracer, SchedulesAgreeOnAMeshCornellBoxWithAPointLight) {
    const std::filesystem::path dir = test::scratchDirectory("pt-schedules-cornell");
    std::ofstream toml(dir / "cornell.toml");
    toml << "[camera]\neye = [278, 273, -800]\ntarget = [278, 273, -799]\nup = [0, 1, 0]\nfov = 39.3077\n"
            "width = 32\nheight = 32\n\n"
            "[[material]]\nname = \"white\"\ntype = \"diffuse\"\nreflectance = [1, 1, 1]\n\n"
            "[[light]]\ntype = \"point\"\nposition = [278, 540, 279.5]\nintensity = 100000\n";
    for (const char* part : {"floor", "ceiling", "back", "greenwall", "redwall", "smallbox", "largebox"}) {
        toml << "\n[[shape]]\ntype = \"obj\"\nfile = \""
             << test::sourcePath(std::string("data/cornell-box/meshes/cbox_") + part + ".obj")
             << "\"\nmaterial = \"white\"\n";
    }
    toml.close();
    expectSchedulesAgree(loadScene((dir / "cornell.toml").string()), "Cornell box");
}

}  // namespace
}  // namespace fg
