// The photon pass against scenes with known irradiance: photon counts in small
// disks (standard density estimation) and footprint-weighted estimates
// (Frisvad et al. 2014, Eqs. 4, 10-12) for direct light from a point and a disk
// source and for a mirror caustic; classification, null boundaries, and
// reproducibility across thread counts and batch sizes.
#include "engine/shading/bsdf.h"
#include "engine/shading/differentials.h"
#include "engine/shading/light.h"
#include "engine/buffers/photon_buffers.h"
#include "engine/accel/ray_query.h"
#include "engine/scene/scene.h"
#include "engine/core/scheduler.h"
#include "jobs/parallel.h"

#include <glm/gtc/matrix_transform.hpp>
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <functional>

namespace fg {
namespace {

struct PhotonRun {
    std::shared_ptr<const PhotonMap> caustic;
    std::shared_ptr<const PhotonMap> global;
    PassStats stats;
};

PhotonRun runPhotonPass(const Scene& scene, const std::map<std::string, ParamValue>& params, int threads = 0,
                        std::uint64_t seed = 1) {
    const Pipeline pipeline{"photons", "photon pass only", {{"photon", "photon", {}, {}, 0}},
                            {"caustic_photons", "global_photons"}};
    JobParams jobParams;
    for (const auto& [name, value] : params) jobParams.values["photon"][name] = {value, "test"};
    const ExecutionPlan plan = ExecutionPlan::build(pipeline, jobParams, "test");
    const jobs::ThreadLimit limit(threads);
    const RayQuery rays(scene);
    RunOptions options;
    options.seed = seed;
    const RunResult result = execute(plan, scene, rays, options);
    PhotonRun run;
    run.caustic = std::static_pointer_cast<const PhotonMap>(result.results.at("caustic_photons").data);
    run.global = std::static_pointer_cast<const PhotonMap>(result.results.at("global_photons").data);
    run.stats = result.stats.at(0);
    return run;
}

int addDiffuse(Scene& scene, const Rgb& albedo = Rgb(0.5f)) {
    scene.bsdfs.push_back(makeDiffuse(makeConstantTexture(albedo)));
    return static_cast<int>(scene.bsdfs.size()) - 1;
}

int addBsdf(Scene& scene, std::shared_ptr<Bsdf> bsdf) {
    scene.bsdfs.push_back(std::move(bsdf));
    return static_cast<int>(scene.bsdfs.size()) - 1;
}

void addShape(Scene& scene, decltype(Shape::geometry) geometry, int bsdf) {
    Shape shape;
    shape.geometry = std::move(geometry);
    shape.bsdf = bsdf;
    scene.shapes.push_back(std::move(shape));
}

// The floor z = 0, [-h, h]^2, facing up.
TriangleMesh floorMesh(float halfSize) {
    TriangleMesh mesh = makeRectangleMesh();
    mesh.transform(glm::scale(Mat4(1.0f), Vec3(halfSize)));
    return mesh;
}

void addPointLight(Scene& scene, const Vec3& position, const Rgb& intensity) {
    scene.lights.push_back(makePointLight(position, intensity));
    scene.lightShape.push_back(-1);
}

// A one-sided disk emitter of radius r at height h facing down.
void addDiskLight(Scene& scene, float radius, float height, const Rgb& radiance) {
    Shape disk;
    TriangleMesh mesh = makeDiskMesh(256);
    mesh.transform(glm::translate(Mat4(1.0f), Vec3(0, 0, height)) * glm::rotate(Mat4(1.0f), kPi, Vec3(1, 0, 0)) *
                   glm::scale(Mat4(1.0f), Vec3(radius)));
    disk.geometry = mesh;
    disk.bsdf = addDiffuse(scene, Rgb(0.0f));
    disk.areaLight = static_cast<int>(scene.lights.size());
    scene.lights.push_back(makeAreaLight(disk, radiance));
    scene.lightShape.push_back(static_cast<int>(scene.shapes.size()));
    scene.shapes.push_back(disk);
}

// Irradiance on the floor below a point source of intensity I at height h.
double pointIrradiance(double intensity, double h, double l) { return intensity * h / std::pow(h * h + l * l, 1.5); }

// Irradiance below a diffuse disk emitter (radius r, radiance L, height h) at lateral distance l.
double diskIrradiance(double L, double r, double h, double l) {
    const double a = h * h + l * l + r * r;
    return 0.5 * M_PI * L * (1.0 - (h * h + l * l - r * r) / std::sqrt(a * a - 4.0 * l * l * r * r));
}

// Mean of f over the floor disk of radius r around (cx, cy), by a polar midpoint rule.
double diskAverage(const std::function<double(double, double)>& f, double cx, double cy, double r) {
    const int radial = 48, angular = 96;
    double sum = 0.0, weight = 0.0;
    for (int i = 0; i < radial; ++i) {
        const double rho = r * (i + 0.5) / radial;
        for (int j = 0; j < angular; ++j) {
            const double phi = 2.0 * M_PI * (j + 0.5) / angular;
            sum += rho * f(cx + rho * std::cos(phi), cy + rho * std::sin(phi));
            weight += rho;
        }
    }
    return sum / weight;
}

// Photons of `photonClass` within distance r of the floor point (x, y): their count and summed power.
struct DiskTally {
    std::int64_t count = 0;
    glm::dvec3 power{0.0};
};
DiskTally tally(const PhotonMap& map, std::uint8_t photonClass, double x, double y, double r) {
    DiskTally t;
    const auto positions = map.photons.column<PhotonPosition>();
    const auto powers = map.photons.column<PhotonPower>();
    const auto classes = map.photons.column<PhotonClassColumn>();
    for (std::size_t i = 0; i < map.photons.size(); ++i) {
        if (classes[i] != photonClass) continue;
        if (std::hypot(positions[i].x - x, positions[i].y - y) >= r) continue;
        ++t.count;
        t.power += glm::dvec3(powers[i]);
    }
    return t;
}

// Footprint-weighted irradiance estimate at a floor point (Eq. 10 without the
// BRDF): E(x) = sum_p pi K(|M_p (x - x_p)|) Phi_p / A_p.
glm::dvec3 footprintIrradiance(const PhotonMap& map, std::uint8_t photonClass, const Vec3& x) {
    glm::dvec3 sum(0.0);
    const auto positions = map.photons.column<PhotonPosition>();
    const auto powers = map.photons.column<PhotonPower>();
    const auto normals = map.photons.column<PhotonNormal>();
    const auto classes = map.photons.column<PhotonClassColumn>();
    const auto du = map.photons.column<PhotonDu>();
    const auto dv = map.photons.column<PhotonDv>();
    for (std::size_t i = 0; i < map.photons.size(); ++i) {
        if (classes[i] != photonClass) continue;
        const Vec3 offset = x - positions[i];
        if (glm::length(offset) > footprintMajorRadius(du[i], dv[i])) continue;
        const float k = silvermanKernel(glm::length(footprintFilter(du[i], dv[i], normals[i]).apply(offset)));
        if (k > 0.0f) sum += glm::dvec3(powers[i]) * static_cast<double>(kPi * k / footprintArea(du[i], dv[i]));
    }
    return sum;
}

// Expected photon count in a disk of area A with irradiance E, each photon carrying `power`:
// the count is binomial with a small success probability, so its sigma is about sqrt(count).
void expectCountMatches(const DiskTally& t, double expectedIrradiance, double photonPower, double area,
                        const std::string& where) {
    const double expectedCount = expectedIrradiance * area / photonPower;
    ASSERT_GT(expectedCount, 400.0) << where;
    const double sigma = std::sqrt(expectedCount) * photonPower / area;
    EXPECT_NEAR(t.power.y / area, expectedIrradiance, 4.0 * sigma) << where << ", photons " << t.count;
}

TEST(PhotonPass, PointLightDirectPhotonsGiveIrradiance) {
    Scene scene;
    const float halfSize = 10.0f, height = 1.0f;
    addShape(scene, floorMesh(halfSize), addDiffuse(scene));
    const Rgb intensity(1.0f, 2.0f, 3.0f);
    addPointLight(scene, Vec3(0, 0, height), intensity);
    scene.finalize();
    const std::int64_t photons = 1000000;
    const PhotonRun run = runPhotonPass(
        scene, {{"photons", photons}, {"store_direct", true}, {"differentials", false}, {"max_depth", std::int64_t{1}}});
    const PhotonMap& map = *run.global;
    EXPECT_EQ(map.emitted, static_cast<std::uint64_t>(photons));
    EXPECT_FALSE(map.hasDifferentials);
    EXPECT_EQ(run.caustic->photons.size(), 0u);
    EXPECT_EQ(run.stats.items, photons);
    EXPECT_EQ(run.stats.counters.at("direct_photons"), static_cast<std::int64_t>(map.photons.size()));

    // Every photon carries Phi / N, in the light's colour.
    const double photonPower = 4.0 * M_PI * intensity.y / photons;
    for (const Rgb& p : map.photons.column<PhotonPower>()) {
        ASSERT_NEAR(p.y, photonPower, 1e-6 * photonPower);
        ASSERT_NEAR(p.z / p.x, 3.0, 1e-5);
    }
    // The floor receives the fraction Omega / 4 pi of the flux (binomial count).
    const double a = halfSize, h = height;
    const double omega = 4.0 * std::asin(a * a / (a * a + h * h));
    const double p = omega / (4.0 * M_PI);
    const double expectedCount = p * photons;
    EXPECT_NEAR(static_cast<double>(map.photons.size()), expectedCount, 4.0 * std::sqrt(photons * p * (1.0 - p)));

    const double r = 0.2;
    for (const Vec2 at : {Vec2(0.0f), Vec2(0.5f, 0.0f), Vec2(-0.3f, 0.9f), Vec2(1.5f, -1.0f)}) {
        const double expected = diskAverage([&](double x, double y) { return pointIrradiance(intensity.y, h, std::hypot(x, y)); },
                                            at.x, at.y, r);
        expectCountMatches(tally(map, PhotonClass::Direct, at.x, at.y, r), expected, photonPower, M_PI * r * r,
                           "at " + std::to_string(at.x) + "," + std::to_string(at.y));
    }
}

TEST(PhotonPass, DiskLightDirectPhotonsGiveIrradiance) {
    Scene scene;
    const float radius = 0.5f, height = 1.0f, radiance = 2.0f;
    addShape(scene, floorMesh(8.0f), addDiffuse(scene));
    addDiskLight(scene, radius, height, Rgb(radiance));
    scene.finalize();
    const std::int64_t photons = 1000000;
    const PhotonRun run = runPhotonPass(
        scene, {{"photons", photons}, {"store_direct", true}, {"differentials", false}, {"store", std::string("global")}});
    const PhotonMap& map = *run.global;
    // The mesh disk is a 256-gon: its area is what the light emits from.
    const double area = 0.5 * 256 * std::sin(2.0 * M_PI / 256) * radius * radius;
    const double photonPower = M_PI * radiance * area / photons;
    const double r = 0.15;
    for (const Vec2 at : {Vec2(0.0f), Vec2(0.4f, 0.2f), Vec2(-0.8f, 0.3f), Vec2(0.2f, -1.4f)}) {
        const double expected = diskAverage(
            [&](double x, double y) { return diskIrradiance(radiance, radius, height, std::hypot(x, y)); }, at.x, at.y, r);
        expectCountMatches(tally(map, PhotonClass::Direct, at.x, at.y, r), expected, photonPower, M_PI * r * r,
                           "at " + std::to_string(at.x) + "," + std::to_string(at.y));
    }
    // Photons the floor reflects up may land on the emitter's (black, diffuse) surface.
    for (std::uint8_t c : map.photons.column<PhotonClassColumn>()) EXPECT_TRUE(c == PhotonClass::Direct || c == PhotonClass::Global);
}

// Photon differentials (Eqs. 2-12) as density estimator: with smoothing s the
// footprints of neighbouring photons overlap about s^2 times, so the estimate's
// relative noise is about sqrt(1.8) / s per point; averaged over 16 points
// further apart than a footprint it is below 1 %. A wrong footprint area (Eq. 4)
// or filter (Eq. 12) shows up as a scale error.
TEST(PhotonPass, FootprintEstimateOfDirectLightMatchesIrradiance) {
    for (bool areaLight : {false, true}) {
        SCOPED_TRACE(areaLight ? "disk light" : "point light");
        Scene scene;
        addShape(scene, floorMesh(8.0f), addDiffuse(scene));
        if (areaLight) addDiskLight(scene, 0.5f, 1.0f, Rgb(2.0f));
        else addPointLight(scene, Vec3(0, 0, 1.0f), Rgb(1.0f));
        scene.finalize();
        const std::int64_t photons = 400000;
        const PhotonRun run = runPhotonPass(scene, {{"photons", photons}, {"store_direct", true}, {"smoothing", 40.0},
                                                    {"max_depth", std::int64_t{1}}});
        const PhotonMap& map = *run.global;
        EXPECT_EQ(map.collapsedFootprints, 0u);
        ASSERT_GT(map.photons.size(), 0u);
        double measured = 0.0, expected = 0.0;
        for (int i = 0; i < 4; ++i)
            for (int j = 0; j < 4; ++j) {
                const double x = -0.9 + 0.6 * i, y = -0.9 + 0.6 * j;
                const double l = std::hypot(x, y);
                measured += footprintIrradiance(map, PhotonClass::Direct, Vec3(x, y, 0.0)).y;
                expected += areaLight ? diskIrradiance(2.0, 0.5, 1.0, l) : pointIrradiance(1.0, 1.0, l);
            }
    EXPECT_NEAR(measured / expected, 1.0, 0.04);
        // Footprints lie in the floor.
        const auto du = map.photons.column<PhotonDu>();
        for (std::size_t i = 0; i < map.photons.size(); i += 97) {
            EXPECT_NEAR(du[i].z, 0.0f, 1e-4f * glm::length(du[i]));
            EXPECT_GT(glm::length(du[i]), 0.0f);
        }
    }
}

// A point light beside a perfect vertical mirror x = 1: the floor's caustic is
// the direct light of the mirror image at (2, 0, h).
TEST(PhotonPass, MirrorCausticMatchesImageSource) {
    Scene scene;
    const float height = 1.0f;
    TriangleMesh floor = makeRectangleMesh();
    floor.transform(glm::translate(Mat4(1.0f), Vec3(-1.5f, 0, 0)) * glm::scale(Mat4(1.0f), Vec3(2.5f, 4.0f, 1.0f)));
    addShape(scene, floor, addDiffuse(scene));
    TriangleMesh mirror = makeRectangleMesh();
    mirror.transform(glm::translate(Mat4(1.0f), Vec3(1.0f, 0.0f, 2.0f)) *
                     glm::rotate(Mat4(1.0f), -0.5f * kPi, Vec3(0, 1, 0)) * glm::scale(Mat4(1.0f), Vec3(2.0f, 4.0f, 1.0f)));
    addShape(scene, mirror, addBsdf(scene, makeConductor(*conductorPreset("none"))));
    addPointLight(scene, Vec3(0, 0, height), Rgb(1.0f));
    scene.finalize();

    const std::int64_t photons = 1000000;
    const PhotonRun run = runPhotonPass(scene, {{"photons", photons}, {"store", std::string("caustic")},
                                                {"caustic_only_paths", true}, {"smoothing", 40.0}});
    const PhotonMap& caustic = *run.caustic;
    EXPECT_TRUE(caustic.hasDifferentials);
    EXPECT_EQ(run.global->photons.size(), 0u);
    ASSERT_GT(caustic.photons.size(), 0u);
    for (std::uint8_t c : caustic.photons.column<PhotonClassColumn>()) ASSERT_EQ(c, PhotonClass::Caustic);
    EXPECT_EQ(run.stats.counters.at("caustic_photons"), static_cast<std::int64_t>(caustic.photons.size()));

    const Vec3 image(2.0f, 0.0f, height);
    const auto imageIrradiance = [&](double x, double y) {
        const double l = std::hypot(x - image.x, y - image.y);
        return pointIrradiance(1.0, height, l);
    };
    const double photonPower = 4.0 * M_PI / photons;
    const double r = 0.25;
    double measured = 0.0, expected = 0.0;
    for (const Vec2 at : {Vec2(0.0f), Vec2(-1.0f, 0.5f), Vec2(0.5f, -0.5f), Vec2(-0.5f, -1.2f)}) {
        expectCountMatches(tally(caustic, PhotonClass::Caustic, at.x, at.y, r),
                           diskAverage(imageIrradiance, at.x, at.y, r), photonPower, M_PI * r * r,
                           "at " + std::to_string(at.x) + "," + std::to_string(at.y));
    }
    for (int i = 0; i < 4; ++i)
        for (int j = 0; j < 4; ++j) {
            const double x = -2.4 + 0.6 * i, y = -0.9 + 0.6 * j;
            measured += footprintIrradiance(caustic, PhotonClass::Caustic, Vec3(x, y, 0.0)).y;
            expected += imageIrradiance(x, y);
        }
    EXPECT_NEAR(measured / expected, 1.0, 0.04);
}

// A glass ball on a diffuse floor: classes go where they belong.
Scene glassBallScene() {
    Scene scene;
    addShape(scene, floorMesh(4.0f), addDiffuse(scene, Rgb(0.8f)));
    addShape(scene, Sphere{Vec3(0.0f, 0.0f, 1.0f), 0.5f}, addBsdf(scene, makeDielectric(1.5f)));
    TriangleMesh wall = makeRectangleMesh();
    wall.transform(glm::translate(Mat4(1.0f), Vec3(-2.0f, 0, 2.0f)) * glm::rotate(Mat4(1.0f), 0.5f * kPi, Vec3(0, 1, 0)) *
                   glm::scale(Mat4(1.0f), Vec3(2.0f, 4.0f, 1.0f)));
    addShape(scene, wall, addDiffuse(scene, Rgb(0.6f)));
    addDiskLight(scene, 0.3f, 3.0f, Rgb(10.0f));
    addPointLight(scene, Vec3(1.0f, 0.5f, 2.5f), Rgb(3.0f));
    scene.finalize();
    return scene;
}

TEST(PhotonPass, ClassesAndOptions) {
    const Scene scene = glassBallScene();
    const std::int64_t photons = 50000;
    const PhotonRun all = runPhotonPass(scene, {{"photons", photons}, {"store_direct", true}});
    ASSERT_GT(all.caustic->photons.size(), 100u);
    std::int64_t direct = 0, global = 0;
    for (std::uint8_t c : all.global->photons.column<PhotonClassColumn>()) {
        direct += c == PhotonClass::Direct;
        global += c == PhotonClass::Global;
    }
    EXPECT_GT(direct, 0);
    EXPECT_GT(global, 0);
    EXPECT_EQ(direct + global, static_cast<std::int64_t>(all.global->photons.size()));
    EXPECT_EQ(all.stats.counters.at("direct_photons"), direct);
    EXPECT_EQ(all.stats.counters.at("global_photons"), global);
    // Caustic photons lie on the floor, the wall or the emitter's back, with footprints.
    const auto positions = all.caustic->photons.column<PhotonPosition>();
    const auto du = all.caustic->photons.column<PhotonDu>();
    const auto dv = all.caustic->photons.column<PhotonDv>();
    const auto normals = all.caustic->photons.column<PhotonNormal>();
    for (std::size_t i = 0; i < all.caustic->photons.size(); ++i) {
        EXPECT_TRUE(std::abs(positions[i].z) < 1e-3f || std::abs(positions[i].x + 2.0f) < 1e-3f ||
                    std::abs(positions[i].z - 3.0f) < 1e-3f);
        EXPECT_FALSE(footprintCollapsed(du[i], dv[i], normals[i]));
    }
    // Global photons carry no footprint.
    const auto globalDu = all.global->photons.column<PhotonDu>();
    const auto globalClass = all.global->photons.column<PhotonClassColumn>();
    for (std::size_t i = 0; i < all.global->photons.size(); ++i) {
        if (globalClass[i] == PhotonClass::Global) {
            ASSERT_EQ(globalDu[i], Vec3(0.0f));
        }
    }

    // Caustic photons only: the same caustic map, nothing else.
    const PhotonRun causticOnly = runPhotonPass(
        scene, {{"photons", photons}, {"store", std::string("caustic")}, {"caustic_only_paths", true}});
    EXPECT_EQ(causticOnly.global->photons.size(), 0u);
    ASSERT_EQ(causticOnly.caustic->photons.size(), all.caustic->photons.size());
    const auto onlyPositions = causticOnly.caustic->photons.column<PhotonPosition>();
    for (std::size_t i = 0; i < positions.size(); ++i) ASSERT_EQ(onlyPositions[i], positions[i]);

    // Without differentials: the same photons, without footprints.
    const PhotonRun plain = runPhotonPass(scene, {{"photons", photons}, {"differentials", false}});
    EXPECT_FALSE(plain.caustic->hasDifferentials);
    EXPECT_EQ(plain.caustic->collapsedFootprints, 0u);
    ASSERT_EQ(plain.caustic->photons.size(), all.caustic->photons.size() + all.caustic->collapsedFootprints);
    for (const Vec3& d : plain.caustic->photons.column<PhotonDu>()) ASSERT_EQ(d, Vec3(0.0f));
    EXPECT_EQ(plain.global->photons.size(), static_cast<std::size_t>(global));
}

bool samePhotons(const PhotonMap& a, const PhotonMap& b) {
    if (a.photons.size() != b.photons.size() || a.emitted != b.emitted ||
        a.collapsedFootprints != b.collapsedFootprints)
        return false;
    const auto equal = [](auto x, auto y) {
        return std::memcmp(x.data(), y.data(), x.size_bytes()) == 0;
    };
    return equal(a.photons.column<PhotonPosition>(), b.photons.column<PhotonPosition>()) &&
           equal(a.photons.column<PhotonIncident>(), b.photons.column<PhotonIncident>()) &&
           equal(a.photons.column<PhotonPower>(), b.photons.column<PhotonPower>()) &&
           equal(a.photons.column<PhotonNormal>(), b.photons.column<PhotonNormal>()) &&
           equal(a.photons.column<PhotonClassColumn>(), b.photons.column<PhotonClassColumn>()) &&
           equal(a.photons.column<PhotonDu>(), b.photons.column<PhotonDu>()) &&
           equal(a.photons.column<PhotonDv>(), b.photons.column<PhotonDv>());
}

TEST(PhotonPass, IdenticalForAnyThreadCountAndBatchSize) {
    const Scene scene = glassBallScene();
    const std::map<std::string, ParamValue> params = {{"photons", std::int64_t{30000}}, {"store_direct", true},
                                                      {"batch_size", std::int64_t{7000}}};
    const PhotonRun one = runPhotonPass(scene, params, 1);
    const PhotonRun two = runPhotonPass(scene, params, 2);
    ASSERT_GT(one.caustic->photons.size(), 0u);
    ASSERT_GT(one.global->photons.size(), 0u);
    EXPECT_TRUE(samePhotons(*one.caustic, *two.caustic));
    EXPECT_TRUE(samePhotons(*one.global, *two.global));
    auto otherBatches = params;
    otherBatches["batch_size"] = std::int64_t{1 << 18};
    const PhotonRun single = runPhotonPass(scene, otherBatches, 2);
    EXPECT_TRUE(samePhotons(*one.caustic, *single.caustic));
    EXPECT_TRUE(samePhotons(*one.global, *single.global));
    // A different seed gives different photons (the comparison can fail).
    const PhotonRun reseeded = runPhotonPass(scene, params, 2, 2);
    EXPECT_FALSE(samePhotons(*one.global, *reseeded.global));
}

// A batch longer than a wave (32768 paths) is traced in several waves whose
// chunk storage is reused; the maps must equal those of batches shorter than
// a wave, whatever the thread count.
TEST(PhotonPass, IdenticalWhenABatchSpansSeveralWaves) {
    const Scene scene = glassBallScene();
    const std::map<std::string, ParamValue> params = {{"photons", std::int64_t{70000}}, {"store_direct", true},
                                                      {"batch_size", std::int64_t{1 << 18}}};
    const PhotonRun waves = runPhotonPass(scene, params, 2);
    ASSERT_GT(waves.caustic->photons.size(), 0u);
    ASSERT_GT(waves.global->photons.size(), 0u);
    EXPECT_EQ(waves.caustic->emitted, 70000u);
    auto shortBatches = params;
    shortBatches["batch_size"] = std::int64_t{9000};
    const PhotonRun batches = runPhotonPass(scene, shortBatches, 1);
    EXPECT_TRUE(samePhotons(*waves.caustic, *batches.caustic));
    EXPECT_TRUE(samePhotons(*waves.global, *batches.global));
    const PhotonRun oneThread = runPhotonPass(scene, params, 1);
    EXPECT_TRUE(samePhotons(*waves.caustic, *oneThread.caustic));
    EXPECT_TRUE(samePhotons(*waves.global, *oneThread.global));
    // Fewer paths give other maps (the comparison can fail).
    auto fewer = params;
    fewer["photons"] = std::int64_t{69999};
    EXPECT_FALSE(samePhotons(*waves.global, *runPhotonPass(scene, fewer, 2).global));
}

// The pass's own seed replaces the job's for the photon streams alone: photons of
// seed s under any job seed are those of job seed s, and 0 means the job's seed.
TEST(PhotonPass, OwnSeedOverridesTheJobSeed) {
    const Scene scene = glassBallScene();
    std::map<std::string, ParamValue> params = {{"photons", std::int64_t{20000}}, {"store_direct", true}};
    const PhotonRun jobSeedTwo = runPhotonPass(scene, params, 2, 2);
    const PhotonRun jobSeedOne = runPhotonPass(scene, params, 2, 1);
    ASSERT_GT(jobSeedTwo.global->photons.size(), 0u);
    params["seed"] = std::int64_t{2};
    const PhotonRun ownSeedTwo = runPhotonPass(scene, params, 2, 1);
    EXPECT_TRUE(samePhotons(*ownSeedTwo.global, *jobSeedTwo.global));
    EXPECT_TRUE(samePhotons(*ownSeedTwo.caustic, *jobSeedTwo.caustic));
    EXPECT_FALSE(samePhotons(*ownSeedTwo.global, *jobSeedOne.global));
    params["seed"] = std::int64_t{0};
    const PhotonRun ownSeedZero = runPhotonPass(scene, params, 2, 2);
    EXPECT_TRUE(samePhotons(*ownSeedZero.global, *jobSeedTwo.global));
}

// Surfaces without a BSDF or with `null` are crossed without an event.
TEST(PhotonPass, NullBoundariesArePassedThrough) {
    Scene scene;
    addShape(scene, floorMesh(4.0f), addDiffuse(scene));
    addPointLight(scene, Vec3(0, 0, 1.0f), Rgb(1.0f));
    scene.finalize();
    Scene wrapped = scene;
    addShape(wrapped, Sphere{Vec3(0.0f), 10.0f}, addBsdf(wrapped, makeNull()));  // encloses everything
    addShape(wrapped, Sphere{Vec3(0.0f, 0.0f, 0.5f), 0.3f}, -1);              // around the light's path
    wrapped.finalize();
    const std::map<std::string, ParamValue> params = {{"photons", std::int64_t{20000}}, {"store_direct", true},
                                                      {"max_depth", std::int64_t{1}}};
    const PhotonRun bare = runPhotonPass(scene, params);
    const PhotonRun inside = runPhotonPass(wrapped, params);
    ASSERT_EQ(bare.global->photons.size(), inside.global->photons.size());
    ASSERT_GT(bare.global->photons.size(), 5000u);
    const auto a = bare.global->photons.column<PhotonPosition>();
    const auto b = inside.global->photons.column<PhotonPosition>();
    const auto da = bare.global->photons.column<PhotonDu>();
    const auto db = inside.global->photons.column<PhotonDu>();
    for (std::size_t i = 0; i < a.size(); ++i) {
        ASSERT_LT(glm::length(a[i] - b[i]), 1e-3f);
        ASSERT_LT(glm::length(da[i] - db[i]), 1e-3f * glm::length(da[i]));
    }
}

}  // namespace
}  // namespace fg
