// Chi-square goodness-of-fit of every non-specular sampling routine against its
// own pdf(): directions come from sample() (the lobe choice drawn from a second,
// independent stream), the expected histogram from integrating pdf(). Specular
// samples are dropped, so the non-specular pdf must integrate to the
// probability of choosing a non-specular lobe for the test to pass.
#include "engine/shading/bsdf.h"
#include "jobs/random.h"
#include "tests/engine/shading/bsdf_test_util.h"
#include "tests/support/chi2.h"

#include <gtest/gtest.h>

#include <functional>
#include <ostream>
#include <string>
#include <vector>

namespace fg {
namespace {

struct Chi2Case {
    std::string name;
    std::function<std::shared_ptr<Bsdf>()> make;
    Vec3 wo;
    int thetaBins = 20;
    int phiBins = 40;
};

// Lets GoogleTest name a case instead of dumping its bytes.
void PrintTo(const Chi2Case& c, std::ostream* os) { *os << c.name; }

ConductorIor gold() { return *conductorPreset("Au"); }

std::string angleName(float deg) { return std::to_string(static_cast<int>(deg)) + "deg"; }
std::string alphaName(float alpha) { return "alpha" + std::to_string(static_cast<int>(alpha * 100.0f + 0.5f)); }

std::vector<Chi2Case> chi2Cases() {
    std::vector<Chi2Case> cases;
    cases.push_back({"Diffuse_30deg", [] { return makeDiffuse(makeConstantTexture(Rgb(0.7f))); },
                     test::directionFromAngles(30.0f, 20.0f)});

    const float alphas[] = {0.1f, 0.3f, 0.7f};
    const float angles[] = {10.0f, 45.0f, 80.0f};
    for (float alpha : alphas) {
        // The narrowest lobes need finer cells for the Simpson integration of
        // the expected counts to be accurate.
        const int thetaBins = alpha < 0.2f ? 40 : 20, phiBins = 2 * thetaBins;
        for (float angle : angles) {
            cases.push_back({"RoughConductor_" + alphaName(alpha) + "_" + angleName(angle),
                             [alpha] { return makeRoughConductor(gold(), alpha); },
                             test::directionFromAngles(angle, 35.0f), thetaBins, phiBins});
        }
    }

    // The transmission density of a rough dielectric jumps to zero where the
    // generalised half vector wo + eta' wi reaches the horizon (GGX has D > 0
    // there), i.e. on the cone cos(theta_i) = -cos(theta_o) / eta'. Simpson's
    // rule assumes a smooth density inside a cell, so the incident angles are
    // chosen to put that cone on a cell edge of the 4.5 degree grid, moved by
    // kConeShift into the cell where the density is non-zero: far more than the
    // rounding of sampled directions (so none spills into the empty cell) and
    // less than the inset of the harness's quadrature nodes from cell edges.
    constexpr double kConeShift = 4e-6;  // radians
    const double eta = 1.5;
    struct DielectricAngle {
        float incidenceDeg;
        bool inside;
    };
    const auto toDegrees = [](double radians) { return static_cast<float>(radians * 180.0 / M_PI); };
    // From either side the transmitted density is non-zero on the far side of
    // the cone from the pole on wo's side (larger theta in the frame of wo).
    const auto outsideForEdge = [&](double edgeDeg) {
        return DielectricAngle{toDegrees(std::acos(-eta * std::cos(edgeDeg * M_PI / 180.0 + kConeShift))), false};
    };
    const auto insideForEdge = [&](double edgeDeg) {
        return DielectricAngle{toDegrees(std::acos(std::cos(edgeDeg * M_PI / 180.0 + kConeShift) / eta)), true};
    };
    const DielectricAngle dielectricAngles[] = {
        outsideForEdge(130.5f), outsideForEdge(117.0f), outsideForEdge(99.0f),  // about 13, 47 and 76 degrees
        // From the inside the cone exists only beyond 48.2 degrees (cos < 1 / eta).
        {10.0f, true}, {45.0f, true}, insideForEdge(72.0f),  // the last about 78 degrees
    };
    for (float alpha : alphas) {
        for (const DielectricAngle& a : dielectricAngles) {
            Vec3 wo = test::directionFromAngles(a.incidenceDeg, -60.0f);
            if (a.inside) wo.z = -wo.z;
            cases.push_back({"RoughDielectric_" + alphaName(alpha) + "_" + angleName(a.incidenceDeg) +
                                 (a.inside ? "_inside" : "_outside"),
                             [alpha] { return makeRoughDielectric(1.5f, alpha); }, wo, 40, 80});
        }
    }

    cases.push_back({"Plastic_20deg", [] { return makePlastic(makeConstantTexture(Rgb(0.5f)), 1.5f); },
                     test::directionFromAngles(20.0f, 0.0f)});
    cases.push_back({"Plastic_75deg", [] { return makePlastic(makeConstantTexture(Rgb(0.5f)), 1.5f); },
                     test::directionFromAngles(75.0f, 100.0f)});
    cases.push_back({"PlasticNonlinear_50deg",
                     [] { return makePlastic(makeConstantTexture(Rgb(0.9f, 0.2f, 0.4f)), 1.7f, true); },
                     test::directionFromAngles(50.0f, 200.0f)});

    // Beckmann lobes, and the rough plastic with either distribution. Beckmann's
    // D vanishes at the horizon, so its transmission density reaches zero
    // continuously at the cone where GGX's jumps, and any angle will do.
    // Every roughness meets near-normal, oblique and grazing incidence; the
    // narrowest lobe, whose cells must be three times finer, only the oblique
    // one, to keep the suite fast.
    struct BeckmannCase {
        float alpha;
        std::vector<float> conductorAngles, outsideAngles, insideAngles, plasticAngles;
    };
    const BeckmannCase beckmannCases[] = {
        {0.05f, {60.0f}, {60.0f}, {60.0f}, {60.0f}},
        {0.2f, {5.0f, 60.0f, 85.0f}, {5.0f, 85.0f}, {60.0f}, {5.0f, 60.0f, 85.0f}},
        {0.5f, {5.0f, 60.0f, 85.0f}, {60.0f}, {5.0f, 85.0f}, {5.0f, 60.0f, 85.0f}},
        {0.9f, {5.0f, 60.0f, 85.0f}, {85.0f}, {60.0f}, {5.0f, 60.0f, 85.0f}},
    };
    for (const BeckmannCase& b : beckmannCases) {
        const float alpha = b.alpha;
        const int thetaBins = alpha < 0.1f ? 60 : 20;
        for (float angle : b.conductorAngles) {
            cases.push_back({"BeckmannConductor_" + alphaName(alpha) + "_" + angleName(angle),
                             [alpha] { return makeRoughConductor(gold(), alpha, Rgb(1.0f), MicrofacetType::Beckmann); },
                             test::directionFromAngles(angle, 35.0f), thetaBins, 2 * thetaBins});
        }
        for (bool inside : {false, true}) {
            for (float angle : inside ? b.insideAngles : b.outsideAngles) {
                Vec3 wo = test::directionFromAngles(angle, -60.0f);
                if (inside) wo.z = -wo.z;
                cases.push_back({"BeckmannDielectric_" + alphaName(alpha) + "_" + angleName(angle) +
                                     (inside ? "_inside" : "_outside"),
                                 [alpha] { return makeRoughDielectric(1.5f, alpha, MicrofacetType::Beckmann); }, wo,
                                 thetaBins, 2 * thetaBins});
            }
        }
        for (float angle : b.plasticAngles) {
            cases.push_back({"RoughPlasticBeckmann_" + alphaName(alpha) + "_" + angleName(angle),
                             [alpha] {
                                 return makeRoughPlastic(makeConstantTexture(Rgb(0.5f)), 1.5f, alpha,
                                                         MicrofacetType::Beckmann);
                             },
                             test::directionFromAngles(angle, 100.0f), thetaBins, 2 * thetaBins});
        }
    }
    cases.push_back({"RoughPlasticGgx_alpha30_45deg",
                     [] {
                         return makeRoughPlastic(makeConstantTexture(Rgb(0.8f, 0.2f, 0.4f)), 1.6f, 0.3f,
                                                 MicrofacetType::Ggx, true, Rgb(0.7f));
                     },
                     test::directionFromAngles(45.0f, 10.0f)});

    Vec3 back = test::directionFromAngles(40.0f, 70.0f);
    back.z = -back.z;
    cases.push_back({"TwoSidedDiffuse_back", [] { return makeTwoSided(makeDiffuse(makeConstantTexture(Rgb(0.5f)))); },
                     back});
    cases.push_back({"TwoSidedRoughConductor_back", [] { return makeTwoSided(makeRoughConductor(gold(), 0.3f)); },
                     back});
    return cases;
}

const int kChi2TestCount = static_cast<int>(chi2Cases().size());

class BsdfChi2 : public ::testing::TestWithParam<Chi2Case> {};

TEST_P(BsdfChi2, SampleMatchesPdf) {
    const Chi2Case& c = GetParam();
    const std::shared_ptr<Bsdf> bsdf = c.make();
    const Vec3 wo = glm::normalize(c.wo);
    const Vec2 uv(0.25f, 0.75f);

    test::Chi2Config config;
    config.thetaBins = c.thetaBins;
    config.phiBins = c.phiBins;
    config.samples = 500'000;
    config.testCount = kChi2TestCount;
    config.seed = std::hash<std::string>{}(c.name);

    jobs::Rng lobeRng(config.seed, jobs::streamKey("bsdf-chi2-lobe"), 0);
    const test::DirectionSampler sampler = [&](const Vec2& u) -> std::optional<Vec3> {
        const float uLobe = lobeRng.uniform();
        const std::optional<BsdfSample> s = bsdf->sample(wo, uv, uLobe, u, TransportMode::Radiance);
        if (!s || s->isSpecular()) return std::nullopt;
        return s->wi;
    };
    const test::DirectionPdf density = [&](const Vec3& wi) { return static_cast<double>(bsdf->pdf(wo, wi, uv)); };

    const test::Chi2Result result = test::chi2SphereTest(sampler, density, config);
    EXPECT_TRUE(result.passed) << c.name << ": " << result.message;
}

INSTANTIATE_TEST_SUITE_P(Bsdf, BsdfChi2, ::testing::ValuesIn(chi2Cases()),
                         [](const ::testing::TestParamInfo<Chi2Case>& param) { return param.param.name; });

// A sampler that ignores part of its density must be caught: the rough
// conductor's pdf paired with a sampler for a different roughness.
TEST(BsdfChi2Sanity, DetectsMismatchedRoughness) {
    const std::shared_ptr<Bsdf> sampled = makeRoughConductor(gold(), 0.3f);
    const std::shared_ptr<Bsdf> claimed = makeRoughConductor(gold(), 0.36f);
    const Vec3 wo = test::directionFromAngles(45.0f, 0.0f);
    test::Chi2Config config;
    config.samples = 500'000;
    const test::Chi2Result result = test::chi2SphereTest(
        [&](const Vec2& u) -> std::optional<Vec3> {
            const auto s = sampled->sample(wo, Vec2(0.0f), 0.5f, u, TransportMode::Radiance);
            return s ? std::optional<Vec3>(s->wi) : std::nullopt;
        },
        [&](const Vec3& wi) { return static_cast<double>(claimed->pdf(wo, wi, Vec2(0.0f))); }, config);
    EXPECT_FALSE(result.passed) << result.message;
}

// The same on the coarse grid of the Beckmann dielectric cases, from inside,
// where most of the density is transmitted: a 10 % error in roughness shows.
TEST(BsdfChi2Sanity, DetectsMismatchedBeckmannTransmission) {
    const std::shared_ptr<Bsdf> sampled = makeRoughDielectric(1.5f, 0.2f, MicrofacetType::Beckmann);
    const std::shared_ptr<Bsdf> claimed = makeRoughDielectric(1.5f, 0.22f, MicrofacetType::Beckmann);
    Vec3 wo = test::directionFromAngles(30.0f, 0.0f);
    wo.z = -wo.z;
    test::Chi2Config config;
    config.samples = 500'000;
    jobs::Rng lobeRng(config.seed, jobs::streamKey("bsdf-chi2-lobe"), 0);
    const test::Chi2Result result = test::chi2SphereTest(
        [&](const Vec2& u) -> std::optional<Vec3> {
            const auto s = sampled->sample(wo, Vec2(0.0f), lobeRng.uniform(), u, TransportMode::Radiance);
            return s ? std::optional<Vec3>(s->wi) : std::nullopt;
        },
        [&](const Vec3& wi) { return static_cast<double>(claimed->pdf(wo, wi, Vec2(0.0f))); }, config);
    EXPECT_FALSE(result.passed) << result.message;
}

}  // namespace
}  // namespace fg
