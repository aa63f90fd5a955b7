// One-sample mixture of BSDF and GMM sampling, Vorba et al. 2014 §4.1.
#include "engine/guiding/guided_sampling.h"

namespace fg {

float GuidedBsdfSampler::pdf(const Vec3& wiLocal) const { return pdf(wiLocal, shading.toWorld(wiLocal)); }

float GuidedBsdfSampler::pdf(const Vec3& wiLocal, const Vec3& wiWorld) const {
    const float bsdfPdf = bsdf->pdf(wo, wiLocal, at);
    const float gmmPdf = gmm->pdfLocal(gmmFrame.toLocal(wiWorld));
    return bsdfProbability * bsdfPdf + (1.0f - bsdfProbability) * gmmPdf;
}

std::optional<GuidedDraw> GuidedBsdfSampler::draw(float uStrategy, float uLobe, const Vec2& uDir) const {
    if (uStrategy < bsdfProbability) {
        const std::optional<BsdfSample> bs = bsdf->sample(wo, at, uLobe, uDir, TransportMode::Radiance);
        if (!bs || bs->pdf <= 0.0f || isBlack(bs->weight)) return std::nullopt;
        return GuidedDraw{bs->wi, shading.toWorld(bs->wi), Vec2(0.0f), bs->pdf, false};
    }
    const Vec2 square = gmm->samplePlane(uLobe, uDir);
    // The GMM's mass outside the square (§4.1).
    if (!(square.x >= 0.0f && square.x <= 1.0f && square.y >= 0.0f && square.y <= 1.0f)) return std::nullopt;
    const Vec3 wiWorld = gmmFrame.toWorld(squareToHemisphere(square));
    return GuidedDraw{shading.toLocal(wiWorld), wiWorld, square, 0.0f, true};
}

float GuidedBsdfSampler::drawnPdf(const GuidedDraw& drawn) const {
    if (!drawn.fromGmm) {
        const float gmmPdf = gmm->pdfLocal(gmmFrame.toLocal(drawn.wiWorld));
        return bsdfProbability * drawn.bsdfPdf + (1.0f - bsdfProbability) * gmmPdf;
    }
    const float gmmPdf = gmm->pdfSquare(drawn.square) * (1.0f / kSquareToHemisphereJacobian);
    return bsdfProbability * bsdf->pdf(wo, drawn.wi, at) + (1.0f - bsdfProbability) * gmmPdf;
}

std::optional<GuidedSample> GuidedBsdfSampler::sample(float uStrategy, float uLobe, const Vec2& uDir) const {
    const std::optional<GuidedDraw> drawn = draw(uStrategy, uLobe, uDir);
    if (!drawn) return std::nullopt;
    return GuidedSample{drawn->wi, drawn->wiWorld, drawnPdf(*drawn)};
}

std::optional<BsdfSample> GuidedBsdfSampler::sampleAsBsdf(float uStrategy, float uLobe, const Vec2& uDir,
                                                          TransportMode mode) const {
    const std::optional<GuidedSample> drawn = sample(uStrategy, uLobe, uDir);
    if (!drawn || !(drawn->pdf > 0.0f)) return std::nullopt;
    const Rgb f = bsdf->eval(wo, drawn->wi, at, mode);
    if (isBlack(f)) return std::nullopt;
    BsdfSample result;
    result.wi = drawn->wi;
    result.weight = f / drawn->pdf;  // Bsdf::eval includes the cosine
    result.pdf = drawn->pdf;
    result.lobe = BsdfLobe::Reflection | BsdfLobe::Glossy;
    return result;
}

}  // namespace fg
