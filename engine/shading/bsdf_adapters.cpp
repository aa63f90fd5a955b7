// Mask, bump map and normal map adapters (bsdf_adapters.h).
//
// Bump mapping follows Blinn 1978, "Simulation of Wrinkled Surfaces": for a
// surface p(u, v) displaced along its normal n by a height h(u, v), the
// displaced tangents are, to first order in h,
//   p'_u = p_u + h_u n,   p'_v = p_v + h_v n
// (the terms h n_u, h n_v are dropped, as Blinn does for small h). As Mitsuba's
// bumpmap the tangents are first made perpendicular to the shading normal
// (p_u - (n.p_u) n), which is what they already are on flat geometry, and the
// result is turned to the geometric normal's side.
#include "engine/shading/bsdf_adapters.h"

#include <algorithm>
#include <utility>

namespace fg {

namespace {

// Everything the wrapped material does, unchanged.
class ForwardingBsdf : public Bsdf {
public:
    explicit ForwardingBsdf(std::shared_ptr<Bsdf> inner) : inner_(std::move(inner)) {}

    std::uint32_t lobes() const override { return inner_->lobes(); }
    Rgb eval(const Vec3& wo, const Vec3& wi, const TexturePoint& at, TransportMode mode) const override {
        return inner_->eval(wo, wi, at, mode);
    }
    float pdf(const Vec3& wo, const Vec3& wi, const TexturePoint& at) const override { return inner_->pdf(wo, wi, at); }
    std::optional<BsdfSample> sample(const Vec3& wo, const TexturePoint& at, float uLobe, const Vec2& u,
                                     TransportMode mode) const override {
        return inner_->sample(wo, at, uLobe, u, mode);
    }
    std::optional<Rgb> constantReflectance(const TexturePoint& at) const override { return inner_->constantReflectance(at); }
    bool hasOpacity() const override { return inner_->hasOpacity(); }
    float opacity(const TexturePoint& at) const override { return inner_->opacity(at); }
    bool perturbsNormal() const override { return inner_->perturbsNormal(); }
    Vec3 perturbedNormal(const ShadingGeometry& geometry) const override { return inner_->perturbedNormal(geometry); }

protected:
    std::shared_ptr<Bsdf> inner_;
};

class MaskBsdf final : public ForwardingBsdf {
public:
    MaskBsdf(std::shared_ptr<Bsdf> inner, std::shared_ptr<Texture> opacity)
        : ForwardingBsdf(std::move(inner)), opacity_(std::move(opacity)) {}

    bool hasOpacity() const override { return true; }
    float opacity(const TexturePoint& at) const override {
        // A mask around a masked material: both must let the ray pass.
        return clamp01(opacity_->evalScalar(at)) * inner_->opacity(at);
    }

private:
    std::shared_ptr<Texture> opacity_;
};

// A normal on the geometric normal's side; a degenerate one keeps the interpolated normal.
Vec3 orientedNormal(const Vec3& candidate, const ShadingGeometry& geometry) {
    const float length = glm::length(candidate);
    if (!(length > 0.0f) || !std::isfinite(length)) return geometry.frame.n;
    const Vec3 n = candidate / length;
    return glm::dot(n, geometry.ng) < 0.0f ? -n : n;
}

// The wrapped material's own perturbation applies first, so that nesting two
// maps composes them (the outer one sees the inner one's normal as its frame).
ShadingGeometry innerGeometry(const Bsdf& inner, const ShadingGeometry& geometry) {
    if (!inner.perturbsNormal()) return geometry;
    ShadingGeometry result = geometry;
    const Vec3 n = inner.perturbedNormal(geometry);
    const Vec3 s = geometry.frame.s - glm::dot(geometry.frame.s, n) * n;
    const float sLength = glm::length(s);
    result.frame = Frame(n);
    if (sLength > 0.0f) {
        result.frame.s = s / sLength;
        result.frame.t = glm::cross(n, result.frame.s);
    }
    return result;
}

class BumpMapBsdf final : public ForwardingBsdf {
public:
    BumpMapBsdf(std::shared_ptr<Bsdf> inner, std::shared_ptr<Texture> height, float scale)
        : ForwardingBsdf(std::move(inner)), height_(std::move(height)), scale_(scale) {}

    bool perturbsNormal() const override { return true; }
    Vec3 perturbedNormal(const ShadingGeometry& outer) const override {
        const ShadingGeometry g = innerGeometry(*inner_, outer);
        const Vec2 gradient = scale_ * height_->scalarGradient(g.uv);
        const Vec3& n = g.frame.n;
        const Vec3 dpdu = g.dpdu + (gradient.x - glm::dot(n, g.dpdu)) * n;
        const Vec3 dpdv = g.dpdv + (gradient.y - glm::dot(n, g.dpdv)) * n;
        return orientedNormal(glm::cross(dpdu, dpdv), g);
    }

private:
    std::shared_ptr<Texture> height_;
    float scale_;
};

class NormalMapBsdf final : public ForwardingBsdf {
public:
    NormalMapBsdf(std::shared_ptr<Bsdf> inner, std::shared_ptr<Texture> normals)
        : ForwardingBsdf(std::move(inner)), normals_(std::move(normals)) {}

    bool perturbsNormal() const override { return true; }
    Vec3 perturbedNormal(const ShadingGeometry& outer) const override {
        const ShadingGeometry g = innerGeometry(*inner_, outer);
        const Vec3 local = 2.0f * normals_->eval(g.uv) - Vec3(1.0f);
        return orientedNormal(g.frame.toWorld(local), g);
    }

private:
    std::shared_ptr<Texture> normals_;
};

// A direction is sampled from one of the two materials, chosen with
// probability 1 - w and w; a smooth sample then carries the blend's own value
// and pdf (both materials' densities, mixed), so that MIS sees one material.
// A specular sample has no density the other material shares: its pdf is the
// discrete probability of the choice times the lobe's.
class BlendBsdf final : public Bsdf {
public:
    BlendBsdf(std::shared_ptr<Bsdf> first, std::shared_ptr<Bsdf> second, std::shared_ptr<Texture> weight)
        : first_(std::move(first)), second_(std::move(second)), weight_(std::move(weight)) {}

    std::uint32_t lobes() const override { return first_->lobes() | second_->lobes(); }
    Rgb eval(const Vec3& wo, const Vec3& wi, const TexturePoint& at, TransportMode mode) const override {
        const float w = weight(at);
        return (1.0f - w) * first_->eval(wo, wi, at, mode) + w * second_->eval(wo, wi, at, mode);
    }
    float pdf(const Vec3& wo, const Vec3& wi, const TexturePoint& at) const override {
        const float w = weight(at);
        return (1.0f - w) * first_->pdf(wo, wi, at) + w * second_->pdf(wo, wi, at);
    }
    std::optional<BsdfSample> sample(const Vec3& wo, const TexturePoint& at, float uLobe, const Vec2& u,
                                     TransportMode mode) const override {
        const float w = weight(at);
        const bool useSecond = uLobe < w;
        const float choice = useSecond ? w : 1.0f - w;
        const float uInner = std::min(useSecond ? uLobe / w : (uLobe - w) / (1.0f - w), 0x1.fffffep-1f);
        std::optional<BsdfSample> s = (useSecond ? second_ : first_)->sample(wo, at, uInner, u, mode);
        if (!s) return std::nullopt;
        if (s->isSpecular() || (s->lobe & BsdfLobe::Null) != 0) {
            s->pdf *= choice;
            return s;
        }
        s->pdf = pdf(wo, s->wi, at);
        if (!(s->pdf > 0.0f)) return std::nullopt;
        s->weight = eval(wo, s->wi, at, mode) / s->pdf;
        return s;
    }
    std::optional<Rgb> constantReflectance(const TexturePoint& at) const override {
        const std::optional<Rgb> a = first_->constantReflectance(at), b = second_->constantReflectance(at);
        if (!a || !b) return std::nullopt;
        const float w = weight(at);
        return (1.0f - w) * *a + w * *b;
    }
    Rgb nullTransmission(const Vec3& w, const TexturePoint& at) const override {
        const float mix = weight(at);
        return (1.0f - mix) * first_->nullTransmission(w, at) + mix * second_->nullTransmission(w, at);
    }
    bool hasOpacity() const override { return first_->hasOpacity() || second_->hasOpacity(); }
    float opacity(const TexturePoint& at) const override {
        const float w = weight(at);
        return (1.0f - w) * first_->opacity(at) + w * second_->opacity(at);
    }

private:
    float weight(const TexturePoint& at) const { return clamp01(weight_->evalScalar(at)); }

    std::shared_ptr<Bsdf> first_, second_;
    std::shared_ptr<Texture> weight_;
};

}  // namespace

std::shared_ptr<Bsdf> makeBlend(std::shared_ptr<Bsdf> first, std::shared_ptr<Bsdf> second, std::shared_ptr<Texture> weight) {
    return std::make_shared<BlendBsdf>(std::move(first), std::move(second), std::move(weight));
}

std::shared_ptr<Bsdf> makeMask(std::shared_ptr<Bsdf> inner, std::shared_ptr<Texture> opacity) {
    return std::make_shared<MaskBsdf>(std::move(inner), std::move(opacity));
}

std::shared_ptr<Bsdf> makeBumpMap(std::shared_ptr<Bsdf> inner, std::shared_ptr<Texture> height, float scale) {
    return std::make_shared<BumpMapBsdf>(std::move(inner), std::move(height), scale);
}

std::shared_ptr<Bsdf> makeNormalMap(std::shared_ptr<Bsdf> inner, std::shared_ptr<Texture> normals) {
    return std::make_shared<NormalMapBsdf>(std::move(inner), std::move(normals));
}

}  // namespace fg
