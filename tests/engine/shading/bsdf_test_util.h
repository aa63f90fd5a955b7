// Helpers shared by the BSDF tests: directions from angles, Monte Carlo albedo
// from sample() weights and deterministic quadrature of eval() over the sphere.
#pragma once

#include "engine/shading/bsdf.h"
#include "jobs/random.h"

#include <cmath>
#include <cstdint>

namespace fg::test {

inline constexpr float kDegree = kPi / 180.0f;

// Unit direction at polar angle thetaDeg from +z and azimuth phiDeg.
inline Vec3 directionFromAngles(float thetaDeg, float phiDeg) {
    const float theta = thetaDeg * kDegree, phi = phiDeg * kDegree;
    return {std::sin(theta) * std::cos(phi), std::sin(theta) * std::sin(phi), std::cos(theta)};
}

struct AlbedoEstimate {
    Rgb mean{0.0f};
    Rgb standardError{0.0f};
};

// Directional albedo E[weight] over n calls to sample(), counting failed samples as 0.
inline AlbedoEstimate albedoBySampling(const Bsdf& bsdf, const Vec3& wo, TransportMode mode, int n,
                                       std::uint64_t seed, const Vec2& uv = Vec2(0.5f)) {
    jobs::Rng rng(seed, jobs::streamKey("albedo"), 0);
    glm::dvec3 sum(0.0), sumSq(0.0);
    for (int i = 0; i < n; ++i) {
        const float uLobe = rng.uniform();
        const Vec2 u = rng.uniform2();
        const std::optional<BsdfSample> s = bsdf.sample(wo, uv, uLobe, u, mode);
        if (!s) continue;
        const glm::dvec3 w(s->weight);
        sum += w;
        sumSq += w * w;
    }
    const glm::dvec3 mean = sum / static_cast<double>(n);
    const glm::dvec3 var = glm::max(sumSq / static_cast<double>(n) - mean * mean, glm::dvec3(0.0));
    return {Rgb(mean), Rgb(glm::sqrt(var / static_cast<double>(n)))};
}

// Integral of eval(wo, wi) over the whole sphere of wi, by the midpoint rule in
// (cos(theta), phi), which is an equal-area parametrisation.
inline Rgb albedoByQuadrature(const Bsdf& bsdf, const Vec3& wo, TransportMode mode, int cosSteps = 1024,
                              int phiSteps = 512, const Vec2& uv = Vec2(0.5f)) {
    glm::dvec3 sum(0.0);
    for (int i = 0; i < cosSteps; ++i) {
        const double z = -1.0 + 2.0 * (i + 0.5) / cosSteps;
        const double r = std::sqrt(std::max(0.0, 1.0 - z * z));
        for (int j = 0; j < phiSteps; ++j) {
            const double phi = 2.0 * M_PI * (j + 0.5) / phiSteps;
            const Vec3 wi(static_cast<float>(r * std::cos(phi)), static_cast<float>(r * std::sin(phi)),
                          static_cast<float>(z));
            sum += glm::dvec3(bsdf.eval(wo, wi, uv, mode));
        }
    }
    const double cellArea = (2.0 / cosSteps) * (2.0 * M_PI / phiSteps);
    return Rgb(sum * cellArea);
}

}  // namespace fg::test
