// Directional Gaussian mixtures for path guiding (Vorba et al. 2014, §4.1,
// Eq. 1): K bivariate Gaussians on the unit square [0,1]², which the equal-area
// map of Shirley and Chiu (1997) takes to the hemisphere around a normal. The
// map's Jacobian is the constant 2π (square area 1, hemisphere area 2π), so
// the solid-angle density is pdf_ω = pdf_s / 2π. The Gaussians are not
// truncated: the mass outside the square belongs to no direction, sampling
// there fails (the path ends, §4.1) and the density over the hemisphere
// integrates to one minus that mass.
#pragma once

#include "engine/core/math.h"

#include <array>
#include <cstdint>
#include <optional>

namespace fg {

// Square [0,1]² -> local hemisphere (z >= 0): concentric disk, then the
// equal-area lift (x, y) * sqrt(2 - r²), z = 1 - r².
Vec3 squareToHemisphere(const Vec2& s);
// The inverse on z >= 0; a direction below the horizon has no preimage.
std::optional<Vec2> hemisphereToSquare(const Vec3& local);

inline constexpr int kGmmComponents = 8;
inline constexpr float kSquareToHemisphereJacobian = 2.0f * kPi;

// One bivariate Gaussian: mixing weight, mean, covariance [[xx, xy], [xy, yy]],
// and what evaluation and sampling derive from them (set by finalize()).
struct GmmComponent {
    float weight = 0.0f;
    Vec2 mean{0.5f};
    float covXX = 0.05f, covXY = 0.0f, covYY = 0.05f;
    // Derived: inverse covariance, 1 / (2π sqrt(det Σ)), lower Cholesky factor.
    float invXX = 0.0f, invXY = 0.0f, invYY = 0.0f;
    float normalisation = 0.0f;
    float cholXX = 0.0f, cholYX = 0.0f, cholYY = 0.0f;
};

// The mixture as evaluation and sampling read it, one array per quantity and
// one lane per component (set by finalize()): the density computes all K
// terms together in vector code instead of walking the components one by one.
// The arrays sampling reads come first and the block starts a cache line, so
// that a guided vertex touches five lines of a record (the record is usually
// not in cache: the vertex has just looked it up).
struct alignas(64) GmmLanes {
    using Lanes = std::array<float, kGmmComponents>;
    // Running sum of the weights, +inf from the last non-empty component on:
    // the component drawn by u in [0, 1) is the number of entries <= u.
    Lanes cdf{};
    Lanes meanX{}, meanY{};
    // Lower Cholesky factor of Σ (as GmmComponent::chol*).
    Lanes cholXX{}, cholYX{}, cholYY{};
    // log2 of a component's Gaussian factor at offset (dx, dy) from its mean is
    // quadXX dx² + quadXY dx dy + quadYY dy² = -½ log2(e) (dx, dy) Σ⁻¹ (dx, dy)ᵀ.
    Lanes quadXX{}, quadXY{}, quadYY{};
    // weight / (2π sqrt(det Σ)); zero for an empty component, whose factor is then 1.
    Lanes scale{};
};

struct DirectionalGmm {
    std::array<GmmComponent, kGmmComponents> components{};
    GmmLanes lanes{};

    // Recomputes the derived quantities; returns false (and leaves the mixture
    // unusable: all weights zero) if a covariance is not positive definite or a
    // value is not finite.
    bool finalize();
    bool usable() const;
    // Asks the memory system for the lanes ahead of their use: a caller that
    // has just found the record can do other work while they arrive.
    void prefetch() const {
        const char* bytes = reinterpret_cast<const char*>(&lanes);
        for (std::size_t offset = 0; offset < sizeof(GmmLanes); offset += 64) __builtin_prefetch(bytes + offset);
    }

    // Density on the plane R² (not truncated to the square).
    float pdfSquare(const Vec2& s) const;
    // Solid-angle density of a local direction (z = the record's normal); zero below the horizon.
    float pdfLocal(const Vec3& local) const;
    // Draws a point of the plane: component by uComponent, Gaussian by Box-Muller from uGauss
    // (its logarithm, cosine and sine by polynomials accurate to float rounding).
    Vec2 samplePlane(float uComponent, const Vec2& uGauss) const;
    // A local direction, or nothing when the point falls outside the square.
    std::optional<Vec3> sampleLocal(float uComponent, const Vec2& uGauss) const;
};

}  // namespace fg
