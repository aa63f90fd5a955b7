// Bidirectional path tracing against scenes with known answers and against pt.
#include "engine/shading/bsdf.h"
#include "engine/shading/light.h"
#include "engine/scene/scene.h"
#include "tests/support/airlight.h"
#include "tests/support/render_helpers.h"

#include "engine/accel/ray_query.h"
#include "engine/core/job.h"
#include "engine/core/scheduler.h"
#include "jobs/parallel.h"
#include "passes/passes.h"

#include <glm/gtc/matrix_transform.hpp>
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstdio>
#include <map>
#include <string>
#include <vector>

namespace fg {
namespace {

using test::renderPipeline;

// Renders the bdpt pipeline and returns its film, AOVs included.
Film renderBdptFilm(const Scene& scene, const std::map<std::string, ParamValue>& params, const FilmSettings& film,
                    std::uint64_t seed = 1, int threads = 2) {
    const Pipeline* pipeline = findPipeline("bdpt");
    JobParams jobParams;
    for (const auto& [key, value] : params) jobParams.values["bdpt"][key] = {value, "test"};
    const ExecutionPlan plan = ExecutionPlan::build(*pipeline, jobParams, "test");
    const jobs::ThreadLimit limit(threads);
    const RayQuery rays(scene);
    RunOptions options;
    options.seed = seed;
    options.film = film;
    const RunResult result = execute(plan, scene, rays, options);
    return *static_cast<const Film*>(result.results.at("image").data.get());
}

using test::addDiffuse;
using test::smallFilm;

// pt's furnace: a camera inside a diffuse sphere of albedo 0.5 around a point
// light of intensity pi sees radiance 1 (sum of 0.5^k over k bounces; the
// depth limit of 64 segments leaves out 0.5^64).
TEST(BdptPass, FurnaceSphereHasUnitRadiance) {
    const Scene scene = test::furnaceSphereScene();

    const auto image = renderPipeline(scene, "bdpt", {{"bdpt.spp", std::int64_t{16}}, {"bdpt.max_depth", std::int64_t{64}}},
                                      smallFilm(24, 24), 1, 2);
    const Rgb mean = image.mean();
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(mean[c], 1.0f, 0.01f) << "channel " << c;
}


// Per 4x4-block means of two estimates of the same image agree within 3 sigma
// of their difference, sigma measured from two independent halves of each.
struct NoisyImage {
    test::RenderedImage first, second;
};

int blocksBeyond(const NoisyImage& a, const NoisyImage& b, double sigmas, int* checked) {
    const int w = a.first.width, h = a.first.height;
    int beyond = 0;
    for (int by = 0; by + 4 <= h; by += 4) {
        for (int bx = 0; bx + 4 <= w; bx += 4) {
            for (int c = 0; c < 3; ++c) {
                double meanA = 0.0, meanB = 0.0, varA = 0.0, varB = 0.0;
                for (int y = by; y < by + 4; ++y) {
                    for (int x = bx; x < bx + 4; ++x) {
                        const double a1 = a.first.at(x, y)[c], a2 = a.second.at(x, y)[c];
                        const double b1 = b.first.at(x, y)[c], b2 = b.second.at(x, y)[c];
                        meanA += 0.5 * (a1 + a2);
                        meanB += 0.5 * (b1 + b2);
                        // The mean of two independent halves has a quarter of their difference's variance.
                        varA += 0.25 * (a1 - a2) * (a1 - a2);
                        varB += 0.25 * (b1 - b2) * (b1 - b2);
                    }
                }
                meanA /= 16.0;
                meanB /= 16.0;
                const double sigma = std::sqrt((varA + varB) / 256.0);
                ++*checked;
                if (std::abs(meanA - meanB) > sigmas * sigma + 1e-6) ++beyond;
            }
        }
    }
    return beyond;
}

NoisyImage renderHalves(const Scene& scene, const std::string& pipeline, const std::map<std::string, ParamValue>& params,
                        const FilmSettings& film) {
    return {renderPipeline(scene, pipeline, params, film, 11, 2), renderPipeline(scene, pipeline, params, film, 12, 2)};
}

// A closed Cornell-like box: white floor, ceiling and back wall, red and green
// side walls, a square emitter under the ceiling, a camera inside.
Scene cornellBox() {
    Scene scene;
    const int white = addDiffuse(scene, Rgb(0.75f));
    const int red = addDiffuse(scene, Rgb(0.63f, 0.06f, 0.05f));
    const int green = addDiffuse(scene, Rgb(0.14f, 0.45f, 0.09f));
    const auto wall = [&](const Mat4& transform, int bsdf) {
        Shape shape;
        TriangleMesh mesh = makeRectangleMesh();
        mesh.transform(transform);
        shape.geometry = mesh;
        shape.bsdf = bsdf;
        scene.shapes.push_back(shape);
    };
    const Mat4 I(1.0f);
    wall(glm::translate(I, Vec3(0, -1, 0)) * glm::rotate(I, -kPi / 2, Vec3(1, 0, 0)), white);  // floor
    wall(glm::translate(I, Vec3(0, 1, 0)) * glm::rotate(I, kPi / 2, Vec3(1, 0, 0)), white);    // ceiling
    wall(glm::translate(I, Vec3(0, 0, -1)), white);                                              // back
    wall(glm::translate(I, Vec3(0, 0, 1)) * glm::rotate(I, kPi, Vec3(0, 1, 0)), white);         // front
    wall(glm::translate(I, Vec3(-1, 0, 0)) * glm::rotate(I, kPi / 2, Vec3(0, 1, 0)), red);      // left
    wall(glm::translate(I, Vec3(1, 0, 0)) * glm::rotate(I, -kPi / 2, Vec3(0, 1, 0)), green);    // right
    Shape emitter;
    TriangleMesh mesh = makeRectangleMesh();
    mesh.transform(glm::translate(I, Vec3(0, 0.99f, 0)) * glm::rotate(I, kPi / 2, Vec3(1, 0, 0)) *
                   glm::scale(I, Vec3(0.25f)));
    emitter.geometry = mesh;
    emitter.bsdf = addDiffuse(scene, Rgb(0.0f));
    emitter.areaLight = 0;
    scene.lights.push_back(makeAreaLight(emitter, Rgb(12.0f)));
    scene.lightShape.push_back(static_cast<int>(scene.shapes.size()));
    scene.shapes.push_back(emitter);
    scene.camera.eye = Vec3(0.0f, 0.0f, 0.95f);
    scene.camera.target = Vec3(0.0f, 0.0f, -1.0f);
    scene.camera.fovYDegrees = 75.0f;
    scene.finalize();
    return scene;
}

TEST(BdptPass, CornellBoxAgreesWithPathTracer) {
    const Scene scene = cornellBox();
    const FilmSettings film = smallFilm(24, 24);
    const NoisyImage bdpt = renderHalves(scene, "bdpt", {{"bdpt.spp", std::int64_t{32}}, {"bdpt.max_depth", std::int64_t{9}}}, film);
    const NoisyImage pt = renderHalves(scene, "pt", {{"pt.spp", std::int64_t{128}}, {"pt.max_depth", std::int64_t{8}}}, film);
    int checked = 0;
    const int beyond3 = blocksBeyond(bdpt, pt, 3.0, &checked);
    int unused = 0;
    const int beyond5 = blocksBeyond(bdpt, pt, 5.0, &unused);
    // 3 sigma is passed by 0.3 % of blocks by chance; sigma itself is an estimate of 16 pixels.
    EXPECT_LE(beyond3, 2) << "of " << checked;
    EXPECT_EQ(beyond5, 0);
    EXPECT_GT(bdpt.first.mean().y, 0.05f);
}

TEST(BdptPass, ImageIsIdenticalForOneAndTwoThreads) {
    const Scene scene = cornellBox();
    FilmSettings film = smallFilm(20, 16);
    film.filter = FilterKind::Gaussian;
    film.filterRadius = 1.5f;
    const std::map<std::string, ParamValue> params = {{"spp", std::int64_t{4}}, {"wave_size", std::int64_t{300}},
                                                      {"strategy_aovs", std::int64_t{2}}};
    Film a = renderBdptFilm(scene, params, film, 7, 1);
    Film b = renderBdptFilm(scene, params, film, 7, 2);
    const std::vector<Rgb> ia = a.resolve(), ib = b.resolve();
    ASSERT_EQ(ia.size(), ib.size());
    bool anyNonZero = false;
    for (std::size_t i = 0; i < ia.size(); ++i) {
        EXPECT_EQ(ia[i], ib[i]) << "pixel " << i;
        anyNonZero |= !isBlack(ia[i]);
    }
    EXPECT_TRUE(anyNonZero);
    ASSERT_EQ(a.aovs().size(), b.aovs().size());
    for (std::size_t k = 0; k < a.aovs().size(); ++k) EXPECT_EQ(a.aovs()[k].second, b.aovs()[k].second) << a.aovs()[k].first;
}

// A spot light under a mirror ceiling points up: the floor below sees it only
// through the mirror (L S D E), and of all strategies only t = 1 (the floor
// vertex of the light subpath connected to the camera) can make that path: the
// camera path meets the mirror but cannot connect from it, nor can the light
// path from its mirror vertex. The image is that of the mirrored spot,
// L = (albedo / pi) I cos(theta) / d^2.
TEST(BdptPass, MirrorCausticIsOnlyTheLightTracingStrategy) {
    const float albedo = 0.5f, intensity = 3.0f, lightHeight = 1.5f, mirrorHeight = 2.0f, cameraHeight = 1.0f;
    Scene scene;
    Shape floor;
    TriangleMesh plane = makeRectangleMesh();
    plane.transform(glm::scale(Mat4(1.0f), Vec3(10.0f)));
    floor.geometry = plane;
    floor.bsdf = addDiffuse(scene, Rgb(albedo));
    scene.shapes.push_back(floor);
    Shape mirror;
    TriangleMesh ceiling = makeRectangleMesh();
    ceiling.transform(glm::translate(Mat4(1.0f), Vec3(0, 0, mirrorHeight)) * glm::rotate(Mat4(1.0f), kPi, Vec3(1, 0, 0)) *
                      glm::scale(Mat4(1.0f), Vec3(10.0f)));
    mirror.geometry = ceiling;
    scene.bsdfs.push_back(makeConductor(*conductorPreset("none")));
    mirror.bsdf = static_cast<int>(scene.bsdfs.size()) - 1;
    scene.shapes.push_back(mirror);
    scene.lights.push_back(makeSpotLight(Vec3(0, 0, lightHeight), Vec3(0, 0, 1), Rgb(intensity), 40.0f, 39.0f));
    scene.lightShape.push_back(-1);
    scene.camera.eye = Vec3(0.0f, 0.0f, cameraHeight);
    scene.camera.target = Vec3(0.0f, 0.0f, 0.0f);
    scene.camera.up = Vec3(0, 1, 0);
    scene.camera.fovYDegrees = 60.0f;
    scene.finalize();

    const int w = 16, h = 16;
    Film film = renderBdptFilm(scene, {{"spp", std::int64_t{64}}, {"max_depth", std::int64_t{3}}, {"strategy_aovs", std::int64_t{3}}},
                               smallFilm(w, h));
    const std::vector<Rgb> image = film.resolve();
    const Vec3 virtualLight(0, 0, 2.0f * mirrorHeight - lightHeight);
    Camera cam = scene.camera;
    cam.width = w;
    cam.height = h;
    double measured = 0.0, expected = 0.0;
    for (int y = 0; y < h; ++y) {
        for (int x = 0; x < w; ++x) {
            const Ray ray = cam.generateRay(Vec2(x + 0.5f, y + 0.5f));
            const Vec3 onFloor = ray.origin + (ray.origin.z / -ray.direction.z) * ray.direction;
            const Vec3 toLight = virtualLight - onFloor;
            const float d2 = glm::dot(toLight, toLight);
            expected += albedo / kPi * intensity * (toLight.z / std::sqrt(d2)) / d2;
            measured += image[static_cast<std::size_t>(y * w + x)].y;
        }
    }
    EXPECT_NEAR(measured, expected, 0.02 * expected);
    for (const auto& [name, values] : film.aovs()) {
        double sum = 0.0;
        for (float v : values) sum += v;
        if (name.starts_with("s3t1.")) EXPECT_NEAR(sum, name == "s3t1.G" ? measured : sum, 1e-3 * measured) << name;
        else EXPECT_EQ(sum, 0.0) << name;
    }
}

// A pool: a camera under a flat water surface (IOR 1.33) looks straight down
// at a diffuse floor lit by a disk lamp above the water. Light reaches the
// floor only through the refraction, by two strategies: s0t4 (the floor's
// BSDF-sampled ray refracts into the lamp) and s3t1 (light tracing). With
// floor, surface, lamp and image plane all parallel, the ratio of their
// densities is the same for every such path, eta^2 p(lamp point) / p(floor
// point from the camera) (the closed form of test_bdpt_path.cpp's pool, checked
// there against finite differences of Snell's law), so the power-heuristic
// weights are constants and a weighted strategy image is its raw image times
// that constant in every pixel, same seed: a check of the subpaths' own
// densities through a real dielectric.
TEST(BdptPass, PoolCausticWeightsAreTheDensityRatiosThroughTheRefraction) {
    const float eta = 1.33f, cameraHeight = 0.85f, lampHeight = 4.0f, fov = 60.0f;
    Scene scene;
    Shape floor;
    TriangleMesh plane = makeRectangleMesh();
    plane.transform(glm::scale(Mat4(1.0f), Vec3(5.0f)));
    floor.geometry = plane;
    floor.bsdf = addDiffuse(scene, Rgb(0.8f));
    scene.shapes.push_back(floor);
    Shape water;
    TriangleMesh surface = makeRectangleMesh();
    surface.transform(glm::translate(Mat4(1.0f), Vec3(0, 0, 1.0f)) * glm::scale(Mat4(1.0f), Vec3(5.0f)));
    water.geometry = surface;
    scene.bsdfs.push_back(makeDielectric(eta));
    water.bsdf = static_cast<int>(scene.bsdfs.size()) - 1;
    scene.shapes.push_back(water);
    Shape lamp;
    TriangleMesh disk = makeDiskMesh(64);
    disk.transform(glm::translate(Mat4(1.0f), Vec3(0, 0, lampHeight)) * glm::rotate(Mat4(1.0f), kPi, Vec3(1, 0, 0)) *
                   glm::scale(Mat4(1.0f), Vec3(0.5f)));
    lamp.geometry = disk;
    lamp.bsdf = addDiffuse(scene, Rgb(0.0f));
    lamp.areaLight = 0;
    scene.lights.push_back(makeAreaLight(lamp, Rgb(20.0f)));
    scene.lightShape.push_back(static_cast<int>(scene.shapes.size()));
    scene.shapes.push_back(lamp);
    scene.camera.eye = Vec3(0.0f, 0.0f, cameraHeight);
    scene.camera.target = Vec3(0.0f);
    scene.camera.up = Vec3(0, 1, 0);
    scene.camera.fovYDegrees = fov;
    scene.finalize();

    const int w = 16, h = 16;
    const auto render = [&](bool weighted) {
        return renderBdptFilm(scene, {{"spp", std::int64_t{64}}, {"max_depth", std::int64_t{3}},
                                      {"strategy_aovs", std::int64_t{3}}, {"strategy_weighted", weighted}},
                              smallFilm(w, h), 5);
    };
    const Film weighted = render(true), raw = render(false);

    const auto origin = scene.lights[0]->sampleEmission(Vec2(0.5f), Vec2(0.5f));
    ASSERT_TRUE(origin);
    const float tanHalf = std::tan(0.5f * fov * kPi / 180.0f);
    const double imagePlaneArea = 4.0 * tanHalf * tanHalf;  // at unit distance, square image
    // The camera's area density on a floor parallel to its image plane.
    const double floorPdf = 1.0 / (imagePlaneArea * cameraHeight * cameraHeight);
    const double ratio = static_cast<double>(eta) * eta * origin->pdfPosition / floorPdf;
    const double lightWeight = ratio * ratio / (1.0 + ratio * ratio);
    const std::map<std::string, double> expected = {{"s0t4.G", 1.0 - lightWeight}, {"s3t1.G", lightWeight}};

    const auto channel = [](const Film& film, const std::string& name) -> const std::vector<float>& {
        for (const auto& [n, values] : film.aovs())
            if (n == name) return values;
        ADD_FAILURE() << "no AOV " << name;
        static const std::vector<float> none;
        return none;
    };
    for (const auto& [name, weight] : expected) {
        const std::vector<float>& a = channel(weighted, name);
        const std::vector<float>& b = channel(raw, name);
        ASSERT_EQ(a.size(), b.size());
        int lit = 0;
        for (std::size_t i = 0; i < a.size(); ++i) {
            if (!(b[i] > 0.0f)) continue;
            ++lit;
            EXPECT_NEAR(a[i] / b[i], weight, 1e-4 + 1e-4 * weight) << name << " pixel " << i << ", density ratio " << ratio;
        }
        EXPECT_GT(lit, w * h / 4) << name << ": " << lit << " pixels lit";
    }
    // The other strategies of up to three segments see nothing.
    for (const auto& [name, values] : weighted.aovs()) {
        if (name.starts_with("s0t4.") || name.starts_with("s3t1.")) continue;
        double sum = 0.0;
        for (float v : values) sum += v;
        EXPECT_EQ(sum, 0.0) << name;
    }
}

// pt's airlight test: single scattering (two segments) from a point light
// along camera rays in a homogeneous medium matches the airlight integral.
TEST(BdptPass, SingleScatteringMatchesAirlightIntegral) {
    const float sigmaS = 0.4f, sigmaA = 0.1f, intensity = 10.0f;
    const float wallDistance = 3.0f, hOffset = 0.5f, delta = 1.2f;
    Scene scene;
    scene.media.emplace_back(Rgb(sigmaA), Rgb(sigmaS), 0.0f);
    Shape wall;
    TriangleMesh plane = makeRectangleMesh();
    plane.transform(glm::translate(Mat4(1.0f), Vec3(0, 0, -wallDistance)) * glm::scale(Mat4(1.0f), Vec3(10.0f)));
    wall.geometry = plane;
    wall.bsdf = addDiffuse(scene, Rgb(0.0f));
    scene.shapes.push_back(wall);
    scene.lights.push_back(makePointLight(Vec3(hOffset, 0.0f, -delta), Rgb(intensity)));
    scene.lightShape.push_back(-1);
    scene.camera.eye = Vec3(0.0f);
    scene.camera.target = Vec3(0, 0, -1);
    scene.camera.fovYDegrees = 2.0f;
    scene.camera.medium = 0;
    scene.finalize();

    const auto image = renderPipeline(scene, "bdpt", {{"bdpt.spp", std::int64_t{256}}, {"bdpt.max_depth", std::int64_t{2}}},
                                      smallFilm(16, 16), 1, 2);
    Camera cam = scene.camera;
    cam.width = cam.height = 16;
    double expected = 0.0;
    for (int y = 0; y < 16; ++y) {
        for (int x = 0; x < 16; ++x) {
            const Vec3 d = glm::normalize(cam.generateRay(Vec2(x + 0.5f, y + 0.5f)).direction);
            const double T = wallDistance / -d.z;
            const Vec3 light(hOffset, 0.0f, -delta);
            const double foot = glm::dot(light, d);
            const double perp = glm::length(light - static_cast<float>(foot) * d);
            expected += test::airlight(sigmaS, sigmaS + sigmaA, intensity, perp, foot, T);
        }
    }
    expected /= 256.0;
    EXPECT_NEAR(image.mean().y, expected, 0.01 * expected);
}

// A fog cube behind a null boundary over a diffuse floor, lit by a point light
// and a constant environment: medium vertices, transmittance on connections
// through the boundary, and the environment reached by escaping paths.
TEST(BdptPass, MediumBoxAgreesWithPathTracer) {
    Scene scene;
    Shape floor;
    TriangleMesh plane = makeRectangleMesh();
    plane.transform(glm::scale(Mat4(1.0f), Vec3(3.0f)));
    floor.geometry = plane;
    floor.bsdf = addDiffuse(scene, Rgb(0.6f, 0.5f, 0.4f));
    scene.shapes.push_back(floor);
    scene.media.emplace_back(Rgb(0.05f, 0.1f, 0.2f), Rgb(0.8f, 0.6f, 0.4f), 0.3f);
    Shape fog;
    TriangleMesh cube = makeCubeMesh();
    // Lifted off the floor: a null face coplanar with the floor would decide at random which medium the floor is in.
    cube.transform(glm::translate(Mat4(1.0f), Vec3(0, 0, 0.85f)) * glm::scale(Mat4(1.0f), Vec3(0.8f)));
    fog.geometry = cube;
    scene.bsdfs.push_back(makeNull());
    fog.bsdf = static_cast<int>(scene.bsdfs.size()) - 1;
    fog.interiorMedium = 0;
    scene.shapes.push_back(fog);
    scene.lights.push_back(makePointLight(Vec3(0.5f, -0.5f, 2.5f), Rgb(6.0f)));
    scene.lightShape.push_back(-1);
    scene.lights.push_back(makeConstantEnvironment(Rgb(0.3f)));
    scene.lightShape.push_back(-1);
    scene.camera.eye = Vec3(0.0f, -4.0f, 2.0f);
    scene.camera.target = Vec3(0.0f, 0.0f, 0.6f);
    scene.camera.up = Vec3(0, 0, 1);
    scene.camera.fovYDegrees = 45.0f;
    scene.finalize();

    const FilmSettings film = smallFilm(24, 24);
    const NoisyImage bdpt = renderHalves(scene, "bdpt", {{"bdpt.spp", std::int64_t{32}}, {"bdpt.max_depth", std::int64_t{7}}}, film);
    const NoisyImage pt = renderHalves(scene, "pt", {{"pt.spp", std::int64_t{128}}, {"pt.max_depth", std::int64_t{6}}}, film);
    int checked = 0;
    const int beyond3 = blocksBeyond(bdpt, pt, 3.0, &checked);
    int unused = 0;
    const int beyond5 = blocksBeyond(bdpt, pt, 5.0, &unused);
    EXPECT_LE(beyond3, 2) << "of " << checked;
    EXPECT_EQ(beyond5, 0);
    EXPECT_GT(bdpt.first.mean().y, 0.05f);
}

// Unweighted, each strategy (s, t) alone is an unbiased estimator of the light
// carried by paths of s + t - 1 segments wherever every strategy can make
// every such path: in a fog cube (over a diffuse floor) lit by a diffuse area
// emitter above it, seen from outside through its null boundary. The
// strategies of one length must then agree with the MIS-weighted sum of all
// strategies of that length.
TEST(BdptPass, UnweightedStrategiesOfOneLengthAgree) {
    Scene scene;
    Shape floor;
    TriangleMesh plane = makeRectangleMesh();
    plane.transform(glm::scale(Mat4(1.0f), Vec3(3.0f)));
    floor.geometry = plane;
    floor.bsdf = addDiffuse(scene, Rgb(0.6f));
    scene.shapes.push_back(floor);
    scene.media.emplace_back(Rgb(0.1f), Rgb(0.9f), 0.0f);
    Shape fog;
    TriangleMesh cube = makeCubeMesh();
    cube.transform(glm::translate(Mat4(1.0f), Vec3(0, 0, 1.05f)));
    fog.geometry = cube;
    scene.bsdfs.push_back(makeNull());
    fog.bsdf = static_cast<int>(scene.bsdfs.size()) - 1;
    fog.interiorMedium = 0;
    scene.shapes.push_back(fog);
    Shape emitter;
    TriangleMesh mesh = makeRectangleMesh();
    // Above the fog: next-event estimation from medium points right under an
    // emitter has unbounded variance (the 1 / d^2 of its samples).
    mesh.transform(glm::translate(Mat4(1.0f), Vec3(0, 0, 2.35f)) * glm::rotate(Mat4(1.0f), kPi, Vec3(1, 0, 0)) *
                   glm::scale(Mat4(1.0f), Vec3(0.6f)));
    emitter.geometry = mesh;
    emitter.bsdf = addDiffuse(scene, Rgb(0.0f));
    emitter.areaLight = 0;
    scene.lights.push_back(makeAreaLight(emitter, Rgb(5.0f)));
    scene.lightShape.push_back(2);
    scene.shapes.push_back(emitter);
    scene.camera.eye = Vec3(0.0f, -4.0f, 1.2f);
    scene.camera.target = Vec3(0.0f, 0.0f, 1.0f);
    scene.camera.up = Vec3(0, 0, 1);
    scene.camera.fovYDegrees = 40.0f;
    scene.finalize();

    const auto strategyMeans = [&](bool weighted) {
        Film film = renderBdptFilm(scene, {{"spp", std::int64_t{512}}, {"max_depth", std::int64_t{3}},
                                           {"strategy_aovs", std::int64_t{3}}, {"strategy_weighted", weighted}},
                                   smallFilm(16, 16));
        std::map<std::pair<int, int>, double> means;
        for (int length = 1; length <= 3; ++length) {
            for (int t = 1; t <= length + 1; ++t) {
                const int s = length + 1 - t;
                std::array<char, 32> name{};
                std::snprintf(name.data(), name.size(), "s%dt%d.G", s, t);
                const std::vector<float>& values = film.aov(name.data());
                double sum = 0.0;
                for (float v : values) sum += v;
                means[{s, t}] = sum / static_cast<double>(values.size());
            }
        }
        return std::pair(means, film.resolve());
    };
    const auto [unweighted, unused] = strategyMeans(false);
    const auto [weighted, image] = strategyMeans(true);
    double imageMean = 0.0;
    for (const Rgb& p : image) imageMean += p.y;
    imageMean /= static_cast<double>(image.size());
    double weightedTotal = 0.0;
    for (int length = 1; length <= 3; ++length) {
        // The MIS combination is the least noisy estimate of each length's light.
        double reference = 0.0;
        for (int t = 1; t <= length + 1; ++t) reference += weighted.at({length + 1 - t, t});
        ASSERT_GT(reference, 0.01) << "length " << length;
        for (int t = 1; t <= length + 1; ++t) {
            const int s = length + 1 - t;
            // A connection between two subpath vertices (s, t >= 2) in the fog has
            // unbounded variance alone (1 / d^2 as the vertices approach each other),
            // so those are checked only through the weighted sum. The others were
            // within 3.5 % at this sample count.
            if (s >= 2 && t >= 2) continue;
            EXPECT_NEAR(unweighted.at({s, t}), reference, 0.05 * reference) << "s = " << s << ", t = " << t;
        }
        weightedTotal += reference;
    }
    // The image is the weighted strategies' sum (box filter: the AOVs are box-filtered too).
    EXPECT_NEAR(imageMean, weightedTotal, 1e-4 * imageMean);
}

// A diffuse sphere of albedo 0.8 under a constant environment of radiance 1:
// being convex it sees only the sky, so it reflects 0.8 at any depth, and the
// sky itself is 1 (the camera path escaping, s = 0, and the sky sampled from
// the eye, s = 1, t = 1).
TEST(BdptPass, ConvexSphereUnderConstantSkyReflectsItsAlbedo) {
    Scene scene;
    Shape sphere;
    sphere.geometry = Sphere{Vec3(0.0f), 1.0f};
    sphere.bsdf = addDiffuse(scene, Rgb(0.8f));
    scene.shapes.push_back(sphere);
    scene.lights.push_back(makeConstantEnvironment(Rgb(1.0f)));
    scene.lightShape.push_back(-1);
    scene.camera.eye = Vec3(0.0f, 0.0f, 4.0f);
    scene.camera.target = Vec3(0.0f);
    scene.camera.fovYDegrees = 40.0f;
    scene.finalize();
    const int size = 16;
    const auto image = renderPipeline(scene, "bdpt", {{"bdpt.spp", std::int64_t{32}}, {"bdpt.max_depth", std::int64_t{4}}},
                                      smallFilm(size, size), 1, 2);
    Camera cam = scene.camera;
    cam.width = cam.height = size;
    double sphereSum = 0.0, skySum = 0.0;
    int spherePixels = 0, skyPixels = 0;
    for (int y = 0; y < size; ++y) {
        for (int x = 0; x < size; ++x) {
            // Pixels wholly on the sphere or wholly on the sky (all four corners agree).
            int hits = 0;
            for (const Vec2 corner : {Vec2(0, 0), Vec2(1, 0), Vec2(0, 1), Vec2(1, 1)}) {
                const Ray ray = cam.generateRay(Vec2(static_cast<float>(x), static_cast<float>(y)) + corner);
                const float b = glm::dot(ray.origin, ray.direction);
                hits += b * b - (glm::dot(ray.origin, ray.origin) - 1.0f) > 0.0f && b < 0.0f ? 1 : 0;
            }
            const float value = image.at(x, y).y;
            if (hits == 4) sphereSum += value, ++spherePixels;
            if (hits == 0) skySum += value, ++skyPixels;
        }
    }
    ASSERT_GT(spherePixels, 10);
    ASSERT_GT(skyPixels, 10);
    EXPECT_NEAR(sphereSum / spherePixels, 0.8, 0.01);
    EXPECT_NEAR(skySum / skyPixels, 1.0, 1e-3);
}

// A diffuse floor of albedo 0.5 under collimated light of irradiance E at 30
// degrees from the normal reflects 0.5 E cos(30) / pi (direct light only:
// next-event estimation and the light path's floor vertex seen by the camera).
TEST(BdptPass, DirectionalLightOnAFloorMatchesLambert) {
    const float irradiance = 2.0f, albedo = 0.5f;
    Scene scene;
    Shape floor;
    TriangleMesh plane = makeRectangleMesh();
    plane.transform(glm::scale(Mat4(1.0f), Vec3(2.0f)));
    floor.geometry = plane;
    floor.bsdf = addDiffuse(scene, Rgb(albedo));
    scene.shapes.push_back(floor);
    const Vec3 direction = glm::normalize(Vec3(std::sin(kPi / 6.0f), 0.0f, -std::cos(kPi / 6.0f)));
    scene.lights.push_back(makeDirectionalLight(direction, Rgb(irradiance)));
    scene.lightShape.push_back(-1);
    scene.camera.eye = Vec3(0.0f, -1.0f, 2.0f);
    scene.camera.target = Vec3(0.0f);
    scene.camera.up = Vec3(0, 0, 1);
    scene.camera.fovYDegrees = 30.0f;
    scene.finalize();
    const auto image = renderPipeline(scene, "bdpt", {{"bdpt.spp", std::int64_t{64}}, {"bdpt.max_depth", std::int64_t{2}}},
                                      smallFilm(12, 12), 1, 2);
    const double expected = albedo * irradiance * std::cos(kPi / 6.0) / kPi;
    EXPECT_NEAR(image.mean().y, expected, 0.01 * expected);
}

// Sum of an AOV channel over the image.
double aovSum(Film& film, const std::string& name) {
    double sum = 0.0;
    for (float v : film.aov(name)) sum += v;
    return sum;
}

// The AOVs of every strategy but `only` (s, t) are black, and that one holds
// the whole image (box filter: the AOVs are box-filtered).
void expectOnlyStrategy(Film& film, int onlyS, int onlyT) {
    std::array<char, 16> only{};
    std::snprintf(only.data(), only.size(), "s%dt%d.", onlyS, onlyT);
    double image = 0.0;
    for (const Rgb& p : film.resolve()) image += p.y;
    EXPECT_GT(image, 0.0);
    std::vector<std::string> names;
    for (const auto& [name, values] : film.aovs()) names.push_back(name);
    for (const std::string& name : names) {
        const double sum = aovSum(film, name);
        if (name.starts_with(only.data())) {
            if (name.ends_with(".G")) {
                EXPECT_NEAR(sum, image, 1e-4 * image) << name;
            }
        } else {
            EXPECT_EQ(sum, 0.0) << name;
        }
    }
}

// A mirror ceiling; the camera below it looks up. (1) A disk emitter facing
// up under the camera is seen only in the mirror (L S E): only s = 0, the
// camera path reaching the emitter, makes that path, and where a pixel sees
// the emitter wholly its value is the emitter's radiance. (2) A point light
// over a diffuse floor, the floor seen only in the mirror (L D S E): only
// s = 1, next-event estimation from the floor, makes that path; the image is
// (albedo / pi) I cos(theta) / d^2 at the floor point of each reflected ray.
TEST(BdptPass, CameraHitsAndNextEventStrategiesAloneThroughAMirror) {
    const float mirrorHeight = 2.0f;
    const auto mirrorScene = [&](Scene& scene) {
        Shape mirror;
        TriangleMesh ceiling = makeRectangleMesh();
        ceiling.transform(glm::translate(Mat4(1.0f), Vec3(0, 0, mirrorHeight)) *
                          glm::rotate(Mat4(1.0f), kPi, Vec3(1, 0, 0)) * glm::scale(Mat4(1.0f), Vec3(10.0f)));
        mirror.geometry = ceiling;
        scene.bsdfs.push_back(makeConductor(*conductorPreset("none")));
        mirror.bsdf = static_cast<int>(scene.bsdfs.size()) - 1;
        scene.shapes.push_back(mirror);
        scene.camera.eye = Vec3(0.0f, 0.0f, 0.5f);
        scene.camera.target = Vec3(0.0f, 0.0f, 1.0f);
        scene.camera.up = Vec3(0, 1, 0);
        scene.camera.fovYDegrees = 50.0f;
    };
    const int size = 16;
    const std::map<std::string, ParamValue> params = {{"spp", std::int64_t{32}}, {"max_depth", std::int64_t{3}},
                                                      {"strategy_aovs", std::int64_t{3}}};
    Camera cam;
    // Where the ray through raster r meets the plane z = height after the mirror.
    const auto reflectedHit = [&](const Vec2& r, float height) {
        const Ray ray = cam.generateRay(r);
        const float toMirror = (mirrorHeight - ray.origin.z) / ray.direction.z;
        const Vec3 onMirror = ray.origin + toMirror * ray.direction;
        const Vec3 down(ray.direction.x, ray.direction.y, -ray.direction.z);
        return onMirror + ((onMirror.z - height) / -down.z) * down;
    };
    {
        const float radius = 0.6f, diskHeight = 0.2f, radiance = 3.0f;
        Scene scene;
        mirrorScene(scene);
        Shape disk;
        TriangleMesh mesh = makeDiskMesh(256);
        mesh.transform(glm::translate(Mat4(1.0f), Vec3(0, 0, diskHeight)) * glm::scale(Mat4(1.0f), Vec3(radius)));
        disk.geometry = mesh;
        disk.bsdf = addDiffuse(scene, Rgb(0.0f));
        disk.areaLight = 0;
        scene.lights.push_back(makeAreaLight(disk, Rgb(radiance)));
        scene.lightShape.push_back(1);
        scene.shapes.push_back(disk);
        scene.finalize();
        cam = scene.camera;
        cam.width = cam.height = size;
        Film film = renderBdptFilm(scene, params, smallFilm(size, size));
        expectOnlyStrategy(film, 0, 3);
        const std::vector<Rgb> image = film.resolve();
        int inside = 0;
        for (int y = 0; y < size; ++y) {
            for (int x = 0; x < size; ++x) {
                bool covered = true;
                for (const Vec2 corner : {Vec2(0, 0), Vec2(1, 0), Vec2(0, 1), Vec2(1, 1)}) {
                    const Vec3 onDisk = reflectedHit(Vec2(static_cast<float>(x), static_cast<float>(y)) + corner, diskHeight);
                    covered &= glm::length(Vec2(onDisk.x, onDisk.y)) < radius * 0.99f;
                }
                if (!covered) continue;
                ++inside;
                EXPECT_NEAR(image[static_cast<std::size_t>(y * size + x)].y, radiance, 1e-4f) << x << "," << y;
            }
        }
        EXPECT_GT(inside, 8);
    }
    {
        const float albedo = 0.5f, intensity = 2.0f;
        const Vec3 lightPosition(0.3f, -0.2f, 1.0f);
        Scene scene;
        mirrorScene(scene);
        Shape floor;
        TriangleMesh plane = makeRectangleMesh();
        plane.transform(glm::scale(Mat4(1.0f), Vec3(10.0f)));
        floor.geometry = plane;
        floor.bsdf = addDiffuse(scene, Rgb(albedo));
        scene.shapes.push_back(floor);
        scene.lights.push_back(makePointLight(lightPosition, Rgb(intensity)));
        scene.lightShape.push_back(-1);
        scene.finalize();
        cam = scene.camera;
        cam.width = cam.height = size;
        Film film = renderBdptFilm(scene, params, smallFilm(size, size));
        expectOnlyStrategy(film, 1, 3);
        double measured = 0.0, expected = 0.0;
        const std::vector<Rgb> image = film.resolve();
        for (int y = 0; y < size; ++y) {
            for (int x = 0; x < size; ++x) {
                const Vec3 onFloor = reflectedHit(Vec2(x + 0.5f, y + 0.5f), 0.0f);
                const Vec3 toLight = lightPosition - onFloor;
                const float d2 = glm::dot(toLight, toLight);
                expected += albedo / kPi * intensity * (toLight.z / std::sqrt(d2)) / d2;
                measured += image[static_cast<std::size_t>(y * size + x)].y;
            }
        }
        // Pixel centres stand for the pixels' means: the radiance varies smoothly across each.
        EXPECT_NEAR(measured, expected, 0.01 * expected);
    }
}

}  // namespace
}  // namespace fg
