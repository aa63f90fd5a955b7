// Isotropic GGX (Trowbridge-Reitz) microfacet distribution with Smith masking,
// shared by the rough conductor and rough dielectric. Directions are in the
// local shading frame (normal = +z).
#pragma once

#include "engine/core/math.h"

namespace fg {

class GgxDistribution {
public:
    // alpha is the GGX roughness (width of the slope distribution); values
    // below kMinAlpha are clamped because the density degenerates to a delta.
    explicit GgxDistribution(float alpha);

    static constexpr float kMinAlpha = 1e-4f;

    float alpha() const { return alpha_; }

    // Normal distribution D(m), normalised so that the integral of D(m) cos(theta_m)
    // over the upper hemisphere is 1. Zero for m below the macrosurface.
    float D(const Vec3& m) const;
    // Smith's auxiliary function Lambda(w) for the GGX slope distribution.
    float lambda(const Vec3& w) const;
    // Smith masking G1(w) = 1 / (1 + Lambda(w)); uses |cos(theta)|, so it also
    // serves directions below the surface (transmission).
    float G1(const Vec3& w) const;
    // Separable (uncorrelated) masking-shadowing G1(wo) G1(wi), as in Walter et al. 2007.
    float G(const Vec3& wo, const Vec3& wi) const { return G1(wo) * G1(wi); }

    // Density of visible normals D_wo(m) = G1(wo) max(0, wo.m) D(m) / cos(theta_o)
    // (Heitz 2018, Eq. 1) for wo above the surface.
    float visibleNormalPdf(const Vec3& wo, const Vec3& m) const;
    // Draws m from D_wo for wo above the surface (Heitz 2018, "Sampling the GGX
    // Distribution of Visible Normals", Listing 1).
    Vec3 sampleVisibleNormal(const Vec3& wo, const Vec2& u) const;

private:
    float alpha_;
};

}  // namespace fg
