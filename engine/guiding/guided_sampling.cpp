// One-sample mixture of BSDF and GMM sampling, Vorba et al. 2014 §4.1.
#include "engine/guiding/guided_sampling.h"

namespace fg {

float GuidedBsdfSampler::pdf(const Vec3& wiLocal) const {
    const float bsdfPdf = bsdf->pdf(wo, wiLocal, at);
    const float gmmPdf = gmm->pdfLocal(gmmFrame.toLocal(shading.toWorld(wiLocal)));
    return bsdfProbability * bsdfPdf + (1.0f - bsdfProbability) * gmmPdf;
}

std::optional<GuidedSample> GuidedBsdfSampler::sample(float uStrategy, float uLobe, const Vec2& uDir) const {
    if (uStrategy < bsdfProbability) {
        const std::optional<BsdfSample> bs = bsdf->sample(wo, at, uLobe, uDir, TransportMode::Radiance);
        if (!bs || bs->pdf <= 0.0f || isBlack(bs->weight)) return std::nullopt;
        const float gmmPdf = gmm->pdfLocal(gmmFrame.toLocal(shading.toWorld(bs->wi)));
        return GuidedSample{bs->wi, bsdfProbability * bs->pdf + (1.0f - bsdfProbability) * gmmPdf};
    }
    const Vec2 square = gmm->samplePlane(uLobe, uDir);
    // The GMM's mass outside the square (§4.1).
    if (!(square.x >= 0.0f && square.x <= 1.0f && square.y >= 0.0f && square.y <= 1.0f)) return std::nullopt;
    const Vec3 wi = shading.toLocal(gmmFrame.toWorld(squareToHemisphere(square)));
    const float gmmPdf = gmm->pdfSquare(square) / kSquareToHemisphereJacobian;
    return GuidedSample{wi, bsdfProbability * bsdf->pdf(wo, wi, at) + (1.0f - bsdfProbability) * gmmPdf};
}

}  // namespace fg
