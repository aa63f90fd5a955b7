// The spherical-harmonic radiance map of photon ray splatting (Herzog et al.
// 2007, §8.1; passes/prs/sh_radiance.h): the basis against the clamped-cosine
// coefficients Â_l (Ramamoorthi & Hanrahan 2001), rotation against
// re-projection, the Lambertian one-coefficient integral against direct
// Eq. 6, and rough conductors under a smooth field against Eq. 6 by
// quadrature.
#include "passes/prs/sh_radiance.h"

#include "engine/shading/texture.h"

#include <gtest/gtest.h>

#include <functional>
#include <random>

namespace fg {
namespace {

// Σ over a midpoint grid in (θ, φ) of g(ω) Y_k(ω) dω: the projection of g.
std::array<double, sh::kCoefficients> project(const std::function<double(const Vec3&)>& g, int nTheta = 256) {
    const int nPhi = 2 * nTheta;
    const double dTheta = kPi / nTheta, dPhi = 2.0 * kPi / nPhi;
    std::array<double, sh::kCoefficients> c{};
    float y[sh::kCoefficients];
    for (int i = 0; i < nTheta; ++i) {
        const double theta = (i + 0.5) * dTheta;
        for (int j = 0; j < nPhi; ++j) {
            const double phi = (j + 0.5) * dPhi;
            const Vec3 w(static_cast<float>(std::sin(theta) * std::cos(phi)), static_cast<float>(std::sin(theta) * std::sin(phi)),
                         static_cast<float>(std::cos(theta)));
            sh::evaluate(w, y);
            const double v = g(w) * std::sin(theta) * dTheta * dPhi;
            for (int k = 0; k < sh::kCoefficients; ++k) c[static_cast<std::size_t>(k)] += v * y[k];
        }
    }
    return c;
}

TEST(PrsSphericalHarmonics, ClampedCosineCoefficients) {
    // Â_l = sqrt(4π / (2l + 1)) c_l0 for max(cos θ, 0): π, 2π/3, π/4, 0.
    const auto c = project([](const Vec3& w) { return std::max(0.0, static_cast<double>(w.z)); });
    const double expected[4] = {kPi, 2.0 * kPi / 3.0, kPi / 4.0, 0.0};
    for (int l = 0; l < sh::kBands; ++l) {
        const double a = std::sqrt(4.0 * kPi / (2 * l + 1)) * c[static_cast<std::size_t>(sh::index(l, 0))];
        // Midpoint quadrature at 256 x 512 points: errors near 1e-5; the kink at the horizon adds some.
        EXPECT_NEAR(a, expected[l], 1e-3) << "l = " << l;
        for (int m = -l; m <= l; ++m) {
            if (m != 0) {
                EXPECT_NEAR(c[static_cast<std::size_t>(sh::index(l, m))], 0.0, 1e-4) << "l " << l << " m " << m;
            }
        }
    }
}

TEST(PrsSphericalHarmonics, BasisIsOrthonormal) {
    for (int k = 0; k < sh::kCoefficients; ++k) {
        const auto c = project(
            [k](const Vec3& w) {
                float y[sh::kCoefficients];
                sh::evaluate(w, y);
                return static_cast<double>(y[k]);
            },
            128);
        for (int j = 0; j < sh::kCoefficients; ++j)
            EXPECT_NEAR(c[static_cast<std::size_t>(j)], j == k ? 1.0 : 0.0, 1e-3) << k << ", " << j;
    }
}

TEST(PrsSphericalHarmonics, RotationMatchesReprojection) {
    std::mt19937 rng(7);
    std::uniform_real_distribution<float> u(-1.0f, 1.0f);
    for (int trial = 0; trial < 3; ++trial) {
        sh::Coefficients<float> world;
        for (float& v : world) v = u(rng);
        const Vec3 n = glm::normalize(Vec3(u(rng), u(rng), u(rng)));
        const Vec3 wo = glm::normalize(Vec3(u(rng), u(rng), u(rng)));
        const sh::VertexFrame f = sh::vertexFrame(n, wo);
        const sh::Coefficients<float> local = sh::Rotator::instance().rotate(world, f.x, f.y, f.z);
        // g(ω_local) = f_world(ω_local.x X + ω_local.y Y + ω_local.z Z), projected afresh.
        const auto expected = project(
            [&](const Vec3& w) {
                float y[sh::kCoefficients];
                sh::evaluate(w.x * f.x + w.y * f.y + w.z * f.z, y);
                double v = 0.0;
                for (int k = 0; k < sh::kCoefficients; ++k) v += world[static_cast<std::size_t>(k)] * y[k];
                return v;
            },
            128);
        for (int k = 0; k < sh::kCoefficients; ++k)
            EXPECT_NEAR(local[static_cast<std::size_t>(k)], expected[static_cast<std::size_t>(k)], 1e-3) << "trial " << trial << " k " << k;
        // A rotation keeps each band's energy.
        for (int l = 0; l < sh::kBands; ++l) {
            double a = 0.0, b = 0.0;
            for (int m = -l; m <= l; ++m) {
                a += static_cast<double>(world[static_cast<std::size_t>(sh::index(l, m))]) * world[static_cast<std::size_t>(sh::index(l, m))];
                b += static_cast<double>(local[static_cast<std::size_t>(sh::index(l, m))]) * local[static_cast<std::size_t>(sh::index(l, m))];
            }
            EXPECT_NEAR(b, a, 1e-4 * (1.0 + a)) << "band " << l;
        }
    }
}

TEST(PrsSphericalHarmonics, LambertianFromOneCoefficientIsExact) {
    // Deposits w_i from directions ω_i above n: Eq. 6 gives (ρ/π) Σ w_i; the
    // map's c_00 = Σ w_i Y_00 gives the same through ∫ E = 2√π c_00.
    std::mt19937 rng(3);
    std::uniform_real_distribution<float> u(-1.0f, 1.0f), w01(0.0f, 1.0f);
    const Vec3 n = glm::normalize(Vec3(0.3f, -0.5f, 0.8f));
    const Rgb albedo(0.7f, 0.4f, 0.2f);
    sh::Coefficients<Rgb> c;
    c.fill(Rgb(0.0f));
    Rgb direct(0.0f);
    float y[sh::kCoefficients];
    for (int i = 0; i < 1000; ++i) {
        Vec3 w = glm::normalize(Vec3(u(rng), u(rng), u(rng)));
        if (glm::dot(w, n) < 0.0f) w = -w;
        const Rgb deposit = Rgb(w01(rng), w01(rng), w01(rng)) * glm::dot(w, n);
        direct += albedo * kInvPi * deposit;
        sh::evaluate(w, y);
        for (int k = 0; k < sh::kCoefficients; ++k) c[static_cast<std::size_t>(k)] += deposit * y[k];
    }
    const Rgb viaMap = albedo * kInvPi * sh::integral(c);
    for (int ch = 0; ch < 3; ++ch) EXPECT_NEAR(viaMap[ch], direct[ch], 1e-5f * direct[ch]);
}

// A rough conductor under the smooth field L_i(ω) = 1 + 0.5 ω·a: SH-16
// (projection, rotation, table) against Eq. 6 by direct quadrature.
class PrsShRoughConductor : public ::testing::TestWithParam<float> {};

TEST_P(PrsShRoughConductor, WithinTenPercentOfDirectEq6) {
    const float alpha = GetParam();
    const std::shared_ptr<Bsdf> bsdf = makeRoughConductor(*conductorPreset("Au"), alpha);
    const sh::BrdfTable table(*bsdf, Vec2(0.0f));
    const Vec3 a = glm::normalize(Vec3(0.4f, 0.7f, 0.2f));
    const Vec3 n = glm::normalize(Vec3(0.2f, 0.9f, -0.3f));
    const auto field = [&](const Vec3& w) { return 1.0 + 0.5 * glm::dot(w, a); };
    // E = L_i max(cos, 0) in the world frame.
    const auto e = project([&](const Vec3& w) { return field(w) * std::max(0.0f, glm::dot(w, n)); });
    sh::Coefficients<Rgb> world;
    for (int k = 0; k < sh::kCoefficients; ++k) world[static_cast<std::size_t>(k)] = Rgb(static_cast<float>(e[static_cast<std::size_t>(k)]));
    for (float thetaODegrees : {0.0f, 30.0f, 60.0f}) {
        // w_o in the plane of n and a tangent.
        const Vec3 t = glm::normalize(glm::cross(n, Vec3(1, 0, 0)));
        const float th = glm::radians(thetaODegrees);
        const Vec3 wo = std::cos(th) * n + std::sin(th) * t;
        const sh::VertexFrame f = sh::vertexFrame(n, wo);
        const Rgb viaSh = table.integrate(sh::Rotator::instance().rotate(world, f.x, f.y, f.z), f.cosThetaO);
        // Eq. 6 directly: ∫ eval(w_o, ω) L_i(ω) dω over the local hemisphere (eval carries the cosine).
        const Vec3 woLocal(glm::dot(wo, f.x), glm::dot(wo, f.y), glm::dot(wo, f.z));
        const int nTheta = 256, nPhi = 512;
        const double dTheta = 0.5 * kPi / nTheta, dPhi = 2.0 * kPi / nPhi;
        std::array<double, 3> direct{};
        for (int i = 0; i < nTheta; ++i) {
            const double theta = (i + 0.5) * dTheta;
            for (int j = 0; j < nPhi; ++j) {
                const double phi = (j + 0.5) * dPhi;
                const Vec3 wl(static_cast<float>(std::sin(theta) * std::cos(phi)), static_cast<float>(std::sin(theta) * std::sin(phi)),
                              static_cast<float>(std::cos(theta)));
                const Rgb fe = bsdf->eval(woLocal, wl, Vec2(0.0f), TransportMode::Radiance);
                const double li = field(wl.x * f.x + wl.y * f.y + wl.z * f.z);
                for (int c = 0; c < 3; ++c) direct[static_cast<std::size_t>(c)] += fe[c] * li * std::sin(theta) * dTheta * dPhi;
            }
        }
        for (int c = 0; c < 3; ++c) {
            std::printf("alpha %.1f theta_o %2.0f channel %d: SH %.4f direct %.4f (%.1f %%)\n", alpha, thetaODegrees, c, viaSh[c],
                        direct[static_cast<std::size_t>(c)], 100.0 * (viaSh[c] / direct[static_cast<std::size_t>(c)] - 1.0));
            EXPECT_NEAR(viaSh[c], direct[static_cast<std::size_t>(c)], 0.1 * direct[static_cast<std::size_t>(c)])
                << "alpha " << alpha << " theta_o " << thetaODegrees;
        }
    }
}

INSTANTIATE_TEST_SUITE_P(Roughness, PrsShRoughConductor, ::testing::Values(0.3f, 0.5f));

}  // namespace
}  // namespace fg
