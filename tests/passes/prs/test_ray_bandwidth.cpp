// Eqs. 7-8 of Herzog et al. 2007: the photon pass's bounded path densities on
// scenes whose densities are known in closed form (point light over a diffuse
// or a mirror floor), and the bandwidth model on hand-made rays (h(x_0) = 0,
// h_0 and dh, clamping, the calibration at M = 1e5, the M^(-1/6) rate).
#include "passes/passes.h"
#include "passes/prs/ray_bandwidth.h"

#include "engine/accel/ray_query.h"
#include "engine/core/job.h"
#include "engine/core/scheduler.h"
#include "engine/scene/scene_toml.h"
#include "jobs/parallel.h"
#include "jobs/random.h"

#include <gtest/gtest.h>
#if defined(__x86_64__) || defined(__SSE__)
#include <xmmintrin.h>
#endif

#include <array>
#include <cmath>
#include <cstring>
#include <limits>
#include <map>
#include <memory>
#include <string>

namespace fg {
namespace {

// A point light 1 above a floor (diffuse or mirror), a diffuse ceiling at height 3.
Scene pointLightBox(const std::string& floorMaterial) {
    const std::string text = R"(
[camera]
eye = [0, -5, 1.5]
target = [0, 0, 1.5]
up = [0, 0, 1]
fov = 60
width = 16
height = 16
[[material]]
name = "white"
type = "diffuse"
reflectance = [0.5, 0.5, 0.5]
[[material]]
name = "mirror"
type = "conductor"
material = "none"
[[shape]]
type = "rectangle"
material = ")" + floorMaterial + R"("
transform = [{ scale = 10 }]
[[shape]]
type = "rectangle"
material = "white"
flip_normals = true
transform = [{ scale = 10 }, { translate = [0, 0, 3] }]
[[light]]
type = "point"
position = [0, 0, 1]
intensity = 10
)";
    return parseTomlScene(text, "point-light-box.toml", ".");
}

std::shared_ptr<const PhotonRays> tracePhotonRays(const Scene& scene, std::int64_t photons, double clampDistance) {
    const Pipeline pipeline{"rays", "photon rays only", {{"photon", "photon", {}, {}, 0}}, {"photon_rays"}};
    JobParams jobParams;
    jobParams.values["photon"]["photons"] = {ParamValue(photons), "test"};
    jobParams.values["photon"]["photon_rays"] = {ParamValue(true), "test"};
    jobParams.values["photon"]["max_depth"] = {ParamValue(std::int64_t{2}), "test"};
    jobParams.values["photon"]["clamp_distance"] = {ParamValue(clampDistance), "test"};
    const ExecutionPlan plan = ExecutionPlan::build(pipeline, jobParams, "test");
    const RayQuery rays(scene);
    RunOptions options;
    options.seed = 3;
    const RunResult result = execute(plan, scene, rays, options);
    return std::static_pointer_cast<const PhotonRays>(result.results.at("photon_rays").data);
}

void expectRelativeNear(double actual, double expected, double tolerance, const std::string& what) {
    EXPECT_NEAR(actual, expected, tolerance * std::abs(expected)) << what;
}

// Eq. 7 on L D D paths: p~_1 = p_e / D with p_e = 1 / (4 pi) (isotropic point
// light, the only light), then p~_2 = p~_1 (1 / pi) / D: cosine sampling's
// projected-solid-angle density is 1 / pi. D~ = 1.5 clamps the short rays.
TEST(PrsPhotonRays, BoundedDensityOnDiffusePaths) {
    const Scene scene = pointLightBox("white");
    const double clamp = 1.5;
    const auto rays = tracePhotonRays(scene, 4000, clamp);
    const PhotonRayBuffer& r = rays->rays;
    ASSERT_GT(r.size(), 4000u);
    int clampedDirect = 0, unclampedDirect = 0, secondRays = 0;
    for (std::size_t i = 0; i < r.size(); ++i) {
        const auto ray = r.get(i);
        const double length = ray.get<RayLength>();
        const double d = std::max(clamp * clamp, length * length);
        const Vec3 end = ray.get<RayOrigin>() + ray.get<RayLength>() * ray.get<RayDirection>();
        if (ray.get<RayEndNormal>() == Vec3(0.0f)) {
            // Escaped between the planes: clipped where it leaves the scene box.
            EXPECT_NEAR(std::max(std::abs(end.x), std::abs(end.y)), 10.0f, 1e-3f) << "ray " << i;
        } else {
            EXPECT_TRUE(std::abs(end.z) < 1e-3f || std::abs(end.z - 3.0f) < 1e-3f) << "ray " << i << " ends off the planes";
            EXPECT_LT(glm::dot(ray.get<RayEndNormal>(), ray.get<RayDirection>()), 0.0f);
        }
        if (ray.get<RayVertex>() == 0) {
            EXPECT_EQ(ray.get<RayClassColumn>(), PhotonRayClass::Direct);
            EXPECT_EQ(ray.get<RayOriginDensity>(), 0.0f);
            expectRelativeNear(ray.get<RayDensity>(), 1.0 / (4.0 * kPi * d), 1e-5, "direct ray");
            ++(length < clamp ? clampedDirect : unclampedDirect);
        } else {
            ASSERT_EQ(ray.get<RayVertex>(), 1);
            EXPECT_EQ(ray.get<RayClassColumn>(), PhotonRayClass::Global);
            // The path's previous ray is the one just before (rays of a path are consecutive).
            const auto previous = r.get(i - 1);
            ASSERT_EQ(previous.get<RayPath>(), ray.get<RayPath>());
            EXPECT_EQ(ray.get<RayOriginDensity>(), previous.get<RayDensity>());
            expectRelativeNear(ray.get<RayDensity>(), ray.get<RayOriginDensity>() / (kPi * d), 1e-5, "second ray");
            EXPECT_GT(glm::dot(ray.get<RayOriginNormal>(), ray.get<RayDirection>()), 0.0f);
            ++secondRays;
        }
    }
    EXPECT_GT(clampedDirect, 100);
    EXPECT_GT(unclampedDirect, 100);
    EXPECT_GT(secondRays, 1000);
}

// A specular bounce has no density: specular_pdf (100) stands in for p_s^perp,
// and the ray leaving the mirror is a caustic ray.
TEST(PrsPhotonRays, SpecularEventsUseSpecularPdf) {
    const Scene scene = pointLightBox("mirror");
    const double clamp = 0.5;
    const auto rays = tracePhotonRays(scene, 2000, clamp);
    int caustic = 0;
    for (std::size_t i = 0; i < rays->rays.size(); ++i) {
        const auto ray = rays->rays.get(i);
        if (ray.get<RayVertex>() != 1 || std::abs(ray.get<RayOrigin>().z) > 1e-3f) continue;  // not from the mirror
        const double length = ray.get<RayLength>();
        EXPECT_EQ(ray.get<RayClassColumn>(), PhotonRayClass::Caustic);
        expectRelativeNear(ray.get<RayDensity>(),
                           ray.get<RayOriginDensity>() * 100.0 / std::max(clamp * clamp, length * length), 1e-5,
                           "ray leaving the mirror");
        ++caustic;
    }
    EXPECT_GT(caustic, 500);
}

// --- The bandwidth model on hand-made rays ------------------------------------

PhotonRayBuffer::Record handMadeRay(std::uint64_t path, std::uint16_t vertex, float originDensity, float density,
                                    float length, std::uint8_t rayClass = PhotonRayClass::Global) {
    return PhotonRayBuffer::Record{Vec3(0.0f), Vec3(0, 0, 1), length, Rgb(1.0f), 0.0f, 0.0f, density, originDensity,
                                   rayClass, Vec3(0, 0, 1), Vec3(0, 0, -1), path, vertex};
}

// Rays of `paths` two-segment paths with log-uniform densities over eight decades.
PhotonRayBuffer randomPaths(std::uint64_t paths, std::uint64_t firstPath, std::uint64_t seed) {
    PhotonRayBuffer rays;
    for (std::uint64_t p = 0; p < paths; ++p) {
        jobs::Rng rng(seed, 7, p);
        const float first = std::pow(10.0f, -4.0f + 8.0f * rng.uniform());
        const float second = first * std::pow(10.0f, -2.0f + 4.0f * rng.uniform());
        rays.append(handMadeRay(firstPath + p, 0, 0.0f, first, 0.2f + rng.uniform()));
        rays.append(handMadeRay(firstPath + p, 1, first, second, 0.2f + 2.0f * rng.uniform()));
    }
    return rays;
}

TEST(PrsBandwidth, RayLeavingTheLightStartsAtZero) {
    PhotonRayBuffer rays;
    rays.append(handMadeRay(0, 0, 0.0f, 2.0f, 4.0f));
    rays.append(handMadeRay(0, 1, 2.0f, 0.5f, 2.0f));   // density falls: h grows along the ray
    rays.append(handMadeRay(1, 1, 0.5f, 2.0f, 1.0f));   // density rises: h shrinks
    BandwidthSettings settings;
    settings.maxScaling = 1e-6;  // no clamping here
    const BandwidthModel model = fitBandwidthModel(rays, 0.0f, settings);
    assignBandwidths(rays, model);
    const auto h0 = rays.column<RayH0>();
    const auto dh = rays.column<RayDh>();
    const double hAt2 = model.unclamped(2.0, PhotonRayClass::Global);
    const double hAtHalf = model.unclamped(0.5, PhotonRayClass::Global);
    ASSERT_GT(hAtHalf, hAt2);
    EXPECT_EQ(h0[0], 0.0f);  // h(x_0) = 0
    EXPECT_FLOAT_EQ(dh[0], static_cast<float>(hAt2 / 4.0));
    EXPECT_FLOAT_EQ(h0[1], static_cast<float>(hAt2));
    EXPECT_FLOAT_EQ(dh[1], static_cast<float>((hAtHalf - hAt2) / 2.0));
    EXPECT_FLOAT_EQ(h0[2], static_cast<float>(hAt2));  // min of the two ends
    EXPECT_EQ(dh[2], 0.0f);
    // h ~ p~^(-S/2): a density four times smaller gives 4^(S/2) times the bandwidth.
    EXPECT_NEAR(hAtHalf / hAt2, std::pow(4.0, 0.2), 1e-12);
}

// At M = 1e5 the pilot's mean unclamped h is C mu_C, mu_C = 0.2 <max(D~, length)>.
TEST(PrsBandwidth, PilotMeanIsCMuCAtCalibrationCount) {
    PhotonRayBuffer rays = randomPaths(50000, 0, 11);  // 1e5 rays, all global
    BandwidthSettings settings;
    settings.smoothness = 1.7;
    settings.pilotPaths = 1u << 30;
    const float clamp = 0.5f;
    const BandwidthModel model = fitBandwidthModel(rays, clamp, settings);
    ASSERT_EQ(model.countPerClass[PhotonRayClass::Global], 100000u);
    double lengthSum = 0.0, hSum = 0.0;
    for (std::size_t i = 0; i < rays.size(); ++i) {
        lengthSum += std::max(clamp, rays.column<RayLength>()[i]);
        hSum += model.unclamped(rays.column<RayDensity>()[i], PhotonRayClass::Global);
    }
    const double muC = 0.2 * lengthSum / static_cast<double>(rays.size());
    EXPECT_NEAR(model.sceneScale, muC, 1e-9 * muC);
    EXPECT_NEAR(hSum / static_cast<double>(rays.size()), 1.7 * muC, 1e-9 * muC);
    EXPECT_NEAR(model.typical(PhotonRayClass::Global), 1.7 * muC, 1e-9 * muC);
}

TEST(PrsBandwidth, ClampsToRangeAroundTypicalBandwidth) {
    PhotonRayBuffer rays = randomPaths(2000, 0, 5);
    rays.append(handMadeRay(9000, 1, 1.0f, 1e-30f, 1.0f));  // far below the pilot's densities
    rays.append(handMadeRay(9001, 1, 1.0f, 1e30f, 1.0f));   // far above
    BandwidthSettings settings;
    settings.maxScaling = 0.25;
    settings.pilotPaths = 2000;
    const BandwidthModel model = fitBandwidthModel(rays, 0.1f, settings);
    const double centre = model.typical(PhotonRayClass::Global);
    EXPECT_DOUBLE_EQ(model.clamped(1e-30, PhotonRayClass::Global), centre / 0.25);
    EXPECT_DOUBLE_EQ(model.clamped(1e30, PhotonRayClass::Global), centre * 0.25);
    assignBandwidths(rays, model);
    int atBounds = 0;
    for (std::size_t i = 0; i < rays.size(); ++i) {
        const float h0 = rays.column<RayH0>()[i];
        const float hEnd = h0 + rays.column<RayDh>()[i] * rays.column<RayLength>()[i];
        if (rays.column<RayVertex>()[i] > 0) {
            EXPECT_GE(h0, static_cast<float>(centre * 0.25) * (1 - 1e-6f));
        }
        EXPECT_LE(hEnd, static_cast<float>(centre / 0.25) * (1 + 1e-6f));
        atBounds += std::abs(hEnd - static_cast<float>(centre / 0.25)) < 1e-6f * hEnd;
    }
    EXPECT_GE(atBounds, 1);
}

// Doubling M (the pilot unchanged) scales every h, clamped or not, by 2^(-1/6).
TEST(PrsBandwidth, DoublingPhotonCountScalesEveryBandwidth) {
    BandwidthSettings settings;
    settings.pilotPaths = 3000;
    settings.maxScaling = 0.5;  // so that some rays are clamped
    PhotonRayBuffer single = randomPaths(3000, 0, 21);
    PhotonRayBuffer doubled = randomPaths(3000, 0, 21);
    const PhotonRayBuffer more = randomPaths(3000, 3000, 22);
    for (std::size_t i = 0; i < more.size(); ++i) doubled.append(more.get(i));
    const BandwidthModel a = fitBandwidthModel(single, 0.1f, settings);
    const BandwidthModel b = fitBandwidthModel(doubled, 0.1f, settings);
    assignBandwidths(single, a);
    assignBandwidths(doubled, b);
    const double factor = std::pow(2.0, -1.0 / 6.0);
    int clamped = 0;
    for (std::size_t i = 0; i < single.size(); ++i) {
        const double hEndA = single.column<RayH0>()[i] + single.column<RayDh>()[i] * single.column<RayLength>()[i];
        const double hEndB = doubled.column<RayH0>()[i] + doubled.column<RayDh>()[i] * doubled.column<RayLength>()[i];
        EXPECT_NEAR(doubled.column<RayH0>()[i], factor * single.column<RayH0>()[i], 1e-5 * single.column<RayH0>()[i]);
        EXPECT_NEAR(hEndB, factor * hEndA, 1e-5 * hEndA);
        const double unclamped = a.unclamped(single.column<RayDensity>()[i], PhotonRayClass::Global);
        clamped += std::abs(unclamped - hEndA) > 1e-4 * hEndA;
    }
    EXPECT_GT(clamped, 100);
}


// The pass's lean output is its input in some order, every column the splat
// reads carried over bit for bit and h_0, dh those of the model fitted on the
// input: what gathering through an index permutation must preserve.
TEST(PrsBandwidth, SplatRaysAreTheInputPermutedWithItsBandwidths) {
    const Scene scene = pointLightBox("white");
    const Pipeline pipeline{"rays",
                            "photon rays and their bandwidths",
                            {{"photon", "photon", {}, {}, 0}, {"ray_bandwidth", "ray_bandwidth", {}, {}, 0}},
                            {"photon_rays", "splat_rays"}};
    JobParams jobParams;
    jobParams.values["photon"]["photons"] = {ParamValue(std::int64_t{3000}), "test"};
    jobParams.values["photon"]["photon_rays"] = {ParamValue(true), "test"};
    jobParams.values["photon"]["clamp_distance"] = {ParamValue(0.05), "test"};
    jobParams.values["ray_bandwidth"]["pilot_paths"] = {ParamValue(std::int64_t{1000}), "test"};
    const ExecutionPlan plan = ExecutionPlan::build(pipeline, jobParams, "test");
    const RayQuery rayQuery(scene);
    RunOptions options;
    options.seed = 5;
    const RunResult result = execute(plan, scene, rayQuery, options);
    const auto& input = *std::static_pointer_cast<const PhotonRays>(result.results.at("photon_rays").data);
    const auto& output = *std::static_pointer_cast<const SplatRays>(result.results.at("splat_rays").data);
    const PhotonRayBuffer& in = input.rays;
    const SplatRayBuffer& out = output.rays;
    ASSERT_GT(in.size(), 3000u);
    ASSERT_EQ(out.size(), in.size());
    EXPECT_EQ(output.bytes(), out.size() * kSplatRayBytes);

    BandwidthSettings settings;
    settings.smoothness = 1.0;
    settings.sensitivity = 0.4;
    settings.maxScaling = 0.2;
    settings.pilotPaths = 1000;
    const BandwidthModel model = fitBandwidthModel(in, input.clampDistance, settings);
    EXPECT_EQ(output.countPerClass, model.countPerClass);
    EXPECT_EQ(output.normalisation, model.normalisation);

    const auto bitsOf = [](const Vec3& origin, const Vec3& direction, float length) {
        std::array<std::uint32_t, 7> key{};
        std::memcpy(key.data(), &origin, sizeof(Vec3));
        std::memcpy(key.data() + 3, &direction, sizeof(Vec3));
        std::memcpy(key.data() + 6, &length, sizeof(float));
        return key;
    };
    std::map<std::array<std::uint32_t, 7>, std::size_t> inputOf;
    for (std::size_t i = 0; i < in.size(); ++i)
        inputOf.emplace(bitsOf(in.column<RayOrigin>()[i], in.column<RayDirection>()[i], in.column<RayLength>()[i]), i);
    std::vector<bool> used(in.size(), false);
    std::size_t moved = 0;
    for (std::size_t o = 0; o < out.size(); ++o) {
        const auto found =
            inputOf.find(bitsOf(out.column<RayOrigin>()[o], out.column<RayDirection>()[o], out.column<RayLength>()[o]));
        ASSERT_NE(found, inputOf.end()) << "ray " << o;
        const std::size_t i = found->second;
        ASSERT_FALSE(used[i]) << "ray " << o;
        used[i] = true;
        moved += i != o;
        EXPECT_EQ(out.column<RayPower>()[o], in.column<RayPower>()[i]);
        EXPECT_EQ(out.column<RayClassColumn>()[o], in.column<RayClassColumn>()[i]);
        EXPECT_EQ(out.column<RayOriginNormal>()[o], in.column<RayOriginNormal>()[i]);
        EXPECT_EQ(out.column<RayEndNormal>()[o], in.column<RayEndNormal>()[i]);
        const RayBandwidth b =
            rayBandwidth(model, in.column<RayOriginDensity>()[i], in.column<RayDensity>()[i], in.column<RayVertex>()[i],
                         in.column<RayClassColumn>()[i], in.column<RayLength>()[i]);
        EXPECT_EQ(out.column<RayH0>()[o], b.h0);
        EXPECT_EQ(out.column<RayDh>()[o], b.dh);
    }
    EXPECT_GT(moved, out.size() / 2) << "the 5D order moves most rays";
}

// Densities below FLT_MIN (deep paths in millimetre scenes: 1.3 % of the
// Cornell box's rays) are subnormal floats, which arithmetic reads as zero
// when the thread's denormals-are-zero flag is set. The passes met both
// modes in one test process (set from the command line and in a test run
// alone, clear after other tests had started the thread pool), and
// FinalGathering's figures moved with the order of the tests: the model must
// give the same bits in either mode.
#if defined(__x86_64__) || defined(__SSE__)
TEST(PrsBandwidth, SameBandwidthsWithAndWithoutDenormalsAreZero) {
    const auto makeRays = [] {
        PhotonRayBuffer rays = randomPaths(3000, 0, 31);
        for (std::uint64_t p = 0; p < 200; ++p) {  // densities that underflowed to subnormals or zero
            const float tiny =
                p % 4 == 0 ? 0.0f : std::numeric_limits<float>::denorm_min() * static_cast<float>(1 + 997 * p);
            rays.append(handMadeRay(3000 + p, 1, p % 2 ? tiny : 1e-3f, tiny, 0.5f));
        }
        return rays;
    };
    BandwidthSettings settings;
    settings.pilotPaths = 1u << 30;
    const auto run = [&](bool denormalsAreZero, double& w) {
        constexpr unsigned kFlushToZero = 0x8000, kDenormalsAreZero = 0x40;
        const unsigned saved = _mm_getcsr();
        _mm_setcsr(denormalsAreZero ? (saved | kFlushToZero | kDenormalsAreZero)
                                    : (saved & ~(kFlushToZero | kDenormalsAreZero)));
        PhotonRayBuffer rays = makeRays();
        const BandwidthModel model = fitBandwidthModel(rays, 0.1f, settings);
        assignBandwidths(rays, model);
        _mm_setcsr(saved);
        w = model.normalisation;
        return rays;
    };
    double wOff = 0.0, wOn = 0.0;
    const PhotonRayBuffer off = run(false, wOff), on = run(true, wOn);
    EXPECT_GT(wOff, 0.0);
    EXPECT_EQ(wOff, wOn);
    ASSERT_EQ(off.size(), on.size());
    int differing = 0;
    for (std::size_t i = 0; i < off.size(); ++i)
        differing += std::memcmp(&off.column<RayH0>()[i], &on.column<RayH0>()[i], sizeof(float)) != 0 ||
                     std::memcmp(&off.column<RayDh>()[i], &on.column<RayDh>()[i], sizeof(float)) != 0;
    EXPECT_EQ(differing, 0);
}
#endif

}  // namespace
}  // namespace fg
