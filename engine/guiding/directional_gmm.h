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

struct DirectionalGmm {
    std::array<GmmComponent, kGmmComponents> components{};

    // Recomputes the derived quantities; returns false (and leaves the mixture
    // unusable: all weights zero) if a covariance is not positive definite or a
    // value is not finite.
    bool finalize();
    bool usable() const;

    // Density on the plane R² (not truncated to the square).
    float pdfSquare(const Vec2& s) const;
    // Solid-angle density of a local direction (z = the record's normal); zero below the horizon.
    float pdfLocal(const Vec3& local) const;
    // Draws a point of the plane: component by uComponent, Gaussian by Box-Muller from uGauss.
    Vec2 samplePlane(float uComponent, const Vec2& uGauss) const;
    // A local direction, or nothing when the point falls outside the square.
    std::optional<Vec3> sampleLocal(float uComponent, const Vec2& uGauss) const;
};

}  // namespace fg
