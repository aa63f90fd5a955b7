// Volumetric photon mapping with the beam radiance estimate (`bre`): volume
// photons against the closed-form density of single scattering, the pilot
// radii against their definition, the camera segments against box geometry,
// the whole pipeline against the airlight integral, and reproducibility
// across thread counts.
#include "engine/buffers/beam_buffers.h"
#include "engine/shading/bsdf.h"
#include "engine/core/error.h"
#include "engine/image/image_compare.h"
#include "engine/accel/kdtree.h"
#include "engine/core/job.h"
#include "engine/shading/light.h"
#include "engine/buffers/photon_buffers.h"
#include "engine/accel/photon_bvh.h"
#include "engine/accel/ray_query.h"
#include "engine/scene/scene.h"
#include "engine/scene/scene_loader.h"
#include "engine/core/scheduler.h"
#include "jobs/parallel.h"
#include "passes/passes.h"
#include "tests/support/airlight_scene.h"
#include "tests/support/pass_helpers.h"
#include "tests/support/photon_fixtures.h"

#include <glm/gtc/matrix_transform.hpp>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>

namespace fg {
namespace {

FilmSettings boxFilm(int w, int h) {
    FilmSettings f;
    f.width = w;
    f.height = h;
    return f;
}

int addBsdf(Scene& scene, std::shared_ptr<Bsdf> bsdf) {
    scene.bsdfs.push_back(std::move(bsdf));
    return static_cast<int>(scene.bsdfs.size()) - 1;
}

int addDiffuse(Scene& scene, const Rgb& albedo) { return addBsdf(scene, makeDiffuse(makeConstantTexture(albedo))); }

void addPointLight(Scene& scene, const Vec3& position, const Rgb& intensity) {
    scene.lights.push_back(makePointLight(position, intensity));
    scene.lightShape.push_back(-1);
}

// Runs `pipeline` (default: bre) and keeps the given buffers.
struct PipelineRun {
    std::map<std::string, BufferHandle> buffers;
    std::vector<PassStats> stats;
    template <class T>
    const T& get(const std::string& name) const {
        return *static_cast<const T*>(buffers.at(name).data.get());
    }
    const PassStats& pass(const std::string& instance) const {
        for (const PassStats& s : stats)
            if (s.instance == instance) return s;
        throw std::out_of_range(instance);
    }
};

PipelineRun runPipeline(const Scene& scene, const Pipeline& pipeline, const std::vector<std::string>& results,
                const std::map<std::string, ParamValue>& params, const FilmSettings& film, std::uint64_t seed = 1,
                int threads = 0) {
    Pipeline p = pipeline;
    p.results = results;
    JobParams jobParams;
    for (const auto& [key, value] : params) {
        const auto dot = key.find('.');
        jobParams.values[key.substr(0, dot)][key.substr(dot + 1)] = {value, "test"};
    }
    const ExecutionPlan plan = ExecutionPlan::build(p, jobParams, "test");
    const jobs::ThreadLimit limit(threads);
    const RayQuery rays(scene);
    RunOptions options;
    options.seed = seed;
    options.film = film;
    RunResult result = execute(plan, scene, rays, options);
    return {std::move(result.results), std::move(result.stats)};
}

const Pipeline kPhotonsOnly{"photons", "", {{"photon", "photon", {}, {}, 0}}, {}};

// ---------------------------------------------------------------------------
// Volume photons

// A point light of intensity I in an infinite grey medium: every path's first
// event is a scattering event at distance d with density sigma_t e^{-sigma_t d},
// and its photon carries the emitted share times the albedo. So the power of
// single-scattered photons inside the shell a <= d < b around the light is
//   sigma_s / sigma_t * 4 pi I (e^{-sigma_t a} - e^{-sigma_t b}),
// and their total is the albedo times the emitted power.
TEST(VolumePhotons, SingleScatteringDensityAndPowerMatchTheClosedForm) {
    const float sigmaS = 0.6f, sigmaA = 0.2f, intensity = 2.0f;
    const float sigmaT = sigmaS + sigmaA;
    Scene scene;
    scene.media.emplace_back(Rgb(sigmaA), Rgb(sigmaS), 0.3f);
    scene.camera.medium = 0;
    addPointLight(scene, Vec3(0.5f, -1.0f, 2.0f), Rgb(intensity));
    scene.finalize();

    const std::int64_t target = 40000;
    const PipelineRun run = runPipeline(scene, kPhotonsOnly, {"volume_photons"},
                                {{"photon.volume_photons", target}, {"photon.photons", std::int64_t{1} << 40},
                                 {"photon.max_depth", std::int64_t{1}}},
                                boxFilm(4, 4));
    const VolumePhotonMap& map = run.get<VolumePhotonMap>("volume_photons");
    ASSERT_EQ(map.photons.size(), static_cast<std::size_t>(target)) << "the target is met exactly";
    EXPECT_EQ(map.emitted, static_cast<std::uint64_t>(target)) << "every path scatters once in an infinite medium";
    EXPECT_EQ(run.pass("photon").counters.at("emitted_paths"), target);

    const auto position = map.photons.column<PhotonPosition>();
    const auto incident = map.photons.column<PhotonIncident>();
    const auto power = map.photons.column<PhotonPower>();
    const auto photonClass = map.photons.column<PhotonClassColumn>();
    const double emittedPower = 4.0 * M_PI * intensity;
    glm::dvec3 total(0.0);
    const double shells[] = {0.0, 0.4, 1.0, 2.0, 4.0};
    double shellPower[4] = {0, 0, 0, 0};
    for (std::size_t i = 0; i < map.photons.size(); ++i) {
        ASSERT_EQ(photonClass[i], PhotonClass::Volume | PhotonClass::Direct);
        const Vec3 offset = position[i] - Vec3(0.5f, -1.0f, 2.0f);
        // The photon arrived straight from the light.
        if (glm::length(offset) > 1e-3f) {
            ASSERT_GT(glm::dot(glm::normalize(offset), -incident[i]), 0.9999f);
        }
        total += glm::dvec3(power[i]);
        const double d = glm::length(offset);
        for (int s = 0; s < 4; ++s)
            if (d >= shells[s] && d < shells[s + 1]) shellPower[s] += power[i].y;
    }
    EXPECT_NEAR(total.x / emittedPower, sigmaS / sigmaT, 1e-4);
    EXPECT_NEAR(total.z / emittedPower, sigmaS / sigmaT, 1e-4);
    const double photonPower = emittedPower * sigmaS / sigmaT / static_cast<double>(target);
    for (int s = 0; s < 4; ++s) {
        const double expected =
            sigmaS / sigmaT * emittedPower * (std::exp(-sigmaT * shells[s]) - std::exp(-sigmaT * shells[s + 1]));
        const double sigma = std::sqrt(expected / photonPower) * photonPower;  // binomial count
        EXPECT_NEAR(shellPower[s], expected, 4.0 * sigma) << "shell " << s;
    }
}

// A fog box (null boundary) around a glass sphere and a diffuse floor, lit by
// a point light inside the box.
Scene foggyGlassScene(float g = 0.0f) {
    Scene scene;
    scene.media.emplace_back(Rgb(0.05f, 0.08f, 0.1f), Rgb(0.5f, 0.45f, 0.4f), g);
    Shape box;
    TriangleMesh cube = makeCubeMesh();
    cube.transform(glm::translate(Mat4(1.0f), Vec3(0, 1.0f, 0)) * glm::scale(Mat4(1.0f), Vec3(1.5f, 1.0f, 1.5f)));
    box.geometry = cube;
    box.bsdf = addBsdf(scene, makeNull());
    box.interiorMedium = 0;
    scene.shapes.push_back(box);
    Shape floor;
    TriangleMesh plane = makeRectangleMesh();
    plane.transform(glm::translate(Mat4(1.0f), Vec3(0, 0.01f, 0)) * glm::rotate(Mat4(1.0f), -kPi / 2, Vec3(1, 0, 0)) *
                    glm::scale(Mat4(1.0f), Vec3(1.4f)));
    floor.geometry = plane;
    floor.bsdf = addDiffuse(scene, Rgb(0.7f));
    scene.shapes.push_back(floor);
    Shape glass;
    glass.geometry = Sphere{Vec3(0.1f, 0.9f, 0.0f), 0.35f};
    glass.bsdf = addBsdf(scene, makeDielectric(1.5f));
    glass.exteriorMedium = 0;
    scene.shapes.push_back(glass);
    addPointLight(scene, Vec3(-0.3f, 1.8f, 0.2f), Rgb(3.0f));
    scene.camera.eye = Vec3(0.0f, 1.2f, 5.0f);
    scene.camera.target = Vec3(0.0f, 0.9f, 0.0f);
    scene.camera.fovYDegrees = 40.0f;
    scene.finalize();
    return scene;
}

TEST(VolumePhotons, ClassesTargetsAndOptions) {
    const Scene scene = foggyGlassScene();
    const std::int64_t target = 20000;
    const std::map<std::string, ParamValue> params = {{"photon.volume_photons", target},
                                                      {"photon.photons", std::int64_t{1} << 40}};
    const PipelineRun all = runPipeline(scene, kPhotonsOnly, {"volume_photons", "global_photons", "caustic_photons"}, params,
                                boxFilm(4, 4));
    const VolumePhotonMap& volume = all.get<VolumePhotonMap>("volume_photons");
    ASSERT_EQ(volume.photons.size(), static_cast<std::size_t>(target));
    EXPECT_EQ(all.get<PhotonMap>("global_photons").emitted, volume.emitted);
    EXPECT_GT(volume.emitted, 1000u);
    std::int64_t counts[8] = {};
    for (std::uint8_t c : volume.photons.column<PhotonClassColumn>()) {
        ASSERT_TRUE(c & PhotonClass::Volume);
        ++counts[c & 7];
    }
    EXPECT_GT(counts[PhotonClass::Direct], 1000) << "single scattering";
    EXPECT_GT(counts[PhotonClass::Caustic], 50) << "volume caustic behind the glass sphere";
    EXPECT_GT(counts[PhotonClass::Global], 1000) << "multiple scattering";
    EXPECT_EQ(all.pass("photon").counters.at("single_scattering_photons"), counts[PhotonClass::Direct]);
    for (const Vec3& p : volume.photons.column<PhotonPosition>()) {
        ASSERT_LE(std::abs(p.x), 1.5f + 1e-3f);
        ASSERT_GE(p.y, -1e-3f);
        ASSERT_LE(p.y, 2.0f + 1e-3f);
        ASSERT_GT(glm::length(p - Vec3(0.1f, 0.9f, 0.0f)), 0.35f - 1e-3f) << "no medium inside the sphere";
    }
    // Surface photons after a medium event are global photons.
    EXPECT_GT(all.get<PhotonMap>("global_photons").photons.size(), 1000u);

    // The same paths with a fixed count give the same photons, up to the power normalisation.
    const PipelineRun fixed = runPipeline(scene, kPhotonsOnly, {"volume_photons"},
                                  {{"photon.photons", static_cast<std::int64_t>(volume.emitted)}}, boxFilm(4, 4));
    const VolumePhotonMap& fixedVolume = fixed.get<VolumePhotonMap>("volume_photons");
    ASSERT_GE(fixedVolume.photons.size(), volume.photons.size());
    for (std::size_t i = 0; i < volume.photons.size(); i += 97) {
        ASSERT_EQ(fixedVolume.photons.column<PhotonPosition>()[i], volume.photons.column<PhotonPosition>()[i]);
        const Rgb a = fixedVolume.photons.column<PhotonPower>()[i], b = volume.photons.column<PhotonPower>()[i];
        ASSERT_NEAR(a.y, b.y, 1e-5f * b.y);
    }

    // Without single scattering: no Volume|Direct photons, the others unchanged in kind.
    auto noSingle = params;
    noSingle["photon.store_single_scattering"] = false;
    const PipelineRun multiple = runPipeline(scene, kPhotonsOnly, {"volume_photons"}, noSingle, boxFilm(4, 4));
    for (std::uint8_t c : multiple.get<VolumePhotonMap>("volume_photons").photons.column<PhotonClassColumn>())
        ASSERT_FALSE(c & PhotonClass::Direct);
    EXPECT_GT(multiple.get<VolumePhotonMap>("volume_photons").emitted, volume.emitted);

    // store = "surface" keeps no volume photons; a target then makes no sense.
    const PipelineRun surface = runPipeline(scene, kPhotonsOnly, {"volume_photons"},
                                    {{"photon.photons", std::int64_t{5000}}, {"photon.store", std::string("surface")}},
                                    boxFilm(4, 4));
    EXPECT_EQ(surface.get<VolumePhotonMap>("volume_photons").photons.size(), 0u);
    auto bad = params;
    bad["photon.store"] = std::string("surface");
    EXPECT_THROW(runPipeline(scene, kPhotonsOnly, {"volume_photons"}, bad, boxFilm(4, 4)), InputError);
}

// ---------------------------------------------------------------------------
// Pilot radii

// For uniformly random photons of density rho, the ball out to the k-th other
// neighbour holds k photons on average: E[rho 4/3 pi r^3] = k.
TEST(PhotonRadius, BallsHoldKPhotonsOnAverage) {
    auto map = std::make_shared<VolumePhotonMap>();
    const std::size_t n = 30000;
    for (std::size_t i = 0; i < n; ++i) {
        jobs::Rng rng(5, jobs::streamKey("uniform-volume"), i);
        test::addVolumePhoton(*map, Vec3(rng.uniform(), rng.uniform(), rng.uniform()), Vec3(0, 0, 1), Rgb(1.0f));
    }
    const PassRegistration* pass = findPass("photon_radius");
    ASSERT_NE(pass, nullptr);
    const Scene scene;
    for (const std::int64_t k : {std::int64_t{10}, std::int64_t{40}}) {
        const auto out = test::runPass(*pass, scene, nullptr, boxFilm(4, 4), {{"photons", test::makeBuffer(map)}},
                                       {{"k", k}});
        const auto radii = test::bufferAs<PhotonRadii>(out.at("radii")).radii.column<PhotonRadius>();
        ASSERT_EQ(radii.size(), n);
        double sum = 0.0;
        int interior = 0;
        const auto positions = map->photons.column<PhotonPosition>();
        for (std::size_t i = 0; i < n; ++i) {
            const Vec3 p = positions[i];
            if (glm::any(glm::lessThan(p, Vec3(0.25f))) || glm::any(glm::greaterThan(p, Vec3(0.75f)))) continue;
            sum += static_cast<double>(n) * 4.0 / 3.0 * M_PI * std::pow(radii[i], 3.0);
            ++interior;
        }
        ASSERT_GT(interior, 3000);
        EXPECT_NEAR(sum / interior / static_cast<double>(k), 1.0, 0.03) << "k = " << k;
    }
    // Each radius is exactly the distance to the k-th nearest other photon, by
    // brute force, also on clustered photons with duplicates.
    auto clustered = std::make_shared<VolumePhotonMap>();
    for (std::size_t i = 0; i < 4000; ++i) {
        jobs::Rng rng(6, jobs::streamKey("clustered-volume"), i);
        Vec3 p(rng.uniform(), rng.uniform(), rng.uniform());
        if (i % 3 == 0) p = Vec3(0.2f) + 0.01f * p;  // a dense blob
        if (i % 7 == 0) p.y = 0.5f;                  // a plane
        if (i % 11 == 0 && i > 0) p = clustered->photons.column<PhotonPosition>()[i - 1];  // duplicates
        test::addVolumePhoton(*clustered, p, Vec3(0, 0, 1), Rgb(1.0f));
    }
    const std::int64_t kExact = 12;
    const auto exact = test::runPass(*pass, scene, nullptr, boxFilm(4, 4), {{"photons", test::makeBuffer(clustered)}},
                                     {{"k", kExact}});
    const auto exactRadii = test::bufferAs<PhotonRadii>(exact.at("radii")).radii.column<PhotonRadius>();
    const auto points = clustered->photons.column<PhotonPosition>();
    std::vector<float> d2(points.size());
    for (std::size_t i = 0; i < points.size(); ++i) {
        for (std::size_t j = 0; j < points.size(); ++j) d2[j] = KdTree::distance2(points[i], points[j]);
        std::nth_element(d2.begin(), d2.begin() + kExact, d2.end());
        ASSERT_EQ(exactRadii[i], std::sqrt(d2[static_cast<std::size_t>(kExact)])) << "photon " << i;
    }

    // The scale multiplies, the clamp bounds.
    const auto base = test::runPass(*pass, scene, nullptr, boxFilm(4, 4), {{"photons", test::makeBuffer(map)}});
    const auto scaled = test::runPass(*pass, scene, nullptr, boxFilm(4, 4), {{"photons", test::makeBuffer(map)}},
                                      {{"radius_scale", 2.0}, {"max_radius", 0.05}});
    const auto r1 = test::bufferAs<PhotonRadii>(base.at("radii")).radii.column<PhotonRadius>();
    const auto r2 = test::bufferAs<PhotonRadii>(scaled.at("radii")).radii.column<PhotonRadius>();
    int clamped = 0;
    for (std::size_t i = 0; i < n; ++i) {
        ASSERT_FLOAT_EQ(r2[i], std::min(2.0f * r1[i], 0.05f));
        clamped += r2[i] == 0.05f;
    }
    EXPECT_GT(clamped, 100);
}

// ---------------------------------------------------------------------------
// Camera segments

// A camera outside a null-bounded fog box: each camera sample that crosses the
// box gives exactly one segment, from the entry to the exit point, with the
// sample's weight; the wall behind it is an eye vertex attenuated by the box's
// transmittance.
TEST(VolumeEye, SegmentsSpanTheMediumAndAttenuateWhatLiesBehind) {
    Scene scene;
    const Rgb sigmaA(0.1f, 0.2f, 0.3f), sigmaS(0.3f);
    scene.media.emplace_back(sigmaA, sigmaS, 0.0f);
    Shape box;
    box.geometry = makeCubeMesh();  // [-1, 1]^3
    box.bsdf = addBsdf(scene, makeNull());
    box.interiorMedium = 0;
    scene.shapes.push_back(box);
    Shape wall;
    TriangleMesh plane = makeRectangleMesh();
    plane.transform(glm::translate(Mat4(1.0f), Vec3(0, 0, -3.0f)) * glm::scale(Mat4(1.0f), Vec3(20.0f)));
    wall.geometry = plane;
    wall.bsdf = addDiffuse(scene, Rgb(0.5f));
    scene.shapes.push_back(wall);
    addPointLight(scene, Vec3(0.0f, 0.0f, 3.0f), Rgb(1.0f));
    scene.camera.eye = Vec3(0.2f, 0.1f, 4.0f);
    scene.camera.target = Vec3(0.0f, 0.0f, 0.0f);
    scene.camera.fovYDegrees = 50.0f;
    scene.finalize();

    const PassRegistration* pass = findPass("volume_eye");
    ASSERT_NE(pass, nullptr);
    const RayQuery rays(scene);
    const int spp = 2;
    const auto out = test::runPass(*pass, scene, &rays, boxFilm(12, 12), {}, {{"spp", std::int64_t{spp}}});
    const SegmentBuffer& segments = test::bufferAs<EyeSegments>(out.at("eye_segments")).segments;
    const EyeVertexBuffer& vertices = test::bufferAs<EyeVertices>(out.at("eye_vertices")).vertices;
    ASSERT_EQ(vertices.size(), 12u * 12u * spp) << "every sample reaches the wall";
    ASSERT_GT(segments.size(), 50u);
    ASSERT_LT(segments.size(), vertices.size());

    const auto origin = segments.column<SegmentOrigin>();
    const auto direction = segments.column<SegmentDirection>();
    const auto tNear = segments.column<SegmentTNear>();
    const auto tFar = segments.column<SegmentTFar>();
    const auto pixel = segments.column<SegmentPixel>();
    const auto throughput = segments.column<SegmentThroughput>();
    std::uint32_t previousPixel = 0;
    for (std::size_t i = 0; i < segments.size(); ++i) {
        EXPECT_GE(pixel[i], previousPixel) << "pixel order";
        previousPixel = pixel[i];
        EXPECT_EQ(segments.column<SegmentMedium>()[i], 0);
        EXPECT_LT(glm::length(origin[i] - scene.camera.eye), 1e-5f) << "segments share the camera ray's origin";
        EXPECT_NEAR(glm::length(direction[i]), 1.0f, 1e-6f);
        // The box's slab intersection along this ray.
        float enter = -kInfinity, exit = kInfinity;
        for (int a = 0; a < 3; ++a) {
            const float t0 = (-1.0f - origin[i][a]) / direction[i][a], t1 = (1.0f - origin[i][a]) / direction[i][a];
            enter = std::max(enter, std::min(t0, t1));
            exit = std::min(exit, std::max(t0, t1));
        }
        ASSERT_LT(enter, exit);
        EXPECT_NEAR(tNear[i], enter, 2e-3f);
        EXPECT_NEAR(tFar[i], exit, 2e-3f);
        EXPECT_EQ(throughput[i], Rgb(1.0f / spp));
    }
    // Vertices behind the box carry its transmittance; the others only 1/spp.
    const auto vertexPosition = vertices.column<EyePosition>();
    const auto vertexThroughput = vertices.column<EyeThroughput>();
    int behind = 0;
    for (std::size_t v = 0; v < vertices.size(); ++v) {
        const Vec3 d = glm::normalize(vertexPosition[v] - scene.camera.eye);
        float enter = 0.0f, exit = kInfinity;
        for (int a = 0; a < 3; ++a) {
            const float t0 = (-1.0f - scene.camera.eye[a]) / d[a], t1 = (1.0f - scene.camera.eye[a]) / d[a];
            enter = std::max(enter, std::min(t0, t1));
            exit = std::min(exit, std::max(t0, t1));
        }
        const float length = enter < exit ? exit - enter : 0.0f;
        behind += length > 0.0f;
        const Rgb expected = (1.0f / spp) * glm::exp(-(sigmaA + sigmaS) * length);
        for (int c = 0; c < 3; ++c) EXPECT_NEAR(vertexThroughput[v][c], expected[c], 2e-3f * expected[c] + 1e-7f);
    }
    EXPECT_EQ(static_cast<std::size_t>(behind), segments.size());
}

// ---------------------------------------------------------------------------
// The whole pipeline

// Single scattering only (photons stored at their first event, max_depth 1):
// the BRE converges to the airlight integral as the photon count grows and
// the radii shrink. The photons in a beam's reach number about rho pi r^2 L,
// i.e. N^(1/3) k^(2/3) with r ~ (k / N)^(1/3): with k fixed the noise would
// fall only as N^(-1/6). k grows as sqrt(N) here, which still shrinks the
// radii (as N^(-1/6)) while the noise falls as N^(-1/3), a factor 0.63 per
// fourfold photon count.
TEST(Bre, SingleScatteringConvergesToTheAirlightIntegral) {
    const test::AirlightScene setup;
    const int size = 8;
    std::vector<double> expected;
    for (int y = 0; y < size; ++y)
        for (int x = 0; x < size; ++x) expected.push_back(setup.expected(x, y, size));

    const Pipeline& bre = *findPipeline("bre");
    double previousError = 1e30, previousRadius = 1e30;
    std::vector<double> errors;
    for (const auto& [photons, k] : {std::pair<std::int64_t, std::int64_t>{15000, 15}, {60000, 30}, {240000, 60}}) {
        // The RMS relative error over the pixels of two independent renderings.
        double squared = 0.0, meanRadius = 0.0;
        int terms = 0;
        for (const std::uint64_t seed : {1, 2}) {
            const PipelineRun run = runPipeline(setup.scene, bre, {"image", "photon_radii"},
                                                {{"photon.volume_photons", photons},
                                                 {"photon.photons", std::int64_t{1} << 40},
                                                 {"photon.max_depth", std::int64_t{1}},
                                                 {"photon_radius.k", k},
                                                 {"volume_eye.spp", std::int64_t{4}}},
                                                boxFilm(size, size), seed);
            const std::vector<Rgb> image = run.get<Film>("image").resolve();
            for (std::size_t i = 0; i < image.size(); ++i) {
                squared += sqr(static_cast<float>(image[i].y / expected[i] - 1.0));
                ++terms;
            }
            const auto radii = run.get<PhotonRadii>("photon_radii").radii.column<PhotonRadius>();
            for (float r : radii) meanRadius += r / (2.0 * static_cast<double>(radii.size()));
        }
        const double error = std::sqrt(squared / terms);
        std::printf("bre airlight: %lld photons, k %lld, mean radius %.4f, relative RMS error %.4f\n",
                    static_cast<long long>(photons), static_cast<long long>(k), meanRadius, error);
        EXPECT_LT(meanRadius, 0.9 * previousRadius);
        EXPECT_LT(error, previousError) << photons << " photons";
        previousError = error;
        previousRadius = meanRadius;
        errors.push_back(error);
    }
    // Observed over five seed pairs: 0.10-0.13, 0.065-0.087 and 0.048-0.060.
    EXPECT_LT(errors.back(), 0.65 * errors.front());
    EXPECT_LT(errors.back(), 0.07);
}

// Henyey-Greenstein scattering (g = 0.6) of a point light seen along camera
// rays: the BRE's phase factor against the path tracer's single scattering.
// Points between the camera and the light scatter forwards towards the
// camera, points beyond it backwards, so a flipped phase convention changes
// the image by far more than the tolerance (checked with g = -0.6).
TEST(Bre, AnisotropicSingleScatteringMatchesThePathTracer) {
    const auto render = [](float g, const std::string& pipeline) {
        test::AirlightScene setup;
        setup.scene.media[0] = HomogeneousMedium(Rgb(setup.sigmaA), Rgb(setup.sigmaS), g);
        const Pipeline& p = *findPipeline(pipeline);
        const std::map<std::string, ParamValue> params =
            pipeline == "pt" ? std::map<std::string, ParamValue>{{"pt.spp", std::int64_t{256}},
                                                                 {"pt.max_depth", std::int64_t{1}}}
                             : std::map<std::string, ParamValue>{{"photon.volume_photons", std::int64_t{120000}},
                                                                 {"photon.photons", std::int64_t{1} << 40},
                                                                 {"photon.max_depth", std::int64_t{1}},
                                                                 {"photon_radius.k", std::int64_t{40}},
                                                                 {"volume_eye.spp", std::int64_t{4}}};
        const PipelineRun run = runPipeline(setup.scene, p, {"image"}, params, boxFilm(8, 8));
        double sum = 0.0;
        for (const Rgb& c : run.get<Film>("image").resolve()) sum += c.y;
        return sum / 64.0;
    };
    const double pt = render(0.6f, "pt");
    const double bre = render(0.6f, "bre");
    const double flipped = render(-0.6f, "bre");
    std::printf("HG g = 0.6: pt %.5f, bre %.5f; bre with g = -0.6: %.5f\n", pt, bre, flipped);
    EXPECT_NEAR(bre / pt, 1.0, 0.04);
    EXPECT_GT(std::abs(flipped / pt - 1.0), 0.2);
}

// Multiple scattering, a null boundary and a lit floor (data/medium-box): the
// whole pipeline against the path tracer, per 8 x 8-pixel block.
TEST(Bre, MediumBoxMatchesThePathTracer) {
    const Scene scene = loadScene(std::string(FLUXGRAPH_SOURCE_DIR) + "/data/medium-box/medium-box.toml");
    const int size = 32;
    const PipelineRun pt = runPipeline(scene, *findPipeline("pt"), {"image"},
                                       {{"pt.spp", std::int64_t{512}}, {"pt.max_depth", std::int64_t{32}}},
                                       boxFilm(size, size));
    const PipelineRun bre = runPipeline(scene, *findPipeline("bre"), {"image"},
                                        {{"photon.volume_photons", std::int64_t{100000}},
                                         {"photon.photons", std::int64_t{1} << 40},
                                         {"photon.max_depth", std::int64_t{32}},
                                         {"volume_eye.spp", std::int64_t{16}}},
                                        boxFilm(size, size));
    const std::vector<Rgb> a = pt.get<Film>("image").resolve(), b = bre.get<Film>("image").resolve();
    double sumPt = 0.0, sumBre = 0.0;
    int blocks = 0;
    for (int by = 0; by < size; by += 8) {
        for (int bx = 0; bx < size; bx += 8) {
            double blockPt = 0.0, blockBre = 0.0;
            for (int y = by; y < by + 8; ++y)
                for (int x = bx; x < bx + 8; ++x) {
                    blockPt += luminance(a[static_cast<std::size_t>(y) * size + x]);
                    blockBre += luminance(b[static_cast<std::size_t>(y) * size + x]);
                }
            sumPt += blockPt;
            sumBre += blockBre;
            if (blockPt < 0.5) continue;  // the black background above the box
            ++blocks;
            EXPECT_NEAR(blockBre / blockPt, 1.0, 0.08) << "block " << bx << "," << by;
        }
    }
    EXPECT_GE(blocks, 8);
    EXPECT_NEAR(sumBre / sumPt, 1.0, 0.02);
    std::printf("medium box: bre / pt = %.4f over the image\n", sumBre / sumPt);
}

std::vector<float> aov(const Film& film, const std::string& name) {
    for (const auto& [n, values] : film.aovs())
        if (n == name) return values;
    return {};
}

TEST(Bre, IdenticalForOneAndTwoThreads) {
    const Scene scene = foggyGlassScene(0.4f);
    const Pipeline& bre = *findPipeline("bre");
    const std::map<std::string, ParamValue> params = {{"photon.volume_photons", std::int64_t{30000}},
                                                      {"photon.photons", std::int64_t{1} << 40},
                                                      {"photon.batch_size", std::int64_t{5000}},
                                                      {"volume_eye.spp", std::int64_t{2}}};
    const PipelineRun one = runPipeline(scene, bre, {"image"}, params, boxFilm(24, 20), 3, 1);
    const PipelineRun two = runPipeline(scene, bre, {"image"}, params, boxFilm(24, 20), 3, 2);
    const Film& a = one.get<Film>("image");
    const Film& b = two.get<Film>("image");
    const std::vector<Rgb> pa = a.resolve(), pb = b.resolve();
    ASSERT_EQ(pa.size(), pb.size());
    EXPECT_EQ(std::memcmp(pa.data(), pb.data(), pa.size() * sizeof(Rgb)), 0);
    EXPECT_EQ(aov(a, "query_cost"), aov(b, "query_cost"));
    double cost = 0.0;
    for (float c : aov(a, "query_cost")) cost += c;
    EXPECT_GT(cost, 1000.0);
    // Something was rendered, and another seed renders something else.
    double sum = 0.0;
    for (const Rgb& p : pa) sum += p.y;
    EXPECT_GT(sum, 0.0);
    const PipelineRun other = runPipeline(scene, bre, {"image"}, params, boxFilm(24, 20), 4, 2);
    const std::vector<Rgb> pc = other.get<Film>("image").resolve();
    EXPECT_NE(std::memcmp(pa.data(), pc.data(), pa.size() * sizeof(Rgb)), 0);
    EXPECT_EQ(one.pass("beam_query").counters.at("photons_tested"),
              two.pass("beam_query").counters.at("photons_tested"));
}


// ---------------------------------------------------------------------------
// The test scenes against their path-traced references

// Box-averages factor x factor blocks (the reference is rendered at 128 x 128;
// the tests render the same view at a lower resolution).
ImageChannels downsample(const ImageChannels& image, int factor) {
    ImageChannels out;
    out.width = image.width / factor;
    out.height = image.height / factor;
    out.rgb.assign(static_cast<std::size_t>(out.width) * out.height, Rgb(0.0f));
    for (int y = 0; y < out.height * factor; ++y)
        for (int x = 0; x < out.width * factor; ++x)
            out.rgb[static_cast<std::size_t>(y / factor) * out.width + x / factor] +=
                image.rgb[static_cast<std::size_t>(y) * image.width + x] / static_cast<float>(factor * factor);
    return out;
}

struct ReferenceErrors {
    std::vector<double> rmse;         // per pixel, over the crop
    std::vector<double> relmse;
    std::vector<double> energyError;  // |mean / reference mean - 1| over the crop, luminance
};

// Renders data/<scene>/bre.toml at size x size (box filter) for each volume
// photon count and compares it with the block-averaged reference over `crop`.
ReferenceErrors breErrorsAgainstReference(const std::string& scene, const std::string& reference, int size,
                                          std::int64_t spp, const std::vector<std::int64_t>& counts,
                                          const CropRect& crop) {
    const std::string dir = std::string(FLUXGRAPH_SOURCE_DIR) + "/data/" + scene;
    const Job job = loadJob(dir + "/bre.toml");
    const Scene sceneData = loadScene(job.scenePath, job.sceneDefines);
    const ImageChannels full = readImageLinear(reference);
    EXPECT_EQ(full.width % size, 0);
    const ImageChannels target = downsample(full, full.width / size);
    const auto meanLuminance = [&](const ImageChannels& image) {
        double sum = 0.0;
        for (int y = crop.y; y < crop.y + crop.height; ++y)
            for (int x = crop.x; x < crop.x + crop.width; ++x)
                sum += luminance(image.rgb[static_cast<std::size_t>(y) * image.width + x]);
        return sum / (crop.width * crop.height);
    };
    const double targetMean = meanLuminance(target);
    const RayQuery rays(sceneData);
    ReferenceErrors errors;
    for (const std::int64_t count : counts) {
        JobParams params = job.params;
        params.values["photon"]["volume_photons"] = {count, "test"};
        params.values["volume_eye"]["spp"] = {spp, "test"};
        Pipeline pipeline = job.pipeline;
        pipeline.results = {"image"};
        const ExecutionPlan plan = ExecutionPlan::build(pipeline, params, job.path);
        RunOptions options;
        options.seed = job.seed;
        options.film = boxFilm(size, size);
        const RunResult result = execute(plan, sceneData, rays, options);
        const Film& film = *static_cast<const Film*>(result.results.at("image").data.get());
        ImageChannels image;
        image.width = image.height = size;
        image.rgb = film.resolve();
        const ImageMetrics metrics = compareImages(image, target, crop);
        const double energy = std::abs(meanLuminance(image) / targetMean - 1.0);
        std::printf("bre %s: %lld volume photons, RMSE %.5f, relMSE %.5f, mean off by %.2f %%\n", scene.c_str(),
                    static_cast<long long>(count), metrics.rmse, metrics.relmse, 100.0 * energy);
        errors.rmse.push_back(metrics.rmse);
        errors.relmse.push_back(metrics.relmse);
        errors.energyError.push_back(energy);
    }
    return errors;
}

std::string referenceOf(const std::string& scene) {
    return std::string(FLUXGRAPH_SOURCE_DIR) + "/data/" + scene + "/reference/reference.exr";
}

// The reference is bidirectional (tools/render_bdpt_references.sh, 4096
// samples per pixel as two halves whose difference has an RMSE of 0.0075 at
// 128 x 128, so its own noise is about 0.004): a path tracer's reference of
// this scene was floored by the fireflies of the rare paths that find the
// light through the sphere (RMSE about 0.38 at 32 x 32 whatever the photon
// count). The comparison is at 32 x 32 (4 x 4 blocks of the reference)
// without the rows that hold the light itself. Measured: RMSE 0.138, 0.086,
// 0.065 and the mean 6.3, 2.9 and 1.7 % off the reference's over 2k, 8k and
// 32k volume photons.
TEST(BreScenes, VolumetricCausticConvergesTowardsTheReference) {
    const std::string reference = referenceOf("volumetric-caustic");
    if (!std::filesystem::exists(reference))
        GTEST_SKIP() << "no reference " << reference << " yet (tools/render_bdpt_references.sh renders it)";
    const ReferenceErrors errors = breErrorsAgainstReference("volumetric-caustic", reference, 32, 4,
                                                             {2000, 8000, 32000}, CropRect{0, 4, 32, 28});
    for (std::size_t i = 1; i < errors.rmse.size(); ++i) EXPECT_LT(errors.rmse[i], errors.rmse[i - 1]);
    EXPECT_LT(errors.rmse.back(), 0.7 * errors.rmse.front());
    EXPECT_LT(errors.energyError.back(), 0.05);
}

// Spot-fog is dark but for the beam and the floor, and its absolute error is
// set by the surface part's noise (4 camera samples per pixel) and the
// reference's: the relative error shows the convergence. Over six seeds
// relMSE fell at every step (0.028-0.036, 0.023-0.026, 0.021-0.023) while the
// RMSE stayed at 0.008-0.010; the mean luminance was within 5.4 % of the
// reference's (two path-traced renders of this scene differ by 2 %).
TEST(BreScenes, SpotFogConvergesTowardsTheReference) {
    const std::string reference = referenceOf("spot-fog");
    if (!std::filesystem::exists(reference))
        GTEST_SKIP() << "no path-traced reference " << reference << " yet (tools/render_references.sh renders it)";
    const ReferenceErrors errors =
        breErrorsAgainstReference("spot-fog", reference, 32, 4, {2000, 8000, 32000}, CropRect{0, 0, 32, 32});
    for (std::size_t i = 1; i < errors.relmse.size(); ++i) EXPECT_LT(errors.relmse[i], errors.relmse[i - 1]);
    EXPECT_LT(errors.energyError.back(), 0.1);
}

}  // namespace
}  // namespace fg
