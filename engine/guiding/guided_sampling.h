// Direction sampling at a guided surface vertex (Vorba et al. 2014, §4.1
// "Sampling from the distribution model"): a one-sample mixture that draws the
// BSDF's sampling routine with probability α and the record's GMM otherwise.
// Its density over all directions is
//   p(ω) = α p_bsdf(ω) + (1 - α) p_gmm(ω),
// p_gmm being the GMM's density on the record's hemisphere (zero below it).
// The GMM's mass outside its square, and GMM directions below the shading
// hemisphere, are samples that end the path: they lower the mixture's total
// mass but not its density anywhere else, so dividing by p(ω) stays unbiased,
// and p(ω) is also the pdf the strategy has in MIS against next-event
// estimation. Both are computed here, so that the two cannot drift apart.
// sample() returns p(ω) with the direction: the strategy that drew it already
// holds half of it (the BSDF's pdf, or the GMM's square point, whose density
// needs no return trip through the frames and the inverse map), so the path
// does not evaluate the mixture a second time. draw() and drawnPdf() are its
// two halves, for a path that ends some directions before it needs p(ω): a
// direction the BSDF does not scatter into (a GMM direction below the surface
// of a BSDF that only reflects) or one the shading normal would let through
// the geometric surface ends the path whatever p(ω) is, and p(ω) — the GMM's
// density and, for a GMM direction, the BSDF's pdf — is most of a guided
// vertex's sampling cost.
#pragma once

#include "engine/core/math.h"
#include "engine/guiding/directional_gmm.h"
#include "engine/shading/bsdf.h"

#include <optional>

namespace fg {

struct GuidedSample {
    Vec3 wi{0.0f};   // local to the shading frame
    Vec3 wiWorld{0.0f};  // the same direction in world space
    float pdf = 0.0f;  // mixture density of wi
};

// A direction drawn by one of the two strategies, before its mixture density.
struct GuidedDraw {
    Vec3 wi{0.0f};       // local to the shading frame
    Vec3 wiWorld{0.0f};  // the same direction in world space
    Vec2 square{0.0f};   // the GMM's point for a GMM direction
    float bsdfPdf = 0.0f;  // the BSDF's own pdf for a BSDF direction
    bool fromGmm = false;
};

struct GuidedBsdfSampler {
    const Bsdf* bsdf = nullptr;
    Frame shading;    // the vertex's shading frame: wo and sampled directions are local to it
    Vec3 wo{0.0f, 0.0f, 1.0f};
    TexturePoint at{Vec2(0.0f)};
    const DirectionalGmm* gmm = nullptr;
    Frame gmmFrame;   // the record's frame: its normal is the GMM hemisphere's pole
    float bsdfProbability = 0.5f;  // α

    // Mixture density of a direction local to the shading frame.
    float pdf(const Vec3& wiLocal) const;
    // The same for a caller that holds the direction in both frames (next-event
    // estimation draws it in world space): no round trip through the shading frame.
    float pdf(const Vec3& wiLocal, const Vec3& wiWorld) const;
    // A direction local to the shading frame and its mixture density, or nothing
    // when the chosen strategy fails (the BSDF gives no sample, the GMM point
    // falls outside its square). The density agrees with pdf() up to rounding.
    std::optional<GuidedSample> sample(float uStrategy, float uLobe, const Vec2& uDir) const;
    // sample() in two steps: the direction (nothing where sample() gives
    // nothing), then its mixture density, the same value sample() returns.
    std::optional<GuidedDraw> draw(float uStrategy, float uLobe, const Vec2& uDir) const;
    float drawnPdf(const GuidedDraw& drawn) const;
    // sample() as a BSDF sample of `mode` transport, for walks that take any
    // BSDF's samples: weight f |cos| / p_mix, pdf p_mix; nothing where sample()
    // gives nothing or f vanishes. Only reflection lobes are guided, for which
    // the BSDF half's draws (made in radiance transport) are those of either
    // transport.
    std::optional<BsdfSample> sampleAsBsdf(float uStrategy, float uLobe, const Vec2& uDir, TransportMode mode) const;
};

}  // namespace fg
