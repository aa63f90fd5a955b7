// One-sample mixture of BSDF and GMM sampling, Vorba et al. 2014 §4.1.
#include "engine/guiding/guided_sampling.h"

namespace fg {

float GuidedBsdfSampler::pdf(const Vec3& wiLocal) const {
    const float bsdfPdf = bsdf->pdf(wo, wiLocal, at);
    const float gmmPdf = gmm->pdfLocal(gmmFrame.toLocal(shading.toWorld(wiLocal)));
    return bsdfProbability * bsdfPdf + (1.0f - bsdfProbability) * gmmPdf;
}

std::optional<Vec3> GuidedBsdfSampler::sample(float uStrategy, float uLobe, const Vec2& uDir) const {
    if (uStrategy < bsdfProbability) {
        const std::optional<BsdfSample> bs = bsdf->sample(wo, at, uLobe, uDir, TransportMode::Radiance);
        if (!bs || bs->pdf <= 0.0f || isBlack(bs->weight)) return std::nullopt;
        return bs->wi;
    }
    const std::optional<Vec3> sampled = gmm->sampleLocal(uLobe, uDir);
    if (!sampled) return std::nullopt;  // the GMM's mass outside the square (§4.1)
    return shading.toLocal(gmmFrame.toWorld(*sampled));
}

}  // namespace fg
