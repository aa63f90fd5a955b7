// One-sample mixture of BSDF and GMM sampling, Vorba et al. 2014 §4.1.
#include "engine/guiding/guided_sampling.h"

namespace fg {

float GuidedBsdfSampler::pdf(const Vec3& wiLocal) const { return pdf(wiLocal, shading.toWorld(wiLocal)); }

float GuidedBsdfSampler::pdf(const Vec3& wiLocal, const Vec3& wiWorld) const {
    const float bsdfPdf = bsdf->pdf(wo, wiLocal, at);
    const float gmmPdf = gmm->pdfLocal(gmmFrame.toLocal(wiWorld));
    return bsdfProbability * bsdfPdf + (1.0f - bsdfProbability) * gmmPdf;
}

std::optional<GuidedSample> GuidedBsdfSampler::sample(float uStrategy, float uLobe, const Vec2& uDir) const {
    if (uStrategy < bsdfProbability) {
        const std::optional<BsdfSample> bs = bsdf->sample(wo, at, uLobe, uDir, TransportMode::Radiance);
        if (!bs || bs->pdf <= 0.0f || isBlack(bs->weight)) return std::nullopt;
        const Vec3 wiWorld = shading.toWorld(bs->wi);
        const float gmmPdf = gmm->pdfLocal(gmmFrame.toLocal(wiWorld));
        return GuidedSample{bs->wi, wiWorld, bsdfProbability * bs->pdf + (1.0f - bsdfProbability) * gmmPdf};
    }
    const Vec2 square = gmm->samplePlane(uLobe, uDir);
    // The GMM's mass outside the square (§4.1).
    if (!(square.x >= 0.0f && square.x <= 1.0f && square.y >= 0.0f && square.y <= 1.0f)) return std::nullopt;
    const Vec3 wiWorld = gmmFrame.toWorld(squareToHemisphere(square));
    const Vec3 wi = shading.toLocal(wiWorld);
    const float gmmPdf = gmm->pdfSquare(square) * (1.0f / kSquareToHemisphereJacobian);
    return GuidedSample{wi, wiWorld, bsdfProbability * bsdf->pdf(wo, wi, at) + (1.0f - bsdfProbability) * gmmPdf};
}

}  // namespace fg
