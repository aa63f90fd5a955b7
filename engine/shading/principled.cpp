// Mitsuba 3's `principled` BSDF (see principled.h). Lobes, each weighted as
// in Mitsuba 3's plugin:
//  - Disney diffuse with retro-reflection (Burley 2015's diffuse and
//    retro-reflection terms) and, with `flatness`, the Hanrahan-Krueger-like
//    "fake subsurface" of Burley 2012, weighted by (1 - metallic)(1 - spec_trans);
//  - sheen, a Schlick-weighted grazing term tinted towards the base colour's
//    hue (Burley 2012), only where the diffuse lobe is on;
//  - the main GGX lobe (Walter et al. 2007; the anisotropic alphas of Burley
//    2012) reflecting with Mitsuba's Fresnel blend: the exact dielectric
//    Fresnel term, Schlick's approximation towards base_color for `metallic`
//    and towards the base colour's hue for `spec_tint`;
//  - rough dielectric transmission weighted by (1 - metallic) spec_trans and
//    sqrt(base_color) (Burley 2015's specular transmission), with the exact
//    Fresnel term;
//  - clearcoat: GTR1 (Burley 2012, GTR with gamma = 1) with alpha from 0.1 to 0.001 as
//    clearcoat_gloss goes from 0 to 1, Schlick Fresnel with F0 = 0.04 (IOR 1.5)
//    and separable Smith GGX shadowing of roughness 0.25, scaled by
//    clearcoat / 4; as in Mitsuba 3 its value is D F G |cos(theta_i)| without the
//    microfacet model's 1 / (4 cos cos), so that renders match Mitsuba.
// Inside the material only the main lobe's reflection and transmission exist,
// scaled by (1 - metallic) spec_trans as Mitsuba does.
#include "engine/shading/principled.h"

#include <algorithm>
#include <cmath>
#include <utility>

namespace fg {

namespace {

// Anisotropic GGX with separable Smith masking (D and Lambda as in Heitz 2014,
// "Understanding the Masking-Shadowing Function"); alphaX scales the slopes
// along the shading frame's s axis.
class AnisotropicGgx {
public:
    AnisotropicGgx(float alphaX, float alphaY) : alphaX_(alphaX), alphaY_(alphaY) {}

    float D(const Vec3& m) const {
        if (m.z <= 0.0f) return 0.0f;
        const float x = m.x / alphaX_, y = m.y / alphaY_;
        const float denominator = x * x + y * y + m.z * m.z;
        return 1.0f / (kPi * alphaX_ * alphaY_ * denominator * denominator);
    }

    // Smith G1 for direction w and microfacet m; zero where w sees the back of
    // m from its side of the macrosurface (as Mitsuba's smith_g1).
    float G1(const Vec3& w, const Vec3& m) const {
        if (glm::dot(w, m) * w.z <= 0.0f) return 0.0f;
        const float z2 = w.z * w.z;
        if (z2 <= 0.0f) return 0.0f;
        const float projected = alphaX_ * alphaX_ * w.x * w.x + alphaY_ * alphaY_ * w.y * w.y;
        const float lambda = 0.5f * (-1.0f + std::sqrt(1.0f + projected / z2));
        return 1.0f / (1.0f + lambda);
    }

    // Density of visible normals for wo above the surface (Heitz 2018, Eq. 1).
    float visibleNormalPdf(const Vec3& wo, const Vec3& m) const {
        const float cosOM = glm::dot(wo, m);
        if (wo.z <= 0.0f || cosOM <= 0.0f) return 0.0f;
        return G1(wo, m) * cosOM * D(m) / wo.z;
    }

    // Heitz 2018, "Sampling the GGX Distribution of Visible Normals", Listing 1.
    Vec3 sampleVisibleNormal(const Vec3& wo, const Vec2& u) const {
        const Vec3 stretched = glm::normalize(Vec3(alphaX_ * wo.x, alphaY_ * wo.y, wo.z));
        const float lengthSq = stretched.x * stretched.x + stretched.y * stretched.y;
        const Vec3 t1 = lengthSq > 0.0f ? Vec3(-stretched.y, stretched.x, 0.0f) / std::sqrt(lengthSq)
                                        : Vec3(1.0f, 0.0f, 0.0f);
        const Vec3 t2 = glm::cross(stretched, t1);
        const float r = std::sqrt(u.x);
        const float phi = 2.0f * kPi * u.y;
        const float p1 = r * std::cos(phi);
        const float s = 0.5f * (1.0f + stretched.z);
        const float p2 = (1.0f - s) * safeSqrt(1.0f - p1 * p1) + s * r * std::sin(phi);
        const Vec3 onHemisphere = p1 * t1 + p2 * t2 + safeSqrt(1.0f - p1 * p1 - p2 * p2) * stretched;
        return glm::normalize(Vec3(alphaX_ * onHemisphere.x, alphaY_ * onHemisphere.y, std::max(0.0f, onHemisphere.z)));
    }

private:
    float alphaX_, alphaY_;
};

// Burley 2012's GTR with gamma = 1 (Berry's distribution), normalised so that
// D cos(theta_m) integrates to 1 over the hemisphere (its Appendix B).
class Gtr1 {
public:
    explicit Gtr1(float alpha) : alpha2_(alpha * alpha) {}

    float D(const Vec3& m) const {
        if (m.z <= 0.0f) return 0.0f;
        return (alpha2_ - 1.0f) / (kPi * std::log(alpha2_) * (1.0f + (alpha2_ - 1.0f) * m.z * m.z));
    }
    float pdf(const Vec3& m) const { return m.z * D(m); }

    // Burley 2012, Appendix B, inverting the cdf of cos(theta_m).
    Vec3 sample(const Vec2& u) const {
        const float phi = 2.0f * kPi * u.x;
        const float cos2 = (1.0f - std::pow(alpha2_, 1.0f - u.y)) / (1.0f - alpha2_);
        const float sinTheta = safeSqrt(1.0f - cos2), cosTheta = safeSqrt(cos2);
        return {sinTheta * std::cos(phi), sinTheta * std::sin(phi), cosTheta};
    }

private:
    float alpha2_;
};

// Separable Smith GGX masking of the clearcoat (isotropic, roughness 0.25 in
// Burley 2012's reference implementation).
float clearcoatG1(const Vec3& w, const Vec3& m) {
    if (glm::dot(w, m) * w.z <= 0.0f) return 0.0f;
    constexpr float kAlpha2 = 0.25f * 0.25f;
    const float cos2 = w.z * w.z;
    const float tan2 = (1.0f - cos2) / cos2;
    return 2.0f / (1.0f + std::sqrt(1.0f + kAlpha2 * tan2));
}

// (1 - cos)^5, Schlick's Fresnel weight.
float schlickWeight(float cosTheta) {
    const float m = std::clamp(1.0f - cosTheta, 0.0f, 1.0f);
    return (m * m) * (m * m) * m;
}

// Schlick's approximation R0 + (1 - R0) (1 - cos)^5 at the interface of
// relative IOR eta; where the light comes from the denser side the cosine is
// that of the transmitted direction (as Mitsuba's calc_schlick).
template <class T>
T schlickFresnel(const T& r0, float cosThetaI, float eta) {
    const bool outside = cosThetaI >= 0.0f;
    const float etaIt = outside ? eta : 1.0f / eta;
    if (etaIt > 1.0f) return r0 + (T(1.0f) - r0) * schlickWeight(std::abs(cosThetaI));
    const float etaTi = 1.0f / etaIt;
    const float cosThetaT = safeSqrt(1.0f - (1.0f - cosThetaI * cosThetaI) * etaTi * etaTi);
    return r0 + (T(1.0f) - r0) * schlickWeight(cosThetaT);
}

float schlickR0(float eta) {
    const float r = (eta - 1.0f) / (eta + 1.0f);
    return r * r;
}

float scalarOr(const std::shared_ptr<Texture>& texture, const TexturePoint& at, float fallback) {
    return texture ? texture->evalScalar(at) : fallback;
}

class PrincipledBsdf final : public Bsdf {
public:
    explicit PrincipledBsdf(PrincipledParameters parameters) : p_(std::move(parameters)) {
        if (!p_.baseColor) p_.baseColor = makeConstantTexture(Rgb(0.5f));
        if (!p_.roughness) p_.roughness = makeConstantTexture(Rgb(0.5f));
    }

    std::uint32_t lobes() const override {
        std::uint32_t lobes = BsdfLobe::Reflection | BsdfLobe::Diffuse | BsdfLobe::Glossy;
        if (p_.specTrans) lobes |= BsdfLobe::Transmission;
        return lobes;
    }

    Rgb eval(const Vec3& wo, const Vec3& wi, const TexturePoint& at, TransportMode mode) const override {
        const Local l = local(at);
        const float cosO = wo.z, cosI = wi.z;
        if (cosO == 0.0f || cosI == 0.0f) return Rgb(0.0f);
        const bool reflection = cosO * cosI > 0.0f;
        const bool frontSide = cosO > 0.0f;
        const float etaPath = frontSide ? p_.eta : 1.0f / p_.eta;
        const Vec3 m = halfVector(wo, wi, reflection, etaPath);
        if (m == Vec3(0.0f)) return Rgb(0.0f);
        const float fresnel = fresnelDielectric(glm::dot(wo, m), p_.eta);
        const AnisotropicGgx distribution = l.distribution();

        Rgb value(0.0f);
        if (reflection && compatible(m, wo, wi, true) && fresnel > 0.0f) {
            const Rgb f = principledFresnel(l, fresnel, glm::dot(wo, m), frontSide);
            value += f * (distribution.D(m) * distribution.G1(wo, m) * distribution.G1(wi, m) /
                          (4.0f * std::abs(cosO)));
        }
        if (!reflection && p_.specTrans && l.transmissionWeight > 0.0f && fresnel < 1.0f &&
            compatible(m, wo, wi, false)) {
            // Walter et al. 2007, Eq. 21; radiance is compressed by 1/eta^2 on
            // refraction, importance is not.
            const float scale = mode == TransportMode::Radiance ? 1.0f / (etaPath * etaPath) : 1.0f;
            const float cosOM = glm::dot(wo, m), cosIM = glm::dot(wi, m);
            const float denominator = cosOM + etaPath * cosIM;
            const float microfacet = scale * (1.0f - fresnel) * distribution.D(m) * distribution.G1(wo, m) *
                                     distribution.G1(wi, m) * etaPath * etaPath * cosOM * cosIM /
                                     (cosO * denominator * denominator);
            value += glm::sqrt(l.baseColor) * (l.transmissionWeight * std::abs(microfacet));
        }
        if (reflection && frontSide && compatible(m, wo, wi, true) && l.clearcoat > 0.0f) {
            const Gtr1 clearcoat(l.clearcoatAlpha());
            const float f = schlickFresnel(0.04f, glm::dot(wo, m), p_.eta);
            value += Rgb(0.25f * l.clearcoat * f * clearcoat.D(m) * clearcoatG1(wo, m) * clearcoatG1(wi, m) *
                         std::abs(cosI));
        }
        if (reflection && frontSide && l.diffuseWeight > 0.0f) value += diffuseAndSheen(l, wo, wi, m);
        return value;
    }

    float pdf(const Vec3& wo, const Vec3& wi, const TexturePoint& at) const override {
        const Local l = local(at);
        const float cosO = wo.z, cosI = wi.z;
        if (cosO == 0.0f || cosI == 0.0f) return 0.0f;
        const bool reflection = cosO * cosI > 0.0f;
        const bool frontSide = cosO > 0.0f;
        const float etaPath = frontSide ? p_.eta : 1.0f / p_.eta;
        const Vec3 m = halfVector(wo, wi, reflection, etaPath);
        if (m == Vec3(0.0f)) return 0.0f;
        const float fresnel = fresnelDielectric(glm::dot(wo, m), p_.eta);
        const Probabilities prob = probabilities(l, fresnel, frontSide);
        const AnisotropicGgx distribution = l.distribution();
        const Vec3 woUpper = frontSide ? wo : -wo;
        const float cosOM = glm::dot(wo, m), cosIM = glm::dot(wi, m);

        float density = 0.0f;
        if (reflection) {
            const float jacobian = 1.0f / std::abs(4.0f * cosIM);
            if (compatible(m, wo, wi, true)) {
                density += prob.specularReflection * distribution.visibleNormalPdf(woUpper, m) * jacobian;
                if (prob.clearcoat > 0.0f) density += prob.clearcoat * Gtr1(l.clearcoatAlpha()).pdf(m) * jacobian;
            }
            density += prob.diffuse * cosineHemispherePdf(std::abs(cosI));
        } else if (prob.specularTransmission > 0.0f && compatible(m, wo, wi, false)) {
            const float denominator = cosOM + etaPath * cosIM;
            const float jacobian = std::abs(etaPath * etaPath * cosIM / (denominator * denominator));
            density += prob.specularTransmission * distribution.visibleNormalPdf(woUpper, m) * jacobian;
        }
        return density;
    }

    std::optional<BsdfSample> sample(const Vec3& wo, const TexturePoint& at, float uLobe, const Vec2& u,
                                     TransportMode mode) const override {
        const Local l = local(at);
        const float cosO = wo.z;
        if (cosO == 0.0f) return std::nullopt;
        const bool frontSide = cosO > 0.0f;
        if (!frontSide && !(p_.specTrans && l.transmissionWeight > 0.0f)) return std::nullopt;
        const Vec3 woUpper = frontSide ? wo : -wo;
        const Vec3 m = l.distribution().sampleVisibleNormal(woUpper, u);
        float cosThetaT = 0.0f;
        const float cosOM = glm::dot(wo, m);
        const float fresnel = fresnelDielectric(cosOM, p_.eta, &cosThetaT);
        const Probabilities prob = probabilities(l, fresnel, frontSide);

        BsdfSample s;
        if (uLobe < prob.diffuse) {
            s.wi = sampleCosineHemisphere(u);
            s.lobe = BsdfLobe::Reflection | BsdfLobe::Diffuse;
        } else if (uLobe < prob.diffuse + prob.clearcoat) {
            // GTR1 normals are drawn without regard to wo; one facing away
            // cannot reflect (and pdf() would not count the direction).
            const Vec3 coatNormal = Gtr1(l.clearcoatAlpha()).sample(u);
            if (glm::dot(wo, coatNormal) <= 0.0f) return std::nullopt;
            s.wi = reflect(wo, coatNormal);
            s.lobe = BsdfLobe::Reflection | BsdfLobe::Glossy;
        } else if (uLobe < prob.diffuse + prob.clearcoat + prob.specularTransmission) {
            if (fresnel >= 1.0f || !compatibleSample(m, wo)) return std::nullopt;
            const float etaTi = frontSide ? 1.0f / p_.eta : p_.eta;
            s.wi = glm::normalize(m * (cosOM * etaTi + cosThetaT) - wo * etaTi);
            s.eta = frontSide ? p_.eta : 1.0f / p_.eta;
            s.lobe = BsdfLobe::Transmission | BsdfLobe::Glossy;
        } else {
            if (!compatibleSample(m, wo)) return std::nullopt;
            s.wi = reflect(wo, m);
            s.lobe = BsdfLobe::Reflection | BsdfLobe::Glossy;
        }
        // A reflection that leaves through the surface, or a refraction that
        // does not cross it, is lost, as in Mitsuba: pdf() would count such a
        // direction under the other kind of event.
        const bool reflected = (s.lobe & BsdfLobe::Reflection) != 0;
        if (reflected ? s.wi.z * cosO <= 0.0f : s.wi.z * cosO >= 0.0f) return std::nullopt;
        // Every lobe is smooth, so the direction's density is the mixture's;
        // pdf() also rejects directions whose half vector the sampled lobe
        // cannot produce.
        s.pdf = pdf(wo, s.wi, at);
        if (!(s.pdf > 0.0f) || !std::isfinite(s.pdf)) return std::nullopt;
        s.weight = eval(wo, s.wi, at, mode) / s.pdf;
        return s;
    }

private:
    // The parameters at one surface point.
    struct Local {
        Rgb baseColor;
        float roughness, metallic, specTint, anisotropic, sheen, sheenTint, clearcoat, clearcoatGloss, specTrans,
            flatness;
        float diffuseWeight, transmissionWeight;

        // Burley 2012: alpha = roughness^2, stretched by the aspect ratio
        // sqrt(1 - 0.9 anisotropic); Mitsuba keeps alpha >= 0.001.
        AnisotropicGgx distribution() const {
            const float alpha = roughness * roughness;
            const float aspect = std::sqrt(1.0f - 0.9f * anisotropic);
            return {std::max(0.001f, alpha / aspect), std::max(0.001f, alpha * aspect)};
        }
        float clearcoatAlpha() const { return 0.1f + (0.001f - 0.1f) * clearcoatGloss; }
        // The base colour's hue and saturation at unit luminance (Burley 2012's Ctint).
        Rgb tint() const {
            const float lum = luminance(baseColor);
            return lum > 0.0f ? baseColor / lum : Rgb(1.0f);
        }
    };

    struct Probabilities {
        float diffuse = 0.0f, clearcoat = 0.0f, specularTransmission = 0.0f, specularReflection = 0.0f;
    };

    Local local(const TexturePoint& at) const {
        Local l{};
        l.baseColor = p_.baseColor->evalAt(at);
        l.roughness = p_.roughness->evalScalar(at);
        l.metallic = scalarOr(p_.metallic, at, 0.0f);
        l.specTint = scalarOr(p_.specTint, at, 0.0f);
        l.anisotropic = scalarOr(p_.anisotropic, at, 0.0f);
        l.sheen = scalarOr(p_.sheen, at, 0.0f);
        l.sheenTint = scalarOr(p_.sheenTint, at, 0.0f);
        l.clearcoat = scalarOr(p_.clearcoat, at, 0.0f);
        l.clearcoatGloss = scalarOr(p_.clearcoatGloss, at, 0.0f);
        l.specTrans = scalarOr(p_.specTrans, at, 0.0f);
        l.flatness = scalarOr(p_.flatness, at, 0.0f);
        l.diffuseWeight = (1.0f - l.metallic) * (1.0f - l.specTrans);
        l.transmissionWeight = (1.0f - l.metallic) * l.specTrans;
        return l;
    }

    // Mitsuba's lobe choice: outside, the main lobe (reflection and
    // transmission split by the dielectric Fresnel term) against the diffuse
    // lobe by weight and the clearcoat at a quarter of its weight; inside,
    // the main lobe alone.
    Probabilities probabilities(const Local& l, float fresnel, bool frontSide) const {
        Probabilities prob;
        const float transmission = p_.specTrans ? l.transmissionWeight : 0.0f;
        if (frontSide) {
            prob.specularReflection = p_.mainSpecularSamplingRate * (1.0f - transmission * (1.0f - fresnel));
            prob.specularTransmission = p_.mainSpecularSamplingRate * transmission * (1.0f - fresnel);
            prob.clearcoat = p_.clearcoat ? 0.25f * l.clearcoat * p_.clearcoatSamplingRate : 0.0f;
            prob.diffuse = l.diffuseWeight * p_.diffuseReflectanceSamplingRate;
        } else {
            prob.specularReflection = fresnel;
            prob.specularTransmission = p_.specTrans ? 1.0f - fresnel : 0.0f;
        }
        const float total =
            prob.diffuse + prob.clearcoat + prob.specularTransmission + prob.specularReflection;
        if (total > 0.0f) {
            prob.diffuse /= total;
            prob.clearcoat /= total;
            prob.specularTransmission /= total;
            prob.specularReflection /= total;
        }
        return prob;
    }

    // The reflection half vector, or for refraction the generalised one of
    // Walter et al. 2007, Eq. 16, turned to the outside (+z); zero if undefined.
    static Vec3 halfVector(const Vec3& wo, const Vec3& wi, bool reflection, float etaPath) {
        const Vec3 sum = reflection ? wo + wi : wo + etaPath * wi;
        const float lengthSq = glm::dot(sum, sum);
        if (!(lengthSq > 0.0f)) return Vec3(0.0f);
        const Vec3 m = sum / std::sqrt(lengthSq);
        return m.z < 0.0f ? -m : m;
    }

    // A sampled microfacet must face wo from wo's side.
    static bool compatibleSample(const Vec3& m, const Vec3& wo) { return glm::dot(wo, wo.z > 0.0f ? m : -m) > 0.0f; }

    // Both directions must see the microfacet from the side they are on
    // (Mitsuba's mac_mic_compatibility).
    static bool compatible(const Vec3& m, const Vec3& wo, const Vec3& wi, bool reflection) {
        const Vec3 facing = wo.z > 0.0f ? m : -m;
        return glm::dot(wo, facing) > 0.0f && (reflection ? glm::dot(wi, facing) > 0.0f : glm::dot(wi, facing) < 0.0f);
    }

    // Mitsuba's principled Fresnel term: outside, the dielectric Fresnel term
    // blended with Schlick towards base_color (metallic) and towards the
    // tinted dielectric F0 (spec_tint); inside, the dielectric term scaled by
    // the transmission weight.
    Rgb principledFresnel(const Local& l, float fresnel, float cosOM, bool frontSide) const {
        if (!frontSide) return Rgb(l.transmissionWeight * fresnel);
        Rgb f = Rgb((1.0f - l.metallic) * (1.0f - l.specTint) * fresnel);
        if (l.metallic > 0.0f) f += l.metallic * schlickFresnel(l.baseColor, cosOM, p_.eta);
        if (l.specTint > 0.0f) {
            const float etaIt = cosOM >= 0.0f ? p_.eta : 1.0f / p_.eta;
            f += (1.0f - l.metallic) * l.specTint * schlickFresnel(l.tint() * schlickR0(etaIt), cosOM, p_.eta);
        }
        return f;
    }

    Rgb diffuseAndSheen(const Local& l, const Vec3& wo, const Vec3& wi, const Vec3& m) const {
        const float cosO = std::abs(wo.z), cosI = std::abs(wi.z);
        const float fresnelO = schlickWeight(cosO), fresnelI = schlickWeight(cosI);
        // Burley 2015: the Lambertian part loses light at grazing angles...
        const float lambert = (1.0f - 0.5f * fresnelO) * (1.0f - 0.5f * fresnelI);
        // ...and the retro-reflection term gives it back on rough surfaces.
        const float cosD = glm::dot(m, wi);
        const float retroReflection = 2.0f * l.roughness * cosD * cosD;
        const float retro = retroReflection * (fresnelO + fresnelI + fresnelO * fresnelI * (retroReflection - 1.0f));
        float shape = lambert + retro;
        if (p_.flatness) {
            // Burley 2012: the Hanrahan-Krueger-inspired flattening,
            // with Mitsuba's Fss90 = R_R / 2 (= roughness cos^2(theta_d)).
            const float fss90 = 0.5f * retroReflection;
            const float fss = (1.0f + (fss90 - 1.0f) * fresnelO) * (1.0f + (fss90 - 1.0f) * fresnelI);
            const float subsurface = 1.25f * (fss * (1.0f / (cosO + cosI) - 0.5f) + 0.5f);
            shape += (subsurface - shape) * l.flatness;
        }
        Rgb value = l.baseColor * (l.diffuseWeight * kInvPi * shape * cosI);
        if (l.sheen > 0.0f) {
            const Rgb sheenColour = Rgb(1.0f) + (l.tint() - Rgb(1.0f)) * l.sheenTint;
            value += sheenColour * (l.sheen * (1.0f - l.metallic) * schlickWeight(std::abs(cosD)) * cosI);
        }
        return value;
    }

    PrincipledParameters p_;
};

// Mitsuba 3's principledthin: the same directions on either side (the sheet
// is symmetric, so a back-side wo is mirrored to the front). Lobes, as
// Mitsuba weights them: the principled diffuse and sheen scaled by
// (1 - spec_trans)(1 - diff_trans / 2); Lambertian transmission by
// (1 - spec_trans) diff_trans / 2; and, only where spec_trans > 0, GGX
// reflection with the dielectric Fresnel term blended towards the tinted
// Schlick term by spec_tint, and transmission straight through the sheet
// (the reflection about a microfacet mirrored to the far side), scaled by
// base_color and 1 - F, with roughness scaled by 0.65 eta - 0.35 (Burley
// 2015, Fig. 15). Both specular lobes are weighted by spec_trans.
class PrincipledThinBsdf final : public Bsdf {
public:
    explicit PrincipledThinBsdf(PrincipledThinParameters parameters) : p_(std::move(parameters)) {
        if (!p_.baseColor) p_.baseColor = makeConstantTexture(Rgb(0.5f));
        if (!p_.roughness) p_.roughness = makeConstantTexture(Rgb(0.5f));
        if (!p_.eta) p_.eta = makeConstantTexture(Rgb(1.5f));
    }

    std::uint32_t lobes() const override {
        std::uint32_t lobes = BsdfLobe::Reflection | BsdfLobe::Diffuse;
        if (p_.diffTrans || p_.specTrans) lobes |= BsdfLobe::Transmission;
        if (p_.specTrans) lobes |= BsdfLobe::Glossy;
        return lobes;
    }

    Rgb eval(const Vec3& woAnySide, const Vec3& wiAnySide, const TexturePoint& at, TransportMode) const override {
        if (woAnySide.z == 0.0f) return Rgb(0.0f);
        const Vec3 wo = woAnySide.z > 0.0f ? woAnySide : -woAnySide;
        const Vec3 wi = woAnySide.z > 0.0f ? wiAnySide : -wiAnySide;
        if (wi.z == 0.0f) return Rgb(0.0f);
        const Local l = local(at);
        const bool reflection = wi.z > 0.0f;
        const Vec3 m = glm::normalize(wo + Vec3(wi.x, wi.y, std::abs(wi.z)));

        Rgb value(0.0f);
        if (l.specTrans > 0.0f) {
            const float fresnel = fresnelDielectric(glm::dot(wo, m), l.eta);
            if (reflection && compatible(m, wo, wi, true)) {
                const AnisotropicGgx distribution = l.reflectionDistribution();
                value += thinFresnel(l, fresnel, glm::dot(wo, m)) *
                         (l.specTrans * distribution.D(m) * distribution.G1(wo, m) * distribution.G1(wi, m) /
                          (4.0f * wo.z));
            }
            if (!reflection && compatible(m, wo, wi, false)) {
                const AnisotropicGgx distribution = l.transmissionDistribution();
                value += l.baseColor * (l.specTrans * (1.0f - fresnel) * distribution.D(m) * distribution.G1(wo, m) *
                                        distribution.G1(wi, m) / (4.0f * wo.z));
            }
        }
        if (reflection && l.specTrans < 1.0f && l.diffTrans < 1.0f) {
            const float cosO = wo.z, cosI = wi.z;
            const float fresnelO = schlickWeight(cosO), fresnelI = schlickWeight(cosI);
            const float lambert = (1.0f - 0.5f * fresnelO) * (1.0f - 0.5f * fresnelI);
            const float cosD = glm::dot(m, wi);
            const float retroReflection = 2.0f * l.roughness * cosD * cosD;
            float shape =
                lambert + retroReflection * (fresnelO + fresnelI + fresnelO * fresnelI * (retroReflection - 1.0f));
            if (p_.flatness) {
                const float fss90 = 0.5f * retroReflection;
                const float fss = (1.0f + (fss90 - 1.0f) * fresnelO) * (1.0f + (fss90 - 1.0f) * fresnelI);
                const float subsurface = 1.25f * (fss * (1.0f / (cosO + cosI) - 0.5f) + 0.5f);
                shape += (subsurface - shape) * l.flatness;
            }
            const float weight = (1.0f - l.specTrans) * (1.0f - l.diffTrans);
            value += l.baseColor * (weight * kInvPi * shape * cosI);
            if (l.sheen > 0.0f) {
                const float lum = luminance(l.baseColor);
                const Rgb tint = lum > 0.0f ? l.baseColor / lum : Rgb(1.0f);
                const Rgb sheenColour = Rgb(1.0f) + (tint - Rgb(1.0f)) * l.sheenTint;
                value += sheenColour * (l.sheen * weight * schlickWeight(std::abs(cosD)) * cosI);
            }
        }
        if (!reflection && l.specTrans < 1.0f && l.diffTrans > 0.0f)
            value += l.baseColor * ((1.0f - l.specTrans) * l.diffTrans * kInvPi * std::abs(wi.z));
        return value;
    }

    float pdf(const Vec3& woAnySide, const Vec3& wiAnySide, const TexturePoint& at) const override {
        if (woAnySide.z == 0.0f) return 0.0f;
        const Vec3 wo = woAnySide.z > 0.0f ? woAnySide : -woAnySide;
        const Vec3 wi = woAnySide.z > 0.0f ? wiAnySide : -wiAnySide;
        if (wi.z == 0.0f) return 0.0f;
        const Local l = local(at);
        const Probabilities prob = probabilities(l);
        const bool reflection = wi.z > 0.0f;
        const Vec3 mirrored(wi.x, wi.y, std::abs(wi.z));
        const Vec3 m = glm::normalize(wo + mirrored);
        // Both specular lobes are reflections about m (the transmitted one then
        // mirrored through the sheet), so both have the reflection Jacobian.
        const float jacobian = 1.0f / std::abs(4.0f * glm::dot(mirrored, m));
        float density = 0.0f;
        if (reflection) {
            if (prob.specularReflection > 0.0f && compatible(m, wo, wi, true))
                density += prob.specularReflection * l.reflectionDistribution().visibleNormalPdf(wo, m) * jacobian;
            density += prob.diffuseReflection * cosineHemispherePdf(wi.z);
        } else {
            if (prob.specularTransmission > 0.0f && compatible(m, wo, wi, false))
                density += prob.specularTransmission * l.transmissionDistribution().visibleNormalPdf(wo, m) * jacobian;
            density += prob.diffuseTransmission * cosineHemispherePdf(-wi.z);
        }
        return density;
    }

    std::optional<BsdfSample> sample(const Vec3& woAnySide, const TexturePoint& at, float uLobe, const Vec2& u,
                                     TransportMode mode) const override {
        if (woAnySide.z == 0.0f) return std::nullopt;
        const bool back = woAnySide.z < 0.0f;
        const Vec3 wo = back ? -woAnySide : woAnySide;
        const Local l = local(at);
        const Probabilities prob = probabilities(l);
        BsdfSample s;
        // Microfacet samples whose configuration pdf() would not count for
        // their lobe are lost (the other lobes could cover the direction).
        if (uLobe < prob.specularReflection) {
            const Vec3 m = l.reflectionDistribution().sampleVisibleNormal(wo, u);
            s.wi = reflect(wo, m);
            if (!compatible(m, wo, s.wi, true)) return std::nullopt;
            s.lobe = BsdfLobe::Reflection | BsdfLobe::Glossy;
        } else if (uLobe < prob.specularReflection + prob.specularTransmission) {
            const Vec3 m = l.transmissionDistribution().sampleVisibleNormal(wo, u);
            s.wi = reflect(wo, m);
            s.wi.z = -s.wi.z;
            if (!compatible(m, wo, s.wi, false)) return std::nullopt;
            s.lobe = BsdfLobe::Transmission | BsdfLobe::Glossy;
        } else if (uLobe < prob.specularReflection + prob.specularTransmission + prob.diffuseReflection) {
            s.wi = sampleCosineHemisphere(u);
            s.lobe = BsdfLobe::Reflection | BsdfLobe::Diffuse;
        } else {
            s.wi = -sampleCosineHemisphere(u);
            s.lobe = BsdfLobe::Transmission | BsdfLobe::Diffuse;
        }
        const bool reflected = (s.lobe & BsdfLobe::Reflection) != 0;
        if (reflected ? s.wi.z <= 0.0f : s.wi.z >= 0.0f) return std::nullopt;
        if (back) s.wi = -s.wi;
        s.pdf = pdf(woAnySide, s.wi, at);
        if (!(s.pdf > 0.0f) || !std::isfinite(s.pdf)) return std::nullopt;
        s.weight = eval(woAnySide, s.wi, at, mode) / s.pdf;
        return s;
    }

private:
    struct Local {
        Rgb baseColor;
        float roughness, eta, specTint, anisotropic, sheen, sheenTint, specTrans, flatness, diffTrans;

        AnisotropicGgx distribution(float scaledRoughness) const {
            const float alpha = scaledRoughness * scaledRoughness;
            const float aspect = std::sqrt(1.0f - 0.9f * anisotropic);
            return {std::max(0.001f, alpha / aspect), std::max(0.001f, alpha * aspect)};
        }
        AnisotropicGgx reflectionDistribution() const { return distribution(roughness); }
        AnisotropicGgx transmissionDistribution() const { return distribution((0.65f * eta - 0.35f) * roughness); }
    };

    struct Probabilities {
        float specularReflection = 0.0f, specularTransmission = 0.0f, diffuseReflection = 0.0f,
              diffuseTransmission = 0.0f;
    };

    Local local(const TexturePoint& at) const {
        Local l{};
        l.baseColor = p_.baseColor->evalAt(at);
        l.roughness = p_.roughness->evalScalar(at);
        l.eta = p_.eta->evalScalar(at);
        l.specTint = scalarOr(p_.specTint, at, 0.0f);
        l.anisotropic = scalarOr(p_.anisotropic, at, 0.0f);
        l.sheen = scalarOr(p_.sheen, at, 0.0f);
        l.sheenTint = scalarOr(p_.sheenTint, at, 0.0f);
        l.specTrans = scalarOr(p_.specTrans, at, 0.0f);
        l.flatness = scalarOr(p_.flatness, at, 0.0f);
        // Mitsuba's diff_trans runs from 0 to 2; half of it is the share transmitted.
        l.diffTrans = 0.5f * scalarOr(p_.diffTrans, at, 0.0f);
        return l;
    }

    // Mitsuba's choice: each specular lobe at half of spec_trans, the diffuse
    // lobes sharing the rest as diff_trans / 2 divides it.
    Probabilities probabilities(const Local& l) const {
        Probabilities prob;
        if (p_.specTrans) {
            prob.specularReflection = 0.5f * l.specTrans * p_.specularReflectanceSamplingRate;
            prob.specularTransmission = 0.5f * l.specTrans * p_.specularTransmittanceSamplingRate;
        }
        prob.diffuseReflection = p_.diffuseReflectanceSamplingRate * (1.0f - l.specTrans) * (1.0f - l.diffTrans);
        if (p_.diffTrans)
            prob.diffuseTransmission = p_.diffuseTransmittanceSamplingRate * (1.0f - l.specTrans) * l.diffTrans;
        const float total =
            prob.specularReflection + prob.specularTransmission + prob.diffuseReflection + prob.diffuseTransmission;
        if (total > 0.0f) {
            prob.specularReflection /= total;
            prob.specularTransmission /= total;
            prob.diffuseReflection /= total;
            prob.diffuseTransmission /= total;
        }
        return prob;
    }

    // As the principled BSDF's test, with wo on the front side: for
    // transmission wi must lie behind m as seen from the front.
    static bool compatible(const Vec3& m, const Vec3& wo, const Vec3& wi, bool reflection) {
        return glm::dot(wo, m) > 0.0f && (reflection ? glm::dot(wi, m) > 0.0f : glm::dot(wi, m) < 0.0f);
    }

    // Mitsuba's thin Fresnel term: the dielectric term blended by spec_tint
    // towards Schlick's approximation with the tinted F0.
    static Rgb thinFresnel(const Local& l, float fresnel, float cosOM) {
        if (l.specTint <= 0.0f) return Rgb(fresnel);
        const float lum = luminance(l.baseColor);
        const Rgb tint = lum > 0.0f ? l.baseColor / lum : Rgb(1.0f);
        const Rgb schlick = schlickFresnel(tint * schlickR0(l.eta), cosOM, l.eta);
        return Rgb(fresnel) + (schlick - Rgb(fresnel)) * l.specTint;
    }

    PrincipledThinParameters p_;
};

}  // namespace

std::shared_ptr<Bsdf> makePrincipledThin(PrincipledThinParameters parameters) {
    return std::make_shared<PrincipledThinBsdf>(std::move(parameters));
}

float principledEtaFromSpecular(float specular) { return 2.0f / (1.0f - std::sqrt(0.08f * specular)) - 1.0f; }

std::shared_ptr<Bsdf> makePrincipled(PrincipledParameters parameters) {
    return std::make_shared<PrincipledBsdf>(std::move(parameters));
}

}  // namespace fg
