// The one-sample mixture of BSDF and GMM sampling at a guided vertex: the
// density that guided path tracing divides by and uses in MIS is the density
// of the directions it actually draws, over the whole sphere (chi²), with the
// GMM's frame tilted against the shading frame so that part of its lobes lies
// below the surface and part of its mass outside the square. And the density
// evaluated at a sampled direction is the one of the square point it came
// from, also for narrow lobes (the inverse map is precise enough), and the
// density sample() returns with a direction is the one pdf() gives for it.
#include "engine/guiding/guided_sampling.h"

#include "engine/shading/texture.h"
#include "jobs/random.h"
#include "tests/support/chi2.h"
#include "tests/support/gmm_fixtures.h"

#include <gtest/gtest.h>

#include <cmath>
#include <vector>

namespace fg {
namespace {

using test::gmmComponent;
using test::gmmMixture;

// Lobes near the square's edge (mass outside it, directions near the record's
// horizon), an anisotropic one and a narrow one.
DirectionalGmm testMixture() {
    return gmmMixture({gmmComponent(0.35f, Vec2(0.95f, 0.5f), 0.01f, 0.0f, 0.02f),
                    gmmComponent(0.25f, Vec2(0.3f, 0.7f), 0.04f, 0.012f, 0.006f),
                    gmmComponent(0.2f, Vec2(0.55f, 0.45f), 0.0004f, 0.0f, 0.0004f),
                    gmmComponent(0.2f, Vec2(0.1f, 0.05f), 0.003f, 0.0f, 0.003f)});
}

void expectMixtureMatchesSampling(const Bsdf& bsdf, const Vec3& woLocal, float alpha, const char* what) {
    const DirectionalGmm gmm = testMixture();
    GuidedBsdfSampler sampler;
    sampler.bsdf = &bsdf;
    sampler.shading = Frame(Vec3(0.0f, 0.0f, 1.0f));
    sampler.wo = glm::normalize(woLocal);
    sampler.at = Vec2(0.3f, 0.6f);
    sampler.gmm = &gmm;
    // The record's normal is tilted by about 50° from the shading normal: a
    // good part of the GMM's directions lies below the surface.
    sampler.gmmFrame = Frame(glm::normalize(Vec3(0.6f, -0.5f, 0.62f)));
    sampler.bsdfProbability = alpha;

    test::Chi2Config config;
    config.samples = 400'000;
    config.testCount = 4;
    config.seed = 11;
    jobs::Rng rng(config.seed, jobs::streamKey("guided-mixture-chi2"), 0);
    std::size_t below = 0, total = 0;
    const test::Chi2Result result = test::chi2SphereTest(
        [&](const Vec2& u) -> std::optional<Vec3> {
            const float uStrategy = rng.uniform();
            const float uLobe = rng.uniform();
            const std::optional<GuidedSample> sampled = sampler.sample(uStrategy, uLobe, u);
            ++total;
            if (!sampled) return std::optional<Vec3>();
            if (sampled->wi.z < 0.0f) ++below;
            return std::optional<Vec3>(sampled->wi);
        },
        [&](const Vec3& w) { return double(sampler.pdf(w)); }, config);
    EXPECT_TRUE(result.passed) << what << ": " << result.message;
    // The test covers what it claims to: samples below the surface occur.
    EXPECT_GT(double(below) / double(total), 0.03) << what;
}

TEST(GuidedSampling, Chi2DiffuseMixtureOverSphere) {
    const auto bsdf = makeDiffuse(makeConstantTexture(Rgb(0.7f)));
    expectMixtureMatchesSampling(*bsdf, Vec3(0.3f, 0.2f, 0.9f), 0.5f, "diffuse, alpha 0.5");
}

TEST(GuidedSampling, Chi2MostlyGmmMixtureOverSphere) {
    const auto bsdf = makeDiffuse(makeConstantTexture(Rgb(0.7f)));
    expectMixtureMatchesSampling(*bsdf, Vec3(-0.5f, 0.1f, 0.4f), 0.1f, "diffuse, alpha 0.1");
}

TEST(GuidedSampling, Chi2RoughConductorMixtureOverSphere) {
    const auto bsdf = makeRoughConductor(*conductorPreset("Au"), 0.3f);
    expectMixtureMatchesSampling(*bsdf, Vec3(0.4f, -0.3f, 0.8f), 0.5f, "rough conductor, alpha 0.5");
}

TEST(GuidedSampling, Chi2RoughPlasticMixtureOverSphere) {
    const auto bsdf = makeRoughPlastic(makeConstantTexture(Rgb(0.4f)), 1.5f, 0.1f, MicrofacetType::Ggx);
    expectMixtureMatchesSampling(*bsdf, Vec3(0.1f, 0.5f, 0.6f), 0.5f, "rough plastic, alpha 0.5");
}

// The path divides by the density sample() returns and weighs next-event
// estimation with pdf(): the two must be the same function, for either
// strategy, or MIS would no longer sum to one. They differ only by the
// rounding of the direction's return trip to the square, which the narrow
// lobe of testMixture() magnifies most.
TEST(GuidedSampling, SampledPdfMatchesPdf) {
    const auto diffuse = makeDiffuse(makeConstantTexture(Rgb(0.7f)));
    const auto conductor = makeRoughConductor(*conductorPreset("Au"), 0.3f);
    const DirectionalGmm gmm = testMixture();
    for (const Bsdf* bsdf : {diffuse.get(), conductor.get()}) {
        GuidedBsdfSampler sampler;
        sampler.bsdf = bsdf;
        sampler.shading = Frame(Vec3(0.0f, 0.0f, 1.0f));
        sampler.wo = glm::normalize(Vec3(0.4f, -0.3f, 0.8f));
        sampler.at = Vec2(0.3f, 0.6f);
        sampler.gmm = &gmm;
        sampler.gmmFrame = Frame(glm::normalize(Vec3(0.3f, -0.2f, 0.9f)));
        sampler.bsdfProbability = 0.5f;
        jobs::Rng rng(7, jobs::streamKey("guided-sampled-pdf"), 0);
        int fromBsdf = 0, fromGmm = 0;
        double worst = 0.0;
        for (int k = 0; k < 20'000; ++k) {
            const float uStrategy = rng.uniform();
            const float uLobe = rng.uniform();
            const std::optional<GuidedSample> sampled = sampler.sample(uStrategy, uLobe, rng.uniform2());
            if (!sampled) continue;
            ++(uStrategy < sampler.bsdfProbability ? fromBsdf : fromGmm);
            const double expected = sampler.pdf(sampled->wi);
            ASSERT_GT(expected, 0.0);
            worst = std::max(worst, std::abs(double(sampled->pdf) / expected - 1.0));
        }
        EXPECT_GT(fromBsdf, 5000);
        EXPECT_GT(fromGmm, 5000);
        EXPECT_LT(worst, 1e-3);
    }
}

// pdf_ω at the sampled direction equals pdf_s / 2π at the sampled point of the
// square: the inverse map sends the direction back to (almost) that point. For
// lobes a few thousandths wide, as many particles from one direction give them
// (the prior's b/n), an error of 1e-4 on the square would change the density by
// tens of percent; the relative error is held to 1e-2 at the lobe's core.
TEST(GuidedSampling, PdfAtSampledDirectionMatchesSquareDensity) {
    jobs::Rng rng(5, jobs::streamKey("guided-narrow-lobes"), 0);
    double worst = 0.0;
    int tested = 0;
    for (int lobe = 0; lobe < 64; ++lobe) {
        const Vec2 mean(0.02f + 0.96f * rng.uniform(), 0.02f + 0.96f * rng.uniform());
        const float sigma = 0.002f;
        const DirectionalGmm gmm = gmmMixture({gmmComponent(1.0f, mean, sigma * sigma, 0.0f, sigma * sigma)});
        for (int k = 0; k < 200; ++k) {
            const Vec2 s = gmm.samplePlane(rng.uniform(), rng.uniform2());
            if (!(s.x >= 0.0f && s.x <= 1.0f && s.y >= 0.0f && s.y <= 1.0f)) continue;
            // The core of the lobe: within 2 sigma, where the density is large enough to matter.
            if (glm::length(s - mean) > 2.0f * sigma) continue;
            const double expected = gmm.pdfSquare(s) / kSquareToHemisphereJacobian;
            const double actual = gmm.pdfLocal(squareToHemisphere(s));
            worst = std::max(worst, std::abs(actual / expected - 1.0));
            ++tested;
        }
    }
    EXPECT_GT(tested, 5000);
    EXPECT_LT(worst, 1e-2);
}

}  // namespace
}  // namespace fg
