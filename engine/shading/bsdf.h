// Surface scattering models. Every direction is given in the local shading
// frame (normal = +z) and points away from the surface: wo towards the previous
// vertex, wi towards the next. Conventions (as Mitsuba 3):
//  - eval() returns f(wo, wi) * |cos(theta_i)|, zero for specular lobes;
//  - sample() returns wi, its solid-angle pdf and weight = eval / pdf, or for a
//    specular event the lobe's throughput weight with pdf set to the discrete
//    probability of choosing that lobe (BsdfLobe::Specular set in `lobe`);
//  - TransportMode::Importance is used by light-tracing passes (photons): the
//    radiance-only eta^2 scaling at refraction is then not applied.
// Materials that are not explicitly two-sided are black on their back side,
// except the dielectrics, which are defined on both sides.
#pragma once

#include "engine/core/math.h"
#include "engine/shading/microfacet.h"
#include "engine/shading/texture.h"

#include <cstdint>
#include <memory>
#include <optional>
#include <string_view>
#include <vector>

namespace fg {

enum class TransportMode : std::uint8_t { Radiance, Importance };

namespace BsdfLobe {
inline constexpr std::uint32_t Reflection = 1u << 0;
inline constexpr std::uint32_t Transmission = 1u << 1;
inline constexpr std::uint32_t Diffuse = 1u << 2;
inline constexpr std::uint32_t Glossy = 1u << 3;
inline constexpr std::uint32_t Specular = 1u << 4;
inline constexpr std::uint32_t Null = 1u << 5;  // index-matched pass-through
}  // namespace BsdfLobe

struct BsdfSample {
    Vec3 wi{0.0f};
    Rgb weight{0.0f};   // f * |cos| / pdf
    float pdf = 0.0f;   // solid-angle pdf, or the lobe probability for specular events
    float eta = 1.0f;   // relative IOR crossed (1 for reflection)
    std::uint32_t lobe = 0;
    bool isSpecular() const { return (lobe & BsdfLobe::Specular) != 0; }
};

// Where a material is hit, for the adapters that perturb the shading normal
// (bump and normal maps): the interpolated shading frame with `s` along the
// surface's dp/du (Gram-Schmidt against n), the unnormalised derivatives dp/du
// and dp/dv, the unit geometric normal, all in world space.
struct ShadingGeometry {
    Frame frame;
    Vec3 dpdu{0.0f};
    Vec3 dpdv{0.0f};
    Vec3 ng{0.0f, 0.0f, 1.0f};
    Vec2 uv{0.0f};
};

class Bsdf {
public:
    virtual ~Bsdf() = default;
    // Union of the lobes this material can produce.
    virtual std::uint32_t lobes() const = 0;
    virtual Rgb eval(const Vec3& wo, const Vec3& wi, const TexturePoint& at, TransportMode mode) const = 0;
    virtual float pdf(const Vec3& wo, const Vec3& wi, const TexturePoint& at) const = 0;
    // uLobe picks among lobes, u drives the direction within a lobe.
    virtual std::optional<BsdfSample> sample(const Vec3& wo, const TexturePoint& at, float uLobe, const Vec2& u,
                                             TransportMode mode) const = 0;

    // f_r itself when it is one constant for every pair of directions on the
    // reflecting side (wo.z > 0, wi.z > 0: a Lambertian BRDF), so that callers
    // evaluating one shading point many times can cache it; nullopt otherwise.
    virtual std::optional<Rgb> constantReflectance(const TexturePoint& at) const {
        (void)at;
        return std::nullopt;
    }

    // Light that goes straight through, as if there were no surface, for w (the
    // direction either way, local frame): Mitsuba's null events. A path that
    // samples such an event (BsdfLobe::Null in the sample) continues without a
    // scattering vertex -- it counts no depth and keeps the previous vertex for
    // MIS -- and shadow rays pass with this factor. Zero for opaque materials.
    virtual Rgb nullTransmission(const Vec3& w, const TexturePoint& at) const {
        (void)w;
        (void)at;
        return Rgb(0.0f);
    }
    // Mitsuba's mask: a ray passes through the surface with probability
    // 1 - opacity(at), as through a null boundary (not counted as a bounce), and
    // scatters by this material otherwise; shadow rays are attenuated by 1 - opacity.
    virtual bool hasOpacity() const { return false; }
    virtual float opacity(const TexturePoint& at) const {
        (void)at;
        return 1.0f;
    }
    // Bump and normal maps: the unit world-space shading normal to use instead
    // of the interpolated one (geometry.frame.n). Directions given to eval,
    // pdf and sample are then local to a frame around that normal.
    virtual bool perturbsNormal() const { return false; }
    virtual Vec3 perturbedNormal(const ShadingGeometry& geometry) const { return geometry.frame.n; }

    bool isNull() const { return lobes() == BsdfLobe::Null; }
    // Some of the light may pass as a null event (thindielectric, null).
    bool hasNullLobe() const { return (lobes() & BsdfLobe::Null) != 0; }
    bool hasSmoothLobe() const { return (lobes() & (BsdfLobe::Diffuse | BsdfLobe::Glossy)) != 0; }
    bool isPurelySpecular() const { return !hasSmoothLobe() && !isNull(); }
};

// Fresnel reflectance of a dielectric interface for cos(theta_i) on the side of
// relative IOR eta (= eta_transmitted / eta_incident); sets cosThetaT (signed as pbrt: negative).
float fresnelDielectric(float cosThetaI, float eta, float* cosThetaT = nullptr);
// Unpolarised Fresnel reflectance of a conductor with complex IOR eta + i k, per channel.
Rgb fresnelConductor(float cosThetaI, const Rgb& eta, const Rgb& k);

struct ConductorIor {
    Rgb eta;
    Rgb k;
};
// Mitsuba's named conductor materials ("Au", "Cu", "Ag", ... as in its ior
// tables, integrated to RGB as Mitsuba's RGB mode does), and "none", a perfect
// mirror (eta = 0, k = 1).
std::optional<ConductorIor> conductorPreset(std::string_view name);
// Every name conductorPreset knows, in table order, "none" last.
std::vector<std::string_view> conductorPresetNames();
// Named dielectric IORs ("vacuum", "air", "water", "bk7", "glass", "diamond", ...).
std::optional<float> dielectricIorPreset(std::string_view name);

std::shared_ptr<Bsdf> makeDiffuse(std::shared_ptr<Texture> reflectance);
// eta = interior IOR / exterior IOR. The interior is the side the normal points away from.
std::shared_ptr<Bsdf> makeDielectric(float eta, const Rgb& specularReflectance = Rgb(1.0f),
                                     const Rgb& specularTransmittance = Rgb(1.0f));
std::shared_ptr<Bsdf> makeDielectric(float eta, std::shared_ptr<Texture> specularReflectance,
                                     std::shared_ptr<Texture> specularTransmittance);
// Thin slab of IOR eta, Mitsuba's `thindielectric`: its straight-through
// transmission is a null event (BsdfLobe::Null, nullTransmission = 1 - R of the
// slab), as Mitsuba 3 flags it.
std::shared_ptr<Bsdf> makeThinDielectric(float eta);
std::shared_ptr<Bsdf> makeConductor(const ConductorIor& ior, const Rgb& specularReflectance = Rgb(1.0f));
std::shared_ptr<Bsdf> makeConductor(const ConductorIor& ior, std::shared_ptr<Texture> specularReflectance);
// Microfacet conductor, alpha = roughness of the GGX or Beckmann distribution
// (Mitsuba's `alpha`), sampled with the distribution of visible normals.
std::shared_ptr<Bsdf> makeRoughConductor(const ConductorIor& ior, float alpha, const Rgb& specularReflectance = Rgb(1.0f),
                                         MicrofacetType type = MicrofacetType::Ggx);
std::shared_ptr<Bsdf> makeRoughConductor(const ConductorIor& ior, float alpha, std::shared_ptr<Texture> specularReflectance,
                                         MicrofacetType type = MicrofacetType::Ggx);
std::shared_ptr<Bsdf> makeRoughDielectric(float eta, float alpha, MicrofacetType type = MicrofacetType::Ggx);
// Smooth dielectric coating (IOR eta) over a diffuse base, Mitsuba's `plastic`.
std::shared_ptr<Bsdf> makePlastic(std::shared_ptr<Texture> diffuseReflectance, float eta, bool nonlinear = false);
// Rough dielectric coating (IOR eta, roughness alpha) over a diffuse base,
// Mitsuba's `roughplastic`; specularReflectance scales the coating's reflection.
std::shared_ptr<Bsdf> makeRoughPlastic(std::shared_ptr<Texture> diffuseReflectance, float eta, float alpha,
                                       MicrofacetType type, bool nonlinear = false,
                                       const Rgb& specularReflectance = Rgb(1.0f));
std::shared_ptr<Bsdf> makeNull();
// Applies `inner` on both sides by mirroring the frame when wo is on the back.
std::shared_ptr<Bsdf> makeTwoSided(std::shared_ptr<Bsdf> inner);

}  // namespace fg
