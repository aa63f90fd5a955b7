// Isotropic microfacet distributions with Smith masking, shared by the rough
// conductor, rough dielectric and rough plastic: GGX (Trowbridge-Reitz) and
// Beckmann. Both classes have the same interface so that the BSDFs can be
// templates over the distribution (no virtual call or branch per evaluation).
// Directions are in the local shading frame (normal = +z).
#pragma once

#include "engine/core/math.h"

#include <cstdint>
#include <optional>
#include <string_view>

namespace fg {

enum class MicrofacetType : std::uint8_t { Ggx, Beckmann };

// "ggx" or "beckmann", the names used by both scene formats.
std::optional<MicrofacetType> microfacetTypeFromName(std::string_view name);
std::string_view microfacetTypeName(MicrofacetType type);

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

// Beckmann distribution (Beckmann & Spizzichino 1963; Walter et al. 2007,
// Eqs. 25-27): the slopes of the microsurface are Gaussian with variance
// alpha^2 / 2, so alpha is the RMS slope, as in Mitsuba.
class BeckmannDistribution {
public:
    explicit BeckmannDistribution(float alpha);

    static constexpr float kMinAlpha = 1e-4f;

    float alpha() const { return alpha_; }

    float D(const Vec3& m) const;
    // Exact Smith Lambda with the error function (Walter et al. 2007, Eq. 27 before
    // its rational approximation; Heitz 2014, "Understanding the Masking-Shadowing
    // Function", Eq. 80).
    float lambda(const Vec3& w) const;
    float G1(const Vec3& w) const;
    float G(const Vec3& wo, const Vec3& wi) const { return G1(wo) * G1(wi); }

    float visibleNormalPdf(const Vec3& wo, const Vec3& m) const;
    // Draws m from D_wo for wo above the surface by stretching to unit roughness,
    // sampling the visible slopes there and unstretching (Heitz & d'Eon 2014,
    // "Importance Sampling Microfacet-Based BSDFs using the Distribution of
    // Visible Normals", Sec. 4; the slope marginals as in Jakob 2014, "An Improved
    // Visible Normal Sampling Routine for the Beckmann Distribution").
    Vec3 sampleVisibleNormal(const Vec3& wo, const Vec2& u) const;

private:
    float alpha_;
};

}  // namespace fg
