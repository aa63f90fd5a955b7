// Directional GMM of Vorba et al. 2014 §4.1: the equal-area square-to-hemisphere
// map, the density's normalisation (one minus the mass outside the square) and
// chi² tests of sampling against the density.
#include "engine/guiding/directional_gmm.h"

#include "jobs/random.h"
#include "tests/support/chi2.h"
#include "tests/support/gmm_fixtures.h"

#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <vector>

namespace fg {
namespace {

using test::gmmComponent;
using test::gmmMixture;

DirectionalGmm randomMixture(std::uint64_t key) {
    jobs::Rng rng(7, jobs::streamKey("gmm-random"), key);
    std::vector<GmmComponent> parts;
    float total = 0.0f;
    for (int j = 0; j < kGmmComponents; ++j) {
        const float w = 0.1f + rng.uniform();
        total += w;
        const float sx = 0.03f + 0.2f * rng.uniform(), sy = 0.03f + 0.2f * rng.uniform();
        const float rho = 1.6f * rng.uniform() - 0.8f;
        parts.push_back(gmmComponent(w, Vec2(rng.uniform(), rng.uniform()), sx * sx, rho * sx * sy, sy * sy));
    }
    for (GmmComponent& c : parts) c.weight /= total;
    return gmmMixture(parts);
}

// Mass of an axis-aligned Gaussian inside [0,1]².
double massInsideSquare(const GmmComponent& c) {
    const auto axis = [](double mean, double variance) {
        const double sigma = std::sqrt(variance);
        return 0.5 * (std::erf((1.0 - mean) / (sigma * std::sqrt(2.0))) - std::erf(-mean / (sigma * std::sqrt(2.0))));
    };
    return axis(c.mean.x, c.covXX) * axis(c.mean.y, c.covYY);
}

TEST(GuidingMap, JacobianIsConstant2Pi) {
    jobs::Rng rng(3, jobs::streamKey("map-jacobian"), 0);
    const double h = 1e-3;
    int tested = 0;
    for (int k = 0; k < 2000; ++k) {
        const Vec2 s(0.01f + 0.98f * rng.uniform(), 0.01f + 0.98f * rng.uniform());
        const float a = 2.0f * s.x - 1.0f, b = 2.0f * s.y - 1.0f;
        // The concentric map's wedges meet on the diagonals, where it is not differentiable.
        if (std::abs(std::abs(a) - std::abs(b)) < 0.02f) continue;
        const auto at = [](double x, double y) { return squareToHemisphere(Vec2(float(x), float(y))); };
        const Vec3 dx = (at(s.x + h, s.y) - at(s.x - h, s.y)) / float(2 * h);
        const Vec3 dy = (at(s.x, s.y + h) - at(s.x, s.y - h)) / float(2 * h);
        const double jacobian = glm::length(glm::cross(dx, dy));
        EXPECT_NEAR(jacobian, 2.0 * M_PI, 0.02 * 2.0 * M_PI) << s.x << ", " << s.y;
        ++tested;
    }
    EXPECT_GT(tested, 1500);
}

TEST(GuidingMap, InverseRoundTrips) {
    jobs::Rng rng(3, jobs::streamKey("map-inverse"), 0);
    for (int k = 0; k < 10000; ++k) {
        const Vec2 s = rng.uniform2();
        const Vec3 w = squareToHemisphere(s);
        EXPECT_NEAR(glm::length(w), 1.0f, 1e-5f);
        EXPECT_GE(w.z, 0.0f);
        const std::optional<Vec2> back = hemisphereToSquare(w);
        ASSERT_TRUE(back.has_value());
        EXPECT_NEAR(back->x, s.x, 2e-4f);
        EXPECT_NEAR(back->y, s.y, 2e-4f);
    }
    EXPECT_FALSE(hemisphereToSquare(Vec3(0.0f, 0.6f, -0.8f)).has_value());
}

// The inverse map's polynomial atan against the concentric map's inverse in
// double precision with atan2, over all four wedges and their diagonals: the
// round trip above tolerates the forward map's own rounding, this does not.
TEST(GuidingMap, InverseMatchesDoublePrecisionAtan2) {
    const auto reference = [](const Vec3& w) {
        const double r = std::sqrt(std::max(0.0, 1.0 - double(w.z)));
        const double pi = 3.14159265358979323846;
        double phi = std::atan2(double(w.y), double(w.x));
        if (phi < -0.25 * pi) phi += 2.0 * pi;
        double a, b;
        if (phi < 0.25 * pi) {
            a = r, b = phi * a / (0.25 * pi);
        } else if (phi < 0.75 * pi) {
            b = r, a = -(phi - 0.5 * pi) * b / (0.25 * pi);
        } else if (phi < 1.25 * pi) {
            a = -r, b = (phi - pi) * a / (0.25 * pi);
        } else {
            b = -r, a = -(phi - 1.5 * pi) * b / (0.25 * pi);
        }
        return Vec2(float(0.5 * (a + 1.0)), float(0.5 * (b + 1.0)));
    };
    jobs::Rng rng(5, jobs::streamKey("map-inverse-atan"), 0);
    double worst = 0.0;
    for (int k = 0; k < 20000; ++k) {
        Vec3 w = sampleUniformSphere(rng.uniform2());
        w.z = std::abs(w.z);
        if (k % 4 == 0) w.y = (k % 8 == 0 ? 1.0f : -1.0f) * std::abs(w.x);  // on a wedge boundary
        w = glm::normalize(w);
        const std::optional<Vec2> s = hemisphereToSquare(w);
        ASSERT_TRUE(s.has_value());
        const Vec2 expected = reference(w);
        worst = std::max({worst, std::abs(double(s->x) - expected.x), std::abs(double(s->y) - expected.y)});
    }
    EXPECT_LT(worst, 1e-6);
}

// The forward map's polynomial sine and cosine against the concentric map in
// double precision with the library's cos and sin.
TEST(GuidingMap, ForwardMatchesDoublePrecisionTrigonometry) {
    const auto reference = [](const Vec2& s) {
        const double pi = 3.14159265358979323846;
        const double a = 2.0 * s.x - 1.0, b = 2.0 * s.y - 1.0;
        if (a == 0.0 && b == 0.0) return std::array<double, 3>{0.0, 0.0, 1.0};
        double r, phi;
        if (std::abs(a) > std::abs(b)) {
            r = a, phi = 0.25 * pi * (b / a);
        } else {
            r = b, phi = 0.5 * pi - 0.25 * pi * (a / b);
        }
        const double lift = std::sqrt(2.0 - r * r);
        return std::array<double, 3>{r * std::cos(phi) * lift, r * std::sin(phi) * lift, 1.0 - r * r};
    };
    jobs::Rng rng(5, jobs::streamKey("map-forward-trig"), 0);
    double worst = 0.0;
    for (int k = 0; k < 20000; ++k) {
        Vec2 s = rng.uniform2();
        if (k % 4 == 0) s.y = (k % 8 == 0) ? s.x : 1.0f - s.x;  // on a wedge boundary
        const Vec3 w = squareToHemisphere(s);
        const std::array<double, 3> expected = reference(s);
        for (int a = 0; a < 3; ++a) worst = std::max(worst, std::abs(double(w[a]) - expected[std::size_t(a)]));
    }
    EXPECT_LT(worst, 1e-6);
}

// The density of Eq. 1 from the covariances in double precision with the
// library's exp: the lanes, the polynomial 2^x and the cutoff that makes far
// components exactly zero change the density by float rounding only.
TEST(DirectionalGmm, PdfMatchesDoublePrecisionDensity) {
    for (std::uint64_t key = 1; key <= 4; ++key) {
        const DirectionalGmm gmm = randomMixture(key);
        const auto reference = [&](const Vec2& s) {
            double sum = 0.0;
            for (const GmmComponent& c : gmm.components) {
                if (c.weight <= 0.0f) continue;
                const double det = double(c.covXX) * c.covYY - double(c.covXY) * c.covXY;
                const double dx = double(s.x) - c.mean.x, dy = double(s.y) - c.mean.y;
                const double q = (c.covYY * dx * dx - 2.0 * c.covXY * dx * dy + c.covXX * dy * dy) / det;
                sum += c.weight * std::exp(-0.5 * q) / (2.0 * M_PI * std::sqrt(det));
            }
            return sum;
        };
        jobs::Rng rng(9, jobs::streamKey("gmm-pdf-double"), key);
        int compared = 0, farOut = 0;
        for (int k = 0; k < 20000; ++k) {
            // Points well outside the square too, where every term is tiny or zero.
            const Vec2 s(6.0f * rng.uniform() - 2.5f, 6.0f * rng.uniform() - 2.5f);
            const double expected = reference(s);
            const double actual = gmm.pdfSquare(s);
            if (expected < 1e-30) {
                EXPECT_LT(actual, 1e-30) << s.x << ", " << s.y;
                ++farOut;
                continue;
            }
            // The float quadratic form's rounding, a few 1e-7 of the exponent,
            // dominates away from the means, with the library's expf as here.
            const double relative = 1e-6 * (2.0 + std::abs(std::log(expected)));
            EXPECT_NEAR(actual, expected, relative * expected) << s.x << ", " << s.y;
            ++compared;
        }
        EXPECT_GT(compared, 5000);
        EXPECT_GT(farOut, 100);  // the cutoff is exercised
    }
}

// Sampling draws the component whose running weight first exceeds u and maps
// uGauss by Box-Muller through the Cholesky factor: the same point as that
// recipe in double precision with the library's log, cos and sin.
TEST(DirectionalGmm, SamplePlaneMatchesDoublePrecisionBoxMuller) {
    const DirectionalGmm gmm = gmmMixture({gmmComponent(0.3f, Vec2(0.2f, 0.3f), 0.01f, 0.004f, 0.02f),
                                           gmmComponent(0.0f, Vec2(0.5f, 0.5f), 0.01f, 0.0f, 0.01f),
                                           gmmComponent(0.45f, Vec2(0.7f, 0.6f), 0.03f, -0.02f, 0.05f),
                                           gmmComponent(0.25f, Vec2(0.5f, 0.9f), 0.002f, 0.0f, 0.0004f)});
    jobs::Rng rng(13, jobs::streamKey("gmm-sample-double"), 0);
    std::array<int, kGmmComponents> drawn{};
    for (int k = 0; k < 50000; ++k) {
        const float uComponent = rng.uniform();
        Vec2 uGauss = rng.uniform2();
        if (k % 16 == 0) uGauss.x = 1.0f - 0x1p-24f * float(1 + k % 7);  // the far tail
        double cumulative = 0.0;
        std::size_t chosen = 0;
        bool nearBoundary = false;
        for (std::size_t j = 0; j < kGmmComponents; ++j) {
            if (gmm.components[j].weight <= 0.0f) continue;
            chosen = j;
            cumulative += gmm.components[j].weight;
            nearBoundary = nearBoundary || std::abs(uComponent - cumulative) < 1e-6;
            if (uComponent < cumulative) break;
        }
        if (nearBoundary) continue;
        const GmmComponent& c = gmm.components[chosen];
        const double radius = std::sqrt(-2.0 * std::log(double(1.0f - uGauss.x)));
        const double angle = 2.0 * M_PI * uGauss.y;
        const double z0 = radius * std::cos(angle), z1 = radius * std::sin(angle);
        const double l00 = std::sqrt(double(c.covXX)), l10 = c.covXY / l00;
        const double l11 = std::sqrt(c.covYY - l10 * l10);
        const Vec2 s = gmm.samplePlane(uComponent, uGauss);
        const double tolerance = 1e-6 * (1.0 + radius);
        EXPECT_NEAR(s.x, c.mean.x + l00 * z0, tolerance) << uComponent << " " << uGauss.x << " " << uGauss.y;
        EXPECT_NEAR(s.y, c.mean.y + l10 * z0 + l11 * z1, tolerance) << uComponent << " " << uGauss.x << " " << uGauss.y;
        ++drawn[chosen];
    }
    EXPECT_EQ(drawn[1], 0);  // an empty component is never drawn
    EXPECT_GT(drawn[0], 10000);
    EXPECT_GT(drawn[3], 8000);
}

// ∫ pdf_ω over the hemisphere by midpoint quadrature in (cos θ, φ), against the
// closed-form mass of the axis-aligned Gaussians inside the square: the map,
// its Jacobian and the density's normalisation agree.
TEST(DirectionalGmm, PdfIntegratesToMassInsideSquare) {
    const DirectionalGmm gmm = gmmMixture({gmmComponent(0.3f, Vec2(0.05f, 0.5f), 0.01f, 0.0f, 0.02f),
                                        gmmComponent(0.2f, Vec2(0.9f, 0.95f), 0.03f, 0.0f, 0.005f),
                                        gmmComponent(0.5f, Vec2(0.5f, 0.4f), 0.02f, 0.0f, 0.01f)});
    double expected = 0.0;
    for (const GmmComponent& c : gmm.components)
        if (c.weight > 0.0f) expected += c.weight * massInsideSquare(c);
    ASSERT_LT(expected, 0.9);  // a real part of the mass lies outside
    const int nz = 1500, nphi = 3000;
    double integral = 0.0;
    for (int i = 0; i < nz; ++i) {
        const double z = (i + 0.5) / nz;
        const double r = std::sqrt(1.0 - z * z);
        for (int k = 0; k < nphi; ++k) {
            const double phi = 2.0 * M_PI * (k + 0.5) / nphi;
            integral += gmm.pdfLocal(Vec3(float(r * std::cos(phi)), float(r * std::sin(phi)), float(z)));
        }
    }
    integral *= (1.0 / nz) * (2.0 * M_PI / nphi);
    EXPECT_NEAR(integral, expected, 2e-3);
    EXPECT_EQ(gmm.pdfLocal(Vec3(0.0f, 0.0f, -1.0f)), 0.0f);
}

void expectSamplingMatchesPdf(const DirectionalGmm& gmm, const char* what) {
    test::Chi2Config config;
    config.samples = 400'000;
    config.testCount = 3;
    jobs::Rng componentRng(config.seed, jobs::streamKey("gmm-chi2-component"), 0);
    const test::Chi2Result result = test::chi2SphereTest(
        [&](const Vec2& u) { return gmm.sampleLocal(componentRng.uniform(), u); },
        [&](const Vec3& w) { return double(gmm.pdfLocal(w)); }, config);
    EXPECT_TRUE(result.passed) << what << ": " << result.message;
}

TEST(DirectionalGmm, Chi2RandomMixture) { expectSamplingMatchesPdf(randomMixture(1), "random"); }

TEST(DirectionalGmm, Chi2AnisotropicMixture) {
    expectSamplingMatchesPdf(gmmMixture({gmmComponent(0.6f, Vec2(0.3f, 0.6f), 0.04f, 0.0f, 0.0009f),
                                      gmmComponent(0.4f, Vec2(0.7f, 0.3f), 0.0016f, 0.0f, 0.05f)}),
                             "anisotropic");
}

TEST(DirectionalGmm, Chi2NearSingularMixture) {
    // Correlation 0.999: the Gaussian is almost a line segment across the square.
    expectSamplingMatchesPdf(gmmMixture({gmmComponent(0.7f, Vec2(0.5f, 0.5f), 0.02f, 0.01998f, 0.02f),
                                      gmmComponent(0.3f, Vec2(0.2f, 0.8f), 0.0004f, 0.0f, 0.0004f)}),
                             "near-singular");
}

TEST(DirectionalGmm, FinalizeRejectsIndefiniteCovariance) {
    DirectionalGmm gmm;
    gmm.components[0] = gmmComponent(1.0f, Vec2(0.5f), 0.01f, 0.02f, 0.01f);
    EXPECT_FALSE(gmm.finalize());
    EXPECT_FALSE(gmm.usable());
}

}  // namespace
}  // namespace fg
