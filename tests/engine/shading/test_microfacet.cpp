// Tests of the microfacet distributions on their own: normalisation of D, the
// projected-area identity that ties Smith's G1 to D, the exact Beckmann G1
// against Walter's rational approximation (what Mitsuba 3 evaluates), and a
// chi-square test of Beckmann's visible-normal sampling against its density.
#include "engine/shading/microfacet.h"
#include "jobs/random.h"
#include "tests/engine/shading/bsdf_test_util.h"
#include "tests/support/chi2.h"

#include <gtest/gtest.h>

#include <cmath>
#include <ostream>
#include <string>
#include <vector>

namespace fg {
namespace {

using test::directionFromAngles;

// Integral of f(m) D(m) over the hemisphere of normals, in slope space: with
// m = (-x, -y, 1) / sqrt(1 + x^2 + y^2), d(omega_m) = cos^3(theta_m) dx dy.
// Beckmann's slopes are Gaussian with standard deviation alpha / sqrt(2), so a
// square of half-width 6 alpha leaves out less than exp(-36) of the mass, and
// the midpoint rule converges fast on the smooth integrand.
template <class F>
double integrateOverSlopes(const BeckmannDistribution& d, F f, int steps = 600) {
    const double halfWidth = 6.0 * d.alpha();
    const double h = 2.0 * halfWidth / steps;
    double sum = 0.0;
    for (int i = 0; i < steps; ++i) {
        const double x = -halfWidth + (i + 0.5) * h;
        for (int j = 0; j < steps; ++j) {
            const double y = -halfWidth + (j + 0.5) * h;
            const double cosM = 1.0 / std::sqrt(1.0 + x * x + y * y);
            const Vec3 m(static_cast<float>(-x * cosM), static_cast<float>(-y * cosM), static_cast<float>(cosM));
            sum += f(m) * static_cast<double>(d.D(m)) * cosM * cosM * cosM;
        }
    }
    return sum * h * h;
}

const float kAlphas[] = {0.05f, 0.2f, 0.5f, 0.9f};
const float kAngles[] = {0.0f, 30.0f, 60.0f, 85.0f};

TEST(Beckmann, ProjectedNormalAreaIsOne) {
    for (float alpha : kAlphas) {
        const BeckmannDistribution d(alpha);
        const double projected = integrateOverSlopes(d, [](const Vec3& m) { return static_cast<double>(m.z); });
        EXPECT_NEAR(projected, 1.0, 1e-4) << "alpha " << alpha;
    }
}

TEST(Beckmann, MaskingMatchesProjectedArea) {
    // A direction sees the projected area of the macrosurface:
    // integral of G1(wo) max(0, wo.m) D(m) d(omega_m) = cos(theta_o).
    for (float alpha : kAlphas) {
        const BeckmannDistribution d(alpha);
        for (float angle : kAngles) {
            const Vec3 wo = directionFromAngles(angle, 40.0f);
            const double seen = integrateOverSlopes(
                d, [&](const Vec3& m) { return std::max(0.0, static_cast<double>(glm::dot(wo, m))); });
            EXPECT_NEAR(d.G1(wo) * seen, wo.z, 2e-4 + 1e-3 * wo.z) << "alpha " << alpha << " at " << angle;
        }
    }
}

TEST(Beckmann, MaskingAgreesWithWaltersApproximation) {
    // Mitsuba 3 evaluates G1 with Walter et al.'s rational fit (2007, Eq. 27),
    // quoted as within 0.35 % of the exact form used here.
    for (float alpha : kAlphas) {
        const BeckmannDistribution d(alpha);
        for (float angle = 0.0f; angle < 89.9f; angle += 0.5f) {
            const Vec3 w = directionFromAngles(angle, 0.0f);
            const double a = w.z / (alpha * std::sqrt(std::max(0.0, 1.0 - double(w.z) * w.z)));
            const double walter =
                a >= 1.6 ? 1.0 : (3.535 * a + 2.181 * a * a) / (1.0 + 2.276 * a + 2.577 * a * a);
            EXPECT_NEAR(d.G1(w), walter, 3.6e-3 * walter + 1e-6) << "alpha " << alpha << " at " << angle;
        }
    }
    const BeckmannDistribution d(0.3f);
    EXPECT_EQ(d.G1(Vec3(0.0f, 0.0f, 1.0f)), 1.0f);
    EXPECT_EQ(d.G1(Vec3(1.0f, 0.0f, 0.0f)), 0.0f);
    EXPECT_EQ(d.G1(Vec3(0.6f, 0.0f, -0.8f)), d.G1(Vec3(0.6f, 0.0f, 0.8f))) << "symmetric for transmission";
}

TEST(Beckmann, DensityMatchesTheClosedForm) {
    const BeckmannDistribution d(0.4f);
    for (float angle : {0.0f, 20.0f, 50.0f, 80.0f}) {
        const Vec3 m = directionFromAngles(angle, 10.0f);
        const double c = std::cos(angle * test::kDegree), t = std::tan(angle * test::kDegree);
        const double expected = std::exp(-t * t / 0.16) / (M_PI * 0.16 * c * c * c * c);
        EXPECT_NEAR(d.D(m), expected, 1e-5 * expected + 1e-7) << angle;
    }
    EXPECT_EQ(d.D(Vec3(0.0f, 0.6f, -0.8f)), 0.0f);
    EXPECT_EQ(d.D(Vec3(1.0f, 0.0f, 0.0f)), 0.0f);
}

TEST(Beckmann, SampledNormalsAreVisibleAndUnit) {
    jobs::Rng rng(5, jobs::streamKey("beckmann-visible"), 0);
    for (float alpha : kAlphas) {
        const BeckmannDistribution d(alpha);
        for (float angle : {0.0f, 45.0f, 89.0f}) {
            const Vec3 wo = directionFromAngles(angle, 123.0f);
            for (int i = 0; i < 2000; ++i) {
                const Vec3 m = d.sampleVisibleNormal(wo, rng.uniform2());
                ASSERT_NEAR(glm::length(m), 1.0f, 1e-5f);
                EXPECT_GT(m.z, 0.0f);
                EXPECT_GE(glm::dot(wo, m), -1e-6f) << "alpha " << alpha << " at " << angle;
            }
        }
        // The corners of the unit square stay finite.
        for (Vec2 u : {Vec2(0.0f), Vec2(0.0f, 0.9999999f), Vec2(0.9999999f, 0.0f), Vec2(0.9999999f)}) {
            const Vec3 m = d.sampleVisibleNormal(directionFromAngles(60.0f, 0.0f), u);
            EXPECT_TRUE(std::isfinite(m.x) && std::isfinite(m.y) && std::isfinite(m.z));
        }
    }
}

struct VisibleNormalCase {
    std::string name;
    float alpha;
    float angle;
};

void PrintTo(const VisibleNormalCase& c, std::ostream* os) { *os << c.name; }

std::vector<VisibleNormalCase> visibleNormalCases() {
    std::vector<VisibleNormalCase> cases;
    for (float alpha : kAlphas) {
        for (float angle : {5.0f, 60.0f, 85.0f}) {
            cases.push_back({"alpha" + std::to_string(static_cast<int>(alpha * 100.0f + 0.5f)) + "_" +
                                 std::to_string(static_cast<int>(angle)) + "deg",
                             alpha, angle});
        }
    }
    return cases;
}

class BeckmannVisibleNormalChi2 : public ::testing::TestWithParam<VisibleNormalCase> {};

TEST_P(BeckmannVisibleNormalChi2, SampleMatchesPdf) {
    const VisibleNormalCase& c = GetParam();
    const BeckmannDistribution d(c.alpha);
    const Vec3 wo = directionFromAngles(c.angle, 25.0f);
    test::Chi2Config config;
    // Narrow lobes need finer cells for the expected counts to resolve them.
    config.thetaBins = c.alpha < 0.1f ? 60 : 20;
    config.phiBins = 2 * config.thetaBins;
    config.samples = 200'000;
    config.testCount = static_cast<int>(visibleNormalCases().size());
    config.seed = std::hash<std::string>{}(c.name);
    const test::Chi2Result result = test::chi2SphereTest(
        [&](const Vec2& u) -> std::optional<Vec3> { return d.sampleVisibleNormal(wo, u); },
        [&](const Vec3& m) { return static_cast<double>(d.visibleNormalPdf(wo, m)); }, config);
    EXPECT_TRUE(result.passed) << c.name << ": " << result.message;
}

INSTANTIATE_TEST_SUITE_P(Microfacet, BeckmannVisibleNormalChi2, ::testing::ValuesIn(visibleNormalCases()),
                         [](const ::testing::TestParamInfo<VisibleNormalCase>& param) { return param.param.name; });

// The test must be able to fail: normals drawn for one roughness do not
// follow the visible-normal density of a slightly different one.
TEST(BeckmannVisibleNormalChi2Sanity, DetectsMismatchedRoughness) {
    const BeckmannDistribution sampled(0.3f), claimed(0.33f);
    const Vec3 wo = directionFromAngles(45.0f, 0.0f);
    test::Chi2Config config;
    config.samples = 200'000;
    const test::Chi2Result result = test::chi2SphereTest(
        [&](const Vec2& u) -> std::optional<Vec3> { return sampled.sampleVisibleNormal(wo, u); },
        [&](const Vec3& m) { return static_cast<double>(claimed.visibleNormalPdf(wo, m)); }, config);
    EXPECT_FALSE(result.passed) << result.message;
}

}  // namespace
}  // namespace fg
