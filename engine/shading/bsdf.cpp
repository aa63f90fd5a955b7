// Surface scattering models declared in engine/shading/bsdf.h:
//  - Fresnel equations for dielectrics and for conductors with a complex index
//    of refraction (exact unpolarised form, Born & Wolf, "Principles of Optics",
//    Sec. 14.2), named IOR presets;
//  - Lambertian diffuse, smooth dielectric, thin dielectric (a slab with
//    infinitely many inter-reflections summed in closed form), smooth conductor;
//  - rough conductor and rough dielectric after Walter et al. 2007,
//    "Microfacet Models for Refraction through Rough Surfaces" (Eqs. 20-21 for
//    the BSDF, Eqs. 14-17 for the half-vector Jacobians), with the separable
//    Smith shadowing G1(wo) G1(wi) and visible-normal sampling, templates over
//    the GGX and Beckmann distributions of microfacet.h so that the choice
//    costs nothing per evaluation;
//  - rough plastic: a rough dielectric coating over a Lambertian base
//    (RoughPlasticBsdf below states the model and its approximation);
//  - plastic: a smooth dielectric coating over a Lambertian base (the layered
//    model of Weidlich & Wilkie 2007 in its simplest form, as Mitsuba's
//    `plastic`), where light entering the coating is reflected diffusely and
//    re-enters the base after internal Fresnel reflection, summed as a geometric
//    series with the hemispherical internal reflectance Fdr;
//  - the index-matched null interface and a two-sided adapter.
// All conventions (eval includes |cos(theta_i)|, weight = eval / pdf, specular
// pdf = discrete lobe probability) are those documented in bsdf.h.
#include "engine/shading/bsdf.h"

#include "engine/shading/microfacet.h"

#include <array>
#include <complex>
#include <map>
#include <mutex>
#include <span>
#include <utility>

namespace fg {

namespace {

Vec3 mirrorReflect(const Vec3& w) { return {-w.x, -w.y, w.z}; }
Vec3 flipZ(const Vec3& w) { return {w.x, w.y, -w.z}; }

// Hemispherical average of the Fresnel reflectance, 2 * integral of F(mu) mu dmu
// over [0, 1] (the "diffuse Fresnel reflectance" Fdr). Evaluated by the midpoint
// rule at construction time; the kink at the critical angle limits the error to
// about N^-1.5, far below what a renderer can resolve.
float diffuseFresnelReflectance(float eta) {
    constexpr int kSteps = 1 << 14;
    double sum = 0.0;
    for (int i = 0; i < kSteps; ++i) {
        const float mu = (static_cast<float>(i) + 0.5f) / kSteps;
        sum += static_cast<double>(fresnelDielectric(mu, eta)) * mu;
    }
    return static_cast<float>(2.0 * sum / kSteps);
}

// ---------------------------------------------------------------------------

class DiffuseBsdf final : public Bsdf {
public:
    explicit DiffuseBsdf(std::shared_ptr<Texture> reflectance) : reflectance_(std::move(reflectance)) {}

    std::uint32_t lobes() const override { return BsdfLobe::Reflection | BsdfLobe::Diffuse; }

    Rgb eval(const Vec3& wo, const Vec3& wi, const TexturePoint& at, TransportMode) const override {
        if (wo.z <= 0.0f || wi.z <= 0.0f) return Rgb(0.0f);
        return reflectance_->evalAt(at) * (kInvPi * wi.z);
    }

    std::optional<Rgb> constantReflectance(const TexturePoint& at) const override { return reflectance_->evalAt(at) * kInvPi; }

    float pdf(const Vec3& wo, const Vec3& wi, const TexturePoint&) const override {
        if (wo.z <= 0.0f || wi.z <= 0.0f) return 0.0f;
        return cosineHemispherePdf(wi.z);
    }

    std::optional<BsdfSample> sample(const Vec3& wo, const TexturePoint& at, float, const Vec2& u,
                                     TransportMode) const override {
        // Every return names `s`, so that it is built in the caller's slot: a
        // local copied there at the end is reloaded in wider pieces than it
        // was stored in, which stalls store forwarding on every diffuse bounce.
        std::optional<BsdfSample> s;
        if (wo.z <= 0.0f) return s;
        const Vec3 wi = sampleCosineHemisphere(u);
        if (wi.z <= 0.0f) return s;
        s.emplace();
        s->wi = wi;
        s->pdf = cosineHemispherePdf(wi.z);
        s->weight = reflectance_->evalAt(at);
        s->lobe = BsdfLobe::Reflection | BsdfLobe::Diffuse;
        return s;
    }

private:
    std::shared_ptr<Texture> reflectance_;
};

// ---------------------------------------------------------------------------

class DielectricBsdf final : public Bsdf {
public:
    DielectricBsdf(float eta, std::shared_ptr<Texture> specularReflectance, std::shared_ptr<Texture> specularTransmittance)
        : eta_(eta),
          specularReflectance_(std::move(specularReflectance)),
          specularTransmittance_(std::move(specularTransmittance)) {}

    std::uint32_t lobes() const override {
        return BsdfLobe::Reflection | BsdfLobe::Transmission | BsdfLobe::Specular;
    }
    Rgb eval(const Vec3&, const Vec3&, const TexturePoint&, TransportMode) const override { return Rgb(0.0f); }
    float pdf(const Vec3&, const Vec3&, const TexturePoint&) const override { return 0.0f; }

    std::optional<BsdfSample> sample(const Vec3& wo, const TexturePoint& at, float uLobe, const Vec2&,
                                     TransportMode mode) const override {
        if (wo.z == 0.0f) return std::nullopt;
        float cosThetaT = 0.0f;
        const float reflectance = fresnelDielectric(wo.z, eta_, &cosThetaT);
        BsdfSample s;
        if (uLobe < reflectance) {
            s.wi = mirrorReflect(wo);
            s.pdf = reflectance;
            s.weight = specularReflectance_->evalAt(at);
            s.lobe = BsdfLobe::Reflection | BsdfLobe::Specular;
            return s;
        }
        // Relative IOR from the side of wo to the side of wi.
        const float etaCrossed = wo.z > 0.0f ? eta_ : 1.0f / eta_;
        s.wi = Vec3(-wo.x / etaCrossed, -wo.y / etaCrossed, cosThetaT);
        s.pdf = 1.0f - reflectance;
        // Radiance is compressed into a narrower cone when entering a denser
        // medium; importance (photon flux) is not.
        const float scale = mode == TransportMode::Radiance ? 1.0f / (etaCrossed * etaCrossed) : 1.0f;
        s.weight = specularTransmittance_->evalAt(at) * scale;
        s.eta = etaCrossed;
        s.lobe = BsdfLobe::Transmission | BsdfLobe::Specular;
        return s;
    }

private:
    float eta_;
    std::shared_ptr<Texture> specularReflectance_;
    std::shared_ptr<Texture> specularTransmittance_;
};

// ---------------------------------------------------------------------------

// A slab of negligible thickness: both interfaces see the same angle, the
// transmitted ray leaves undeviated and the inter-reflections inside the slab
// form a geometric series R + T^2 R (1 + R^2 + R^4 + ...) = 2R / (1 + R).
class ThinDielectricBsdf final : public Bsdf {
public:
    explicit ThinDielectricBsdf(float eta) : eta_(eta) {}

    std::uint32_t lobes() const override {
        return BsdfLobe::Reflection | BsdfLobe::Transmission | BsdfLobe::Specular | BsdfLobe::Null;
    }
    Rgb nullTransmission(const Vec3& w, const TexturePoint&) const override {
        if (w.z == 0.0f) return Rgb(0.0f);
        return Rgb(1.0f - slabReflectance(absCosTheta(w)));
    }
    Rgb eval(const Vec3&, const Vec3&, const TexturePoint&, TransportMode) const override { return Rgb(0.0f); }
    float pdf(const Vec3&, const Vec3&, const TexturePoint&) const override { return 0.0f; }

    std::optional<BsdfSample> sample(const Vec3& wo, const TexturePoint&, float uLobe, const Vec2&,
                                     TransportMode) const override {
        if (wo.z == 0.0f) return std::nullopt;
        const float reflectance = slabReflectance(absCosTheta(wo));
        BsdfSample s;
        s.weight = Rgb(1.0f);
        if (uLobe < reflectance) {
            s.wi = mirrorReflect(wo);
            s.pdf = reflectance;
            s.lobe = BsdfLobe::Reflection | BsdfLobe::Specular;
        } else {
            s.wi = -wo;
            s.pdf = 1.0f - reflectance;
            s.lobe = BsdfLobe::Transmission | BsdfLobe::Specular | BsdfLobe::Null;
        }
        return s;
    }

private:
    // Both faces and all internal reflections, incoherently: R + T^2 R / (1 - R^2) = 2R / (1 + R).
    float slabReflectance(float cosTheta) const {
        const float single = fresnelDielectric(cosTheta, eta_);
        return single < 1.0f ? 2.0f * single / (1.0f + single) : 1.0f;
    }

    float eta_;
};

// ---------------------------------------------------------------------------

class ConductorBsdf final : public Bsdf {
public:
    ConductorBsdf(const ConductorIor& ior, std::shared_ptr<Texture> specularReflectance)
        : ior_(ior), specularReflectance_(std::move(specularReflectance)) {}

    std::uint32_t lobes() const override { return BsdfLobe::Reflection | BsdfLobe::Specular; }
    Rgb eval(const Vec3&, const Vec3&, const TexturePoint&, TransportMode) const override { return Rgb(0.0f); }
    float pdf(const Vec3&, const Vec3&, const TexturePoint&) const override { return 0.0f; }

    std::optional<BsdfSample> sample(const Vec3& wo, const TexturePoint& at, float, const Vec2&, TransportMode) const override {
        if (wo.z <= 0.0f) return std::nullopt;
        BsdfSample s;
        s.wi = mirrorReflect(wo);
        s.pdf = 1.0f;
        s.weight = specularReflectance_->evalAt(at) * fresnelConductor(wo.z, ior_.eta, ior_.k);
        s.lobe = BsdfLobe::Reflection | BsdfLobe::Specular;
        return s;
    }

private:
    ConductorIor ior_;
    std::shared_ptr<Texture> specularReflectance_;
};

// ---------------------------------------------------------------------------

template <class Distribution>
class RoughConductorBsdf final : public Bsdf {
public:
    RoughConductorBsdf(const ConductorIor& ior, float alpha, std::shared_ptr<Texture> specularReflectance)
        : ior_(ior), distribution_(alpha), specularReflectance_(std::move(specularReflectance)) {}

    std::uint32_t lobes() const override { return BsdfLobe::Reflection | BsdfLobe::Glossy; }

    Rgb eval(const Vec3& wo, const Vec3& wi, const TexturePoint& at, TransportMode) const override {
        if (wo.z <= 0.0f || wi.z <= 0.0f) return Rgb(0.0f);
        const Vec3 sum = wo + wi;
        if (glm::dot(sum, sum) == 0.0f) return Rgb(0.0f);
        const Vec3 m = glm::normalize(sum);
        const Rgb fresnel = fresnelConductor(glm::dot(wo, m), ior_.eta, ior_.k);
        // D G F / (4 cos_o cos_i), times cos_i.
        return specularReflectance_->evalAt(at) * fresnel * (distribution_.D(m) * distribution_.G(wo, wi) / (4.0f * wo.z));
    }

    float pdf(const Vec3& wo, const Vec3& wi, const TexturePoint&) const override {
        if (wo.z <= 0.0f || wi.z <= 0.0f) return 0.0f;
        const Vec3 sum = wo + wi;
        if (glm::dot(sum, sum) == 0.0f) return 0.0f;
        const Vec3 m = glm::normalize(sum);
        const float cosOM = glm::dot(wo, m);
        if (cosOM <= 0.0f) return 0.0f;
        // Jacobian of the reflection mapping: d(omega_m)/d(omega_i) = 1 / (4 |wo.m|).
        return distribution_.visibleNormalPdf(wo, m) / (4.0f * cosOM);
    }

    std::optional<BsdfSample> sample(const Vec3& wo, const TexturePoint& at, float, const Vec2& u,
                                     TransportMode) const override {
        if (wo.z <= 0.0f) return std::nullopt;
        const Vec3 m = distribution_.sampleVisibleNormal(wo, u);
        const float cosOM = glm::dot(wo, m);
        if (cosOM <= 0.0f) return std::nullopt;
        BsdfSample s;
        s.wi = reflect(wo, m);
        if (s.wi.z <= 0.0f) return std::nullopt;
        s.pdf = distribution_.visibleNormalPdf(wo, m) / (4.0f * cosOM);
        if (!(s.pdf > 0.0f)) return std::nullopt;
        // eval / pdf: D and G1(wo) cancel against the visible-normal density.
        s.weight = specularReflectance_->evalAt(at) * fresnelConductor(cosOM, ior_.eta, ior_.k) * distribution_.G1(s.wi);
        s.lobe = BsdfLobe::Reflection | BsdfLobe::Glossy;
        return s;
    }

private:
    ConductorIor ior_;
    Distribution distribution_;
    std::shared_ptr<Texture> specularReflectance_;
};

// ---------------------------------------------------------------------------

// The interface is symmetric under mirroring z together with inverting eta, so
// every query is first brought to the configuration with wo above the surface.
template <class Distribution>
class RoughDielectricBsdf final : public Bsdf {
public:
    RoughDielectricBsdf(float eta, float alpha) : eta_(eta), distribution_(alpha) {}

    std::uint32_t lobes() const override {
        return BsdfLobe::Reflection | BsdfLobe::Transmission | BsdfLobe::Glossy;
    }

    Rgb eval(const Vec3& woIn, const Vec3& wiIn, const TexturePoint&, TransportMode mode) const override {
        const Upper q = toUpper(woIn, wiIn);
        if (!q.valid) return Rgb(0.0f);
        const Half h = halfVector(q);
        if (!h.valid) return Rgb(0.0f);
        const float fresnel = fresnelDielectric(h.cosOM, q.eta);
        const float dg = distribution_.D(h.m) * distribution_.G(q.wo, q.wi);
        if (h.reflection) return Rgb(fresnel * dg / (4.0f * q.wo.z));
        const float denom = h.cosOM + q.eta * h.cosIM;
        // Walter et al. Eq. 21 (the radiance form) times |cos_i|. Its adjoint,
        // used when tracing importance, carries an extra eta^2 (Veach 1997, Sec. 5.2).
        float value = (1.0f - fresnel) * dg * std::abs(h.cosIM) * h.cosOM / (q.wo.z * denom * denom);
        if (mode == TransportMode::Importance) value *= q.eta * q.eta;
        return Rgb(value);
    }

    float pdf(const Vec3& woIn, const Vec3& wiIn, const TexturePoint&) const override {
        const Upper q = toUpper(woIn, wiIn);
        if (!q.valid) return 0.0f;
        const Half h = halfVector(q);
        if (!h.valid) return 0.0f;
        const float fresnel = fresnelDielectric(h.cosOM, q.eta);
        const float visible = distribution_.visibleNormalPdf(q.wo, h.m);
        if (h.reflection) return fresnel * visible / (4.0f * h.cosOM);
        const float denom = h.cosOM + q.eta * h.cosIM;
        return (1.0f - fresnel) * visible * q.eta * q.eta * std::abs(h.cosIM) / (denom * denom);
    }

    std::optional<BsdfSample> sample(const Vec3& woIn, const TexturePoint&, float uLobe, const Vec2& u,
                                     TransportMode mode) const override {
        if (woIn.z == 0.0f) return std::nullopt;
        const bool flipped = woIn.z < 0.0f;
        const Vec3 wo = flipped ? flipZ(woIn) : woIn;
        const float eta = flipped ? 1.0f / eta_ : eta_;

        const Vec3 m = distribution_.sampleVisibleNormal(wo, u);
        const float cosOM = glm::dot(wo, m);
        if (cosOM <= 0.0f) return std::nullopt;
        const float visible = distribution_.visibleNormalPdf(wo, m);
        float cosThetaT = 0.0f;
        const float fresnel = fresnelDielectric(cosOM, eta, &cosThetaT);

        BsdfSample s;
        if (uLobe < fresnel) {
            s.wi = reflect(wo, m);
            if (s.wi.z <= 0.0f) return std::nullopt;
            s.pdf = fresnel * visible / (4.0f * cosOM);
            s.weight = Rgb(distribution_.G1(s.wi));
            s.lobe = BsdfLobe::Reflection | BsdfLobe::Glossy;
        } else {
            // Refraction about m; cosThetaT is the (negative) cosine to m.
            s.wi = -wo / eta + (cosOM / eta + cosThetaT) * m;
            if (s.wi.z >= 0.0f) return std::nullopt;
            s.wi = glm::normalize(s.wi);
            const float cosIM = glm::dot(s.wi, m);
            const float denom = cosOM + eta * cosIM;
            s.pdf = (1.0f - fresnel) * visible * eta * eta * std::abs(cosIM) / (denom * denom);
            const float scale = mode == TransportMode::Radiance ? 1.0f / (eta * eta) : 1.0f;
            s.weight = Rgb(distribution_.G1(s.wi) * scale);
            s.eta = eta;
            s.lobe = BsdfLobe::Transmission | BsdfLobe::Glossy;
        }
        if (!(s.pdf > 0.0f) || !std::isfinite(s.pdf)) return std::nullopt;
        // A microfacet normal within rounding of the horizon can yield a
        // direction whose reconstructed half vector is on the other side of
        // the cone where pdf() drops to zero; such samples are discarded so
        // that sample() never produces a direction pdf() calls impossible.
        if (!halfVector(Upper{wo, s.wi, eta, true}).valid) return std::nullopt;
        if (flipped) s.wi = flipZ(s.wi);
        return s;
    }

private:
    struct Upper {
        Vec3 wo, wi;
        float eta;  // relative IOR from wo's side to the other side
        bool valid;
    };
    struct Half {
        Vec3 m;
        float cosOM, cosIM;
        bool reflection;
        bool valid;
    };

    Upper toUpper(const Vec3& wo, const Vec3& wi) const {
        if (wo.z == 0.0f || wi.z == 0.0f) return {wo, wi, eta_, false};
        if (wo.z > 0.0f) return {wo, wi, eta_, true};
        return {flipZ(wo), flipZ(wi), 1.0f / eta_, true};
    }

    // Generalised half vector (Walter et al. Eq. 16), oriented towards wo's side,
    // with the side conditions that make the microfacet configuration possible.
    static Half halfVector(const Upper& q) {
        Half h{};
        h.reflection = q.wi.z > 0.0f;
        const Vec3 sum = h.reflection ? q.wo + q.wi : q.wo + q.eta * q.wi;
        const float lenSq = glm::dot(sum, sum);
        if (!(lenSq > 0.0f)) return h;
        h.m = sum / std::sqrt(lenSq);
        if (h.m.z < 0.0f) h.m = -h.m;
        h.cosOM = glm::dot(q.wo, h.m);
        h.cosIM = glm::dot(q.wi, h.m);
        h.valid = h.cosOM > 0.0f && (h.reflection ? h.cosIM > 0.0f : h.cosIM < 0.0f);
        return h;
    }

    float eta_;
    Distribution distribution_;
};

// ---------------------------------------------------------------------------

class PlasticBsdf final : public Bsdf {
public:
    PlasticBsdf(std::shared_ptr<Texture> diffuseReflectance, float eta, bool nonlinear)
        : diffuse_(std::move(diffuseReflectance)),
          eta_(eta),
          invEta2_(1.0f / (eta * eta)),
          fdrInternal_(diffuseFresnelReflectance(1.0f / eta)),
          nonlinear_(nonlinear) {
        // Lobe selection balances the specular albedo (1) against the mean
        // diffuse albedo, each scaled by how much light reaches it.
        const float diffuseMean = std::max(average(diffuse_->mean()), 0.0f);
        specularSamplingWeight_ = 1.0f / (1.0f + diffuseMean);
    }

    std::uint32_t lobes() const override {
        return BsdfLobe::Reflection | BsdfLobe::Specular | BsdfLobe::Diffuse;
    }

    Rgb eval(const Vec3& wo, const Vec3& wi, const TexturePoint& at, TransportMode) const override {
        if (wo.z <= 0.0f || wi.z <= 0.0f) return Rgb(0.0f);
        return diffuseValue(wo, wi, at) * (kInvPi * wi.z);
    }

    float pdf(const Vec3& wo, const Vec3& wi, const TexturePoint&) const override {
        if (wo.z <= 0.0f || wi.z <= 0.0f) return 0.0f;
        const float pSpecular = specularProbability(fresnelDielectric(wo.z, eta_));
        return (1.0f - pSpecular) * cosineHemispherePdf(wi.z);
    }

    std::optional<BsdfSample> sample(const Vec3& wo, const TexturePoint& at, float uLobe, const Vec2& u,
                                     TransportMode) const override {
        if (wo.z <= 0.0f) return std::nullopt;
        const float fresnelIn = fresnelDielectric(wo.z, eta_);
        const float pSpecular = specularProbability(fresnelIn);
        BsdfSample s;
        if (uLobe < pSpecular) {
            s.wi = mirrorReflect(wo);
            s.pdf = pSpecular;
            s.weight = Rgb(fresnelIn / pSpecular);
            s.lobe = BsdfLobe::Reflection | BsdfLobe::Specular;
            return s;
        }
        s.wi = sampleCosineHemisphere(u);
        if (s.wi.z <= 0.0f) return std::nullopt;
        const float pDiffuse = 1.0f - pSpecular;
        s.pdf = pDiffuse * cosineHemispherePdf(s.wi.z);
        s.weight = diffuseValue(wo, s.wi, at) / pDiffuse;
        s.lobe = BsdfLobe::Reflection | BsdfLobe::Diffuse;
        return s;
    }

private:
    float specularProbability(float fresnelIn) const {
        const float specular = fresnelIn * specularSamplingWeight_;
        const float diffuse = (1.0f - fresnelIn) * (1.0f - specularSamplingWeight_);
        const float total = specular + diffuse;
        return total > 0.0f ? specular / total : 1.0f;
    }

    // Diffuse lobe without the 1/pi and cosine: light refracts in (1 - F_i),
    // scatters on the base, and of what heads back up a fraction Fdr is
    // reflected internally and rescattered. Summing the series gives
    // rho / (1 - rho Fdr) ("nonlinear", colours saturate) or, with Mitsuba's
    // default linearisation, rho / (1 - Fdr). Leaving through the coating
    // costs (1 - F_o) and compresses the solid angle by 1/eta^2.
    Rgb diffuseValue(const Vec3& wo, const Vec3& wi, const TexturePoint& at) const {
        const Rgb albedo = diffuse_->evalAt(at);
        const Rgb base = nonlinear_ ? albedo / (Rgb(1.0f) - albedo * fdrInternal_) : albedo / (1.0f - fdrInternal_);
        const float transmission =
            (1.0f - fresnelDielectric(wo.z, eta_)) * (1.0f - fresnelDielectric(wi.z, eta_));
        return base * (invEta2_ * transmission);
    }

    std::shared_ptr<Texture> diffuse_;
    float eta_;
    float invEta2_;
    float fdrInternal_;
    bool nonlinear_;
    float specularSamplingWeight_ = 0.5f;
};

// ---------------------------------------------------------------------------

// Directional albedo of a rough dielectric interface for light arriving at
// cos(theta) = mu on the side from which the relative IOR is eta, split into
// the reflected and the transmitted energy. It is the expectation of the
// rough dielectric's importance-transport sampling weights over the visible
// normals, F G1(wr) and (1 - F) G1(wt), evaluated on a stratified midpoint
// grid of the visible-normal sampling's unit square (deterministic, so every
// material built with the same parameters gets the same tables).
struct InterfaceAlbedo {
    double reflected = 0.0;
    double transmitted = 0.0;
};

template <class Distribution>
InterfaceAlbedo roughInterfaceAlbedo(const Distribution& distribution, float mu, float eta) {
    constexpr int kStrata = 32;
    const Vec3 wo(safeSqrt(1.0f - mu * mu), 0.0f, mu);
    InterfaceAlbedo albedo;
    for (int i = 0; i < kStrata; ++i) {
        for (int j = 0; j < kStrata; ++j) {
            const Vec2 u((static_cast<float>(i) + 0.5f) / kStrata, (static_cast<float>(j) + 0.5f) / kStrata);
            const Vec3 m = distribution.sampleVisibleNormal(wo, u);
            const float cosOM = glm::dot(wo, m);
            if (cosOM <= 0.0f) continue;
            float cosThetaT = 0.0f;
            const float fresnel = fresnelDielectric(cosOM, eta, &cosThetaT);
            const Vec3 reflected = reflect(wo, m);
            if (reflected.z > 0.0f) albedo.reflected += fresnel * distribution.G1(reflected);
            if (fresnel < 1.0f) {
                const Vec3 refracted = glm::normalize(-wo / eta + (cosOM / eta + cosThetaT) * m);
                if (refracted.z < 0.0f) albedo.transmitted += (1.0f - fresnel) * distribution.G1(refracted);
            }
        }
    }
    albedo.reflected /= kStrata * kStrata;
    albedo.transmitted /= kStrata * kStrata;
    return albedo;
}

// What the rough plastic needs to know about its coating: the directional
// transmittance from outside at kSize evenly spaced cosines (interpolated
// linearly) and the hemispherical reflectance from inside.
struct RoughCoatingTables {
    static constexpr int kSize = 64;
    std::array<float, kSize> externalTransmittance{};
    float internalReflectance = 0.0f;
};

template <class Distribution>
RoughCoatingTables computeCoatingTables(float alpha, float eta) {
    const Distribution distribution(alpha);
    RoughCoatingTables tables;
    for (int i = 0; i < RoughCoatingTables::kSize; ++i) {
        const float mu = std::max(static_cast<float>(i) / (RoughCoatingTables::kSize - 1), 1e-4f);
        tables.externalTransmittance[static_cast<std::size_t>(i)] =
            static_cast<float>(roughInterfaceAlbedo(distribution, mu, eta).transmitted);
    }
    constexpr int kInternalSteps = 2 * RoughCoatingTables::kSize;
    double internal = 0.0;
    for (int i = 0; i < kInternalSteps; ++i) {
        const float mu = (static_cast<float>(i) + 0.5f) / kInternalSteps;
        internal += roughInterfaceAlbedo(distribution, mu, 1.0f / eta).reflected * mu;
    }
    tables.internalReflectance = static_cast<float>(2.0 * internal / kInternalSteps);
    return tables;
}

// Scenes use many rough plastics with the same coating and different colours;
// the tables (192 interface albedos of 1024 visible normals each) are
// computed once per coating and shared.
template <class Distribution>
std::shared_ptr<const RoughCoatingTables> coatingTables(float alpha, float eta) {
    static std::mutex mutex;
    static std::map<std::pair<float, float>, std::shared_ptr<const RoughCoatingTables>> cache;
    const std::lock_guard<std::mutex> lock(mutex);
    std::shared_ptr<const RoughCoatingTables>& entry = cache[{alpha, eta}];
    if (!entry) entry = std::make_shared<const RoughCoatingTables>(computeCoatingTables<Distribution>(alpha, eta));
    return entry;
}

// A rough dielectric coating over a Lambertian base, Mitsuba's `roughplastic`
// (whose documentation describes the model; it goes back to Kelemen &
// Szirmay-Kalos 2001, "A Microfacet Based Coupled Specular-Matte BRDF Model
// with Importance Sampling", and Weidlich & Wilkie 2007). The coating's
// reflection is the rough conductor's lobe with the dielectric Fresnel term.
// The diffuse lobe is the smooth plastic's (see PlasticBsdf) with the smooth
// interface's 1 - F replaced by the rough interface's directional
// transmittance T(mu) from outside, and the internal Fresnel average Fdr by
// the rough interface's hemispherical reflectance from inside,
//   r_int = 2 integral_0^1 R_inside(mu) mu dmu,
// so that f_d = rho / (1 - r_int) T(cos_o) T(cos_i) / (pi eta^2), or with
// rho r_int in the denominator when nonlinear.
// The approximation (named so in the tests that measure it): inside the
// coating the radiance is taken to be uniform again after every interaction
// with the rough interface, and light leaving towards wo is weighted with the
// transmittance T(cos_o) of light arriving from wo (exact for a smooth
// interface by Snell's law and Fresnel's symmetry, approximate for a rough one).
template <class Distribution>
class RoughPlasticBsdf final : public Bsdf {
public:
    RoughPlasticBsdf(std::shared_ptr<Texture> diffuseReflectance, float eta, float alpha, bool nonlinear,
                     const Rgb& specularReflectance)
        : diffuse_(std::move(diffuseReflectance)),
          eta_(eta),
          invEta2_(1.0f / (eta * eta)),
          distribution_(alpha),
          nonlinear_(nonlinear),
          specularReflectance_(specularReflectance),
          tables_(coatingTables<Distribution>(distribution_.alpha(), eta)) {
        // Lobe selection balances the mean specular albedo against the mean
        // diffuse albedo, each scaled by how much light reaches it.
        const float diffuseMean = std::max(average(diffuse_->mean()), 0.0f);
        const float specularMean = std::max(average(specularReflectance_), 0.0f);
        specularSamplingWeight_ =
            specularMean + diffuseMean > 0.0f ? specularMean / (specularMean + diffuseMean) : 0.5f;
    }

    std::uint32_t lobes() const override {
        return BsdfLobe::Reflection | BsdfLobe::Glossy | BsdfLobe::Diffuse;
    }

    Rgb eval(const Vec3& wo, const Vec3& wi, const TexturePoint& at, TransportMode) const override {
        if (wo.z <= 0.0f || wi.z <= 0.0f) return Rgb(0.0f);
        Rgb value = diffuseValue(wo, wi, at) * (kInvPi * wi.z);
        const Vec3 m = glm::normalize(wo + wi);
        const float fresnel = fresnelDielectric(glm::dot(wo, m), eta_);
        // D G F / (4 cos_o cos_i), times cos_i.
        value += specularReflectance_ *
                 (fresnel * distribution_.D(m) * distribution_.G(wo, wi) / (4.0f * wo.z));
        return value;
    }

    float pdf(const Vec3& wo, const Vec3& wi, const TexturePoint&) const override {
        if (wo.z <= 0.0f || wi.z <= 0.0f) return 0.0f;
        const float pSpecular = specularProbability(wo.z);
        return pSpecular * specularPdf(wo, wi) + (1.0f - pSpecular) * cosineHemispherePdf(wi.z);
    }

    std::optional<BsdfSample> sample(const Vec3& wo, const TexturePoint& at, float uLobe, const Vec2& u,
                                     TransportMode mode) const override {
        if (wo.z <= 0.0f) return std::nullopt;
        const float pSpecular = specularProbability(wo.z);
        BsdfSample s;
        if (uLobe < pSpecular) {
            const Vec3 m = distribution_.sampleVisibleNormal(wo, u);
            s.wi = reflect(wo, m);
            s.lobe = BsdfLobe::Reflection | BsdfLobe::Glossy;
        } else {
            s.wi = sampleCosineHemisphere(u);
            s.lobe = BsdfLobe::Reflection | BsdfLobe::Diffuse;
        }
        if (s.wi.z <= 0.0f) return std::nullopt;
        // Both lobes are smooth, so the direction's density is the mixture's.
        s.pdf = pSpecular * specularPdf(wo, s.wi) + (1.0f - pSpecular) * cosineHemispherePdf(s.wi.z);
        if (!(s.pdf > 0.0f)) return std::nullopt;
        s.weight = eval(wo, s.wi, at, mode) / s.pdf;
        return s;
    }

private:
    float specularPdf(const Vec3& wo, const Vec3& wi) const {
        const Vec3 m = glm::normalize(wo + wi);
        const float cosOM = glm::dot(wo, m);
        if (cosOM <= 0.0f) return 0.0f;
        return distribution_.visibleNormalPdf(wo, m) / (4.0f * cosOM);
    }

    float externalTransmittance(float cosTheta) const {
        constexpr int kSize = RoughCoatingTables::kSize;
        const float x = std::clamp(cosTheta, 0.0f, 1.0f) * (kSize - 1);
        const int i = std::min(static_cast<int>(x), kSize - 2);
        const float t = x - static_cast<float>(i);
        const auto at = [this](int k) { return tables_->externalTransmittance[static_cast<std::size_t>(k)]; };
        return (1.0f - t) * at(i) + t * at(i + 1);
    }

    // The share of light the coating reflects, 1 - T, stands in for the
    // smooth plastic's Fresnel term in the lobe choice.
    float specularProbability(float cosThetaO) const {
        const float transmittance = externalTransmittance(cosThetaO);
        const float specular = (1.0f - transmittance) * specularSamplingWeight_;
        const float diffuse = transmittance * (1.0f - specularSamplingWeight_);
        const float total = specular + diffuse;
        return total > 0.0f ? specular / total : 1.0f;
    }

    Rgb diffuseValue(const Vec3& wo, const Vec3& wi, const TexturePoint& at) const {
        const Rgb albedo = diffuse_->evalAt(at);
        const float internal = tables_->internalReflectance;
        const Rgb base = nonlinear_ ? albedo / (Rgb(1.0f) - albedo * internal) : albedo / (1.0f - internal);
        return base * (invEta2_ * externalTransmittance(wo.z) * externalTransmittance(wi.z));
    }

    std::shared_ptr<Texture> diffuse_;
    float eta_;
    float invEta2_;
    Distribution distribution_;
    bool nonlinear_;
    Rgb specularReflectance_;
    std::shared_ptr<const RoughCoatingTables> tables_;
    float specularSamplingWeight_ = 0.5f;
};

// ---------------------------------------------------------------------------

class NullBsdf final : public Bsdf {
public:
    std::uint32_t lobes() const override { return BsdfLobe::Null; }
    Rgb nullTransmission(const Vec3&, const TexturePoint&) const override { return Rgb(1.0f); }
    Rgb eval(const Vec3&, const Vec3&, const TexturePoint&, TransportMode) const override { return Rgb(0.0f); }
    float pdf(const Vec3&, const Vec3&, const TexturePoint&) const override { return 0.0f; }
    std::optional<BsdfSample> sample(const Vec3& wo, const TexturePoint&, float, const Vec2&, TransportMode) const override {
        BsdfSample s;
        s.wi = -wo;
        s.weight = Rgb(1.0f);
        s.pdf = 1.0f;
        s.lobe = BsdfLobe::Null | BsdfLobe::Transmission;
        return s;
    }
};

// ---------------------------------------------------------------------------

class TwoSidedBsdf final : public Bsdf {
public:
    explicit TwoSidedBsdf(std::shared_ptr<Bsdf> inner) : inner_(std::move(inner)) {}

    std::uint32_t lobes() const override { return inner_->lobes(); }
    Rgb nullTransmission(const Vec3& w, const TexturePoint& at) const override {
        return inner_->nullTransmission(w.z < 0.0f ? flipZ(w) : w, at);
    }
    bool hasOpacity() const override { return inner_->hasOpacity(); }
    float opacity(const TexturePoint& at) const override { return inner_->opacity(at); }
    bool perturbsNormal() const override { return inner_->perturbsNormal(); }
    Vec3 perturbedNormal(const ShadingGeometry& geometry) const override { return inner_->perturbedNormal(geometry); }

    Rgb eval(const Vec3& wo, const Vec3& wi, const TexturePoint& at, TransportMode mode) const override {
        if (wo.z < 0.0f) return inner_->eval(flipZ(wo), flipZ(wi), at, mode);
        return inner_->eval(wo, wi, at, mode);
    }

    float pdf(const Vec3& wo, const Vec3& wi, const TexturePoint& at) const override {
        if (wo.z < 0.0f) return inner_->pdf(flipZ(wo), flipZ(wi), at);
        return inner_->pdf(wo, wi, at);
    }

    std::optional<BsdfSample> sample(const Vec3& wo, const TexturePoint& at, float uLobe, const Vec2& u,
                                     TransportMode mode) const override {
        if (wo.z >= 0.0f) return inner_->sample(wo, at, uLobe, u, mode);
        std::optional<BsdfSample> s = inner_->sample(flipZ(wo), at, uLobe, u, mode);
        if (s) s->wi = flipZ(s->wi);
        return s;
    }

private:
    std::shared_ptr<Bsdf> inner_;
};

struct ConductorTableEntry {
    std::string_view name;
    Rgb eta;
    Rgb k;
};

// Mitsuba's named conductors: its spectral eta/k tables (mostly the luxpop.com
// database, some Palik) reduced to RGB by tools/conductor_table.py.
std::span<const ConductorTableEntry> conductorTable() {
    static const ConductorTableEntry kTable[] = {
#include "engine/shading/conductor_table.inc"
    };
    return kTable;
}

}  // namespace

// ---------------------------------------------------------------------------

// eta is the interior/exterior ratio. A negative cosThetaI means incidence from
// the interior, where the wave sees the reciprocal ratio. cosThetaT comes back
// with the sign opposite to cosThetaI (the refracted ray is on the other side),
// and 0 under total internal reflection.
float fresnelDielectric(float cosThetaI, float eta, float* cosThetaT) {
    const bool fromInside = cosThetaI < 0.0f;
    const float etaRel = fromInside ? 1.0f / eta : eta;
    const float cosI = std::min(std::abs(cosThetaI), 1.0f);
    if (etaRel == 1.0f) {
        if (cosThetaT) *cosThetaT = -cosThetaI;
        return 0.0f;
    }
    // Snell's law: sin_t = sin_i / eta.
    const float sin2T = (1.0f - cosI * cosI) / (etaRel * etaRel);
    if (sin2T >= 1.0f) {
        if (cosThetaT) *cosThetaT = 0.0f;
        return 1.0f;  // total internal reflection
    }
    const float cosT = std::sqrt(1.0f - sin2T);
    if (cosThetaT) *cosThetaT = fromInside ? cosT : -cosT;
    const float rs = (cosI - etaRel * cosT) / (cosI + etaRel * cosT);
    const float rp = (etaRel * cosI - cosT) / (etaRel * cosI + cosT);
    return 0.5f * (rs * rs + rp * rp);
}

Rgb fresnelConductor(float cosThetaI, const Rgb& eta, const Rgb& k) {
    // Fresnel amplitudes with the complex relative index n = eta + i k and the
    // complex transmitted cosine-term z = sqrt(n^2 - sin^2):
    //   r_s = (cos - z) / (cos + z),  r_p = (n^2 cos - z) / (n^2 cos + z).
    // Evaluated in double precision because |r| is close to 1 for metals.
    using Complex = std::complex<double>;
    const double cosI = std::clamp(static_cast<double>(std::abs(cosThetaI)), 0.0, 1.0);
    const double sin2I = 1.0 - cosI * cosI;
    Rgb result;
    for (int c = 0; c < 3; ++c) {
        const Complex n(eta[c], k[c]);
        const Complex n2 = n * n;
        const Complex z = std::sqrt(n2 - sin2I);
        const Complex sDenom = cosI + z;
        const Complex pDenom = n2 * cosI + z;
        const double rs = std::abs(sDenom) > 0.0 ? std::norm((cosI - z) / sDenom) : 1.0;
        const double rp = std::abs(pDenom) > 0.0 ? std::norm((n2 * cosI - z) / pDenom) : 1.0;
        result[c] = static_cast<float>(std::clamp(0.5 * (rs + rp), 0.0, 1.0));
    }
    return result;
}

std::optional<ConductorIor> conductorPreset(std::string_view name) {
    // Mitsuba's "none": a perfect mirror; with eta = 0, k = 1 the exact
    // conductor Fresnel term is 1 at every angle.
    if (name == "none") return ConductorIor{Rgb(0.0f), Rgb(1.0f)};
    for (const ConductorTableEntry& e : conductorTable())
        if (e.name == name) return ConductorIor{e.eta, e.k};
    return std::nullopt;
}

std::vector<std::string_view> conductorPresetNames() {
    std::vector<std::string_view> names;
    for (const ConductorTableEntry& e : conductorTable()) names.push_back(e.name);
    names.push_back("none");
    return names;
}

std::optional<float> dielectricIorPreset(std::string_view name) {
    // Values at the sodium D line (589 nm), named as in Mitsuba's IOR table.
    struct Entry {
        std::string_view name;
        float ior;
    };
    static const std::array<Entry, 26> kPresets = {{
        {"vacuum", 1.0f},
        {"helium", 1.00004f},
        {"hydrogen", 1.00013f},
        {"air", 1.000277f},
        {"carbon dioxide", 1.00045f},
        {"water", 1.333f},
        {"acetone", 1.36f},
        {"ethanol", 1.361f},
        {"carbon tetrachloride", 1.461f},
        {"glycerol", 1.4729f},
        {"benzene", 1.501f},
        {"silicone oil", 1.52045f},
        {"bromine", 1.661f},
        {"water ice", 1.31f},
        {"fused quartz", 1.458f},
        {"pyrex", 1.47f},
        {"acrylic glass", 1.49f},
        {"acrylic", 1.49f},
        {"polypropylene", 1.49f},
        {"bk7", 1.5046f},
        {"glass", 1.5f},
        {"sodium chloride", 1.544f},
        {"amber", 1.55f},
        {"pet", 1.575f},
        {"polycarbonate", 1.585f},
        {"diamond", 2.419f},
    }};
    for (const Entry& e : kPresets)
        if (e.name == name) return e.ior;
    return std::nullopt;
}

std::shared_ptr<Bsdf> makeDiffuse(std::shared_ptr<Texture> reflectance) {
    return std::make_shared<DiffuseBsdf>(std::move(reflectance));
}

std::shared_ptr<Bsdf> makeDielectric(float eta, const Rgb& specularReflectance, const Rgb& specularTransmittance) {
    return makeDielectric(eta, makeConstantTexture(specularReflectance), makeConstantTexture(specularTransmittance));
}

std::shared_ptr<Bsdf> makeDielectric(float eta, std::shared_ptr<Texture> specularReflectance,
                                     std::shared_ptr<Texture> specularTransmittance) {
    return std::make_shared<DielectricBsdf>(eta, std::move(specularReflectance), std::move(specularTransmittance));
}

std::shared_ptr<Bsdf> makeThinDielectric(float eta) { return std::make_shared<ThinDielectricBsdf>(eta); }

std::shared_ptr<Bsdf> makeConductor(const ConductorIor& ior, const Rgb& specularReflectance) {
    return makeConductor(ior, makeConstantTexture(specularReflectance));
}

std::shared_ptr<Bsdf> makeConductor(const ConductorIor& ior, std::shared_ptr<Texture> specularReflectance) {
    return std::make_shared<ConductorBsdf>(ior, std::move(specularReflectance));
}

std::shared_ptr<Bsdf> makeRoughConductor(const ConductorIor& ior, float alpha, const Rgb& specularReflectance,
                                         MicrofacetType type) {
    return makeRoughConductor(ior, alpha, makeConstantTexture(specularReflectance), type);
}

std::shared_ptr<Bsdf> makeRoughConductor(const ConductorIor& ior, float alpha,
                                         std::shared_ptr<Texture> specularReflectance, MicrofacetType type) {
    if (type == MicrofacetType::Beckmann)
        return std::make_shared<RoughConductorBsdf<BeckmannDistribution>>(ior, alpha, std::move(specularReflectance));
    return std::make_shared<RoughConductorBsdf<GgxDistribution>>(ior, alpha, std::move(specularReflectance));
}

std::shared_ptr<Bsdf> makeRoughDielectric(float eta, float alpha, MicrofacetType type) {
    if (type == MicrofacetType::Beckmann) return std::make_shared<RoughDielectricBsdf<BeckmannDistribution>>(eta, alpha);
    return std::make_shared<RoughDielectricBsdf<GgxDistribution>>(eta, alpha);
}

std::shared_ptr<Bsdf> makePlastic(std::shared_ptr<Texture> diffuseReflectance, float eta, bool nonlinear) {
    return std::make_shared<PlasticBsdf>(std::move(diffuseReflectance), eta, nonlinear);
}

std::shared_ptr<Bsdf> makeRoughPlastic(std::shared_ptr<Texture> diffuseReflectance, float eta, float alpha,
                                       MicrofacetType type, bool nonlinear, const Rgb& specularReflectance) {
    if (type == MicrofacetType::Beckmann) {
        return std::make_shared<RoughPlasticBsdf<BeckmannDistribution>>(std::move(diffuseReflectance), eta, alpha,
                                                                        nonlinear, specularReflectance);
    }
    return std::make_shared<RoughPlasticBsdf<GgxDistribution>>(std::move(diffuseReflectance), eta, alpha, nonlinear,
                                                               specularReflectance);
}

std::shared_ptr<Bsdf> makeNull() { return std::make_shared<NullBsdf>(); }

std::shared_ptr<Bsdf> makeTwoSided(std::shared_ptr<Bsdf> inner) {
    return std::make_shared<TwoSidedBsdf>(std::move(inner));
}

}  // namespace fg
