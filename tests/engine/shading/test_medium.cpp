#include "engine/shading/medium.h"

#include "jobs/random.h"
#include "tests/support/chi2.h"

#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <functional>
#include <limits>

namespace fg {
namespace {

// Closed-form Henyey-Greenstein density written out independently of the engine.
double hgReference(double g, double cosTheta) {
    const double denom = 1.0 + g * g - 2.0 * g * cosTheta;
    return (1.0 - g * g) / (4.0 * M_PI * denom * std::sqrt(denom));
}

const std::array<float, 4> kAsymmetries{-0.7f, 0.0f, 0.3f, 0.9f};

TEST(HenyeyGreenstein, EvalMatchesClosedFormAndForwardConvention) {
    const Vec3 wo = glm::normalize(Vec3(0.2f, -0.4f, 0.9f));
    for (float g : kAsymmetries) {
        const HenyeyGreenstein phase(g);
        for (float c : {-1.0f, -0.5f, 0.0f, 0.4f, 0.95f}) {
            const Frame frame(-wo);
            const Vec3 wi = frame.toWorld(Vec3(std::sqrt(1.0f - c * c), 0.0f, c));
            EXPECT_NEAR(phase.eval(wo, wi), hgReference(g, c), 1e-4 * hgReference(g, c)) << "g=" << g << " cos=" << c;
        }
    }
    // g > 0 favours continuing along the propagation direction -wo.
    const HenyeyGreenstein forward(0.6f);
    EXPECT_GT(forward.eval(wo, -wo), forward.eval(wo, wo));
}

TEST(HenyeyGreenstein, SamplingMatchesDensityChi2) {
    const Vec3 wo = glm::normalize(Vec3(0.7f, -0.3f, 0.5f));
    for (float g : kAsymmetries) {
        const HenyeyGreenstein phase(g);
        test::Chi2Config config;
        config.testCount = static_cast<int>(kAsymmetries.size());
        config.samples = 500'000;
        const auto result = test::chi2SphereTest(
            [&](const Vec2& u) -> std::optional<Vec3> { return phase.sample(wo, u).wi; },
            [&](const Vec3& w) { return static_cast<double>(phase.eval(wo, w)); }, config);
        EXPECT_TRUE(result.passed) << "g = " << g << ": " << result.message;
    }
}

TEST(HenyeyGreenstein, SamplePdfEqualsEvalAndMeanCosineIsG) {
    const Vec3 wo = glm::normalize(Vec3(-0.1f, 0.8f, 0.3f));
    for (float g : kAsymmetries) {
        const HenyeyGreenstein phase(g);
        jobs::Rng rng(7, jobs::streamKey("hg-moments"), static_cast<std::uint64_t>(std::abs(g) * 100));
        constexpr int kSamples = 400'000;
        double sumCos = 0.0, sumCos2 = 0.0;
        for (int i = 0; i < kSamples; ++i) {
            const PhaseSample s = phase.sample(wo, rng.uniform2());
            ASSERT_NEAR(glm::length(s.wi), 1.0f, 1e-4f);
            ASSERT_FLOAT_EQ(s.pdf, phase.eval(wo, s.wi));
            const double c = glm::dot(-wo, s.wi);
            sumCos += c;
            sumCos2 += c * c;
        }
        const double mean = sumCos / kSamples;
        const double stdErr = std::sqrt(std::max(0.0, sumCos2 / kSamples - mean * mean) / kSamples);
        EXPECT_NEAR(mean, g, 5.0 * stdErr + 1e-4) << "g = " << g;
    }
}

TEST(HenyeyGreenstein, IntegratesToOne) {
    const Vec3 wo = glm::normalize(Vec3(0.3f, 0.3f, -0.9f));
    for (float g : kAsymmetries) {
        const HenyeyGreenstein phase(g);
        // Monte Carlo over uniform directions, stratified on a grid to tame the peak of g = 0.9.
        constexpr int kGrid = 1000;
        jobs::Rng rng(3, jobs::streamKey("hg-norm"), 0);
        double sum = 0.0;
        for (int i = 0; i < kGrid; ++i)
            for (int j = 0; j < kGrid; ++j) {
                const Vec2 u((static_cast<float>(i) + rng.uniform()) / kGrid,
                             (static_cast<float>(j) + rng.uniform()) / kGrid);
                sum += phase.eval(wo, sampleUniformSphere(u)) / uniformSpherePdf();
            }
        EXPECT_NEAR(sum / (kGrid * kGrid), 1.0, 5e-3) << "g = " << g;
    }
}

TEST(HomogeneousMedium, TransmittanceHandlesZeroAndInfinity) {
    const HomogeneousMedium medium(Rgb(0.5f, 0.0f, 1.0f), Rgb(0.5f, 0.0f, 0.0f), 0.0f);
    const Rgb tr = medium.transmittance(2.0f);
    EXPECT_NEAR(tr.x, std::exp(-2.0f), 1e-6f);
    EXPECT_EQ(tr.y, 1.0f);
    EXPECT_NEAR(tr.z, std::exp(-2.0f), 1e-6f);
    const Rgb far = medium.transmittance(std::numeric_limits<float>::infinity());
    EXPECT_EQ(far.x, 0.0f);
    EXPECT_EQ(far.y, 1.0f);
    EXPECT_EQ(far.z, 0.0f);
    EXPECT_EQ(medium.transmittance(0.0f), Rgb(1.0f));
}

struct Moments {
    Rgb mean{0.0f};
    Rgb stdErr{0.0f};
};

// Mean and standard error of f(sample) over n samples of the medium's free-flight sampling.
Moments estimate(const HomogeneousMedium& medium, float tMax, const Rgb& throughput, int n,
                 const std::function<Rgb(const DistanceSample&)>& f) {
    jobs::Rng rng(11, jobs::streamKey("free-flight"), 0);
    glm::dvec3 sum(0.0), sum2(0.0);
    for (int i = 0; i < n; ++i) {
        const float uChannel = rng.uniform();
        const DistanceSample s = medium.sampleDistance(tMax, uChannel, rng.uniform(), throughput);
        const glm::dvec3 v(f(s));
        sum += v;
        sum2 += v * v;
    }
    const glm::dvec3 mean = sum / static_cast<double>(n);
    const glm::dvec3 var = glm::max(sum2 / static_cast<double>(n) - mean * mean, glm::dvec3(0.0));
    return {Rgb(mean), Rgb(glm::sqrt(var / static_cast<double>(n)))};
}

// Integral of sigma_s Tr(t) g(t) over [0, tMax] for one channel, by Simpson's rule.
double scatteredIntegral(double sigmaS, double sigmaT, double tMax, const std::function<double(double)>& g) {
    constexpr int kSteps = 20000;
    const double h = tMax / kSteps;
    double sum = 0.0;
    for (int i = 0; i <= kSteps; ++i) {
        const double t = i * h;
        const double w = (i == 0 || i == kSteps) ? 1.0 : (i % 2 ? 4.0 : 2.0);
        sum += w * sigmaS * std::exp(-sigmaT * t) * g(t);
    }
    return sum * h / 3.0;
}

void expectWithin(const Moments& m, const Rgb& expected, const char* what) {
    for (int c = 0; c < 3; ++c) {
        EXPECT_NEAR(m.mean[c], expected[c], 5.0f * m.stdErr[c] + 1e-4f * (1.0f + std::abs(expected[c])))
            << what << ", channel " << c << " (std. error " << m.stdErr[c] << ")";
    }
}

TEST(HomogeneousMedium, ChromaticDistanceSamplingIsUnbiased) {
    // Three very different channels, one of them without any extinction at all.
    const Rgb sigmaA(0.1f, 0.8f, 0.0f), sigmaS(1.5f, 0.2f, 0.0f);
    const HomogeneousMedium medium(sigmaA, sigmaS, 0.3f);
    const Rgb sigmaT = sigmaA + sigmaS;
    const float tMax = 1.7f;
    const auto g = [](double t) { return 1.0 + std::cos(3.0 * t) + t * t; };
    constexpr int kSamples = 600'000;

    for (const Rgb& throughput : {Rgb(1.0f, 0.3f, 0.5f), Rgb(0.0f), Rgb(0.0f, 1.0f, 0.0f), Rgb(0.2f, 0.0f, 2.0f)}) {
        const Moments scattered = estimate(medium, tMax, throughput, kSamples, [&](const DistanceSample& s) {
            if (!s.scattered) return Rgb(0.0f);
            EXPECT_LT(s.t, tMax);
            EXPECT_GE(s.t, 0.0f);
            return s.weight * static_cast<float>(g(s.t));
        });
        Rgb expectedScattered;
        for (int c = 0; c < 3; ++c)
            expectedScattered[c] = static_cast<float>(scatteredIntegral(sigmaS[c], sigmaT[c], tMax, g));
        expectWithin(scattered, expectedScattered, "scattering");

        const Moments passed = estimate(medium, tMax, throughput, kSamples, [&](const DistanceSample& s) {
            if (s.scattered) return Rgb(0.0f);
            EXPECT_EQ(s.t, tMax);
            return s.weight;
        });
        Rgb expectedPassed;
        for (int c = 0; c < 3; ++c) expectedPassed[c] = std::exp(-sigmaT[c] * tMax);
        expectWithin(passed, expectedPassed, "transmission");
    }
}

TEST(HomogeneousMedium, InfiniteSegmentOnlyPassesThroughClearChannels) {
    const Rgb sigmaA(0.3f, 0.0f, 0.0f), sigmaS(0.6f, 2.0f, 0.0f);
    const HomogeneousMedium medium(sigmaA, sigmaS, 0.0f);
    const Rgb sigmaT = sigmaA + sigmaS;
    const float tMax = std::numeric_limits<float>::infinity();
    const auto g = [](double t) { return std::exp(-t); };
    constexpr int kSamples = 400'000;
    const Rgb throughput(1.0f, 1.0f, 1.0f);

    const Moments scattered = estimate(medium, tMax, throughput, kSamples, [&](const DistanceSample& s) {
        EXPECT_TRUE(isFinite(s.weight));
        return s.scattered ? s.weight * static_cast<float>(g(s.t)) : Rgb(0.0f);
    });
    // integral_0^inf sigma_s exp(-sigma_t t) exp(-t) dt = sigma_s / (sigma_t + 1)
    expectWithin(scattered, sigmaS / (sigmaT + Rgb(1.0f)), "scattering");

    const Moments passed = estimate(medium, tMax, throughput, kSamples,
                                    [&](const DistanceSample& s) { return s.scattered ? Rgb(0.0f) : s.weight; });
    expectWithin(passed, Rgb(0.0f, 0.0f, 1.0f), "transmission");
}

TEST(HomogeneousMedium, GreyMediumGivesAlbedoWeights) {
    // Equal extinction in every channel but chromatic albedo: the classic sigma_s / sigma_t weight.
    const HomogeneousMedium grey(Rgb(0.5f, 0.25f, 0.75f), Rgb(0.5f, 0.75f, 0.25f), 0.0f);
    jobs::Rng rng(5, jobs::streamKey("grey"), 0);
    int scatteredCount = 0;
    for (int i = 0; i < 1000; ++i) {
        const DistanceSample s = grey.sampleDistance(3.0f, rng.uniform(), rng.uniform(), Rgb(1.0f, 0.2f, 0.1f));
        if (s.scattered) {
            ++scatteredCount;
            EXPECT_NEAR(s.weight.x, 0.5f, 1e-4f);
            EXPECT_NEAR(s.weight.y, 0.75f, 1e-4f);
            EXPECT_NEAR(s.weight.z, 0.25f, 1e-4f);
        } else {
            EXPECT_NEAR(s.weight.x, 1.0f, 1e-4f);
        }
    }
    EXPECT_GT(scatteredCount, 900);  // P(scatter) = 1 - e^-3 = 0.95
}

// Free-flight densities of a segment for MIS weights: the densities along a
// segment of several media, from either end, with the channels averaged.
TEST(FreeFlightSegment, DensitiesFromEitherEndOverSeveralMedia) {
    const HomogeneousMedium fog(Rgb(0.1f), Rgb(0.4f), 0.0f);
    const HomogeneousMedium dense(Rgb(0.5f, 2.0f, 0.1f), Rgb(3.0f, 6.0f, 1.0f), 0.0f);
    const float passDense = (std::exp(-3.5f * 0.4f) + std::exp(-8.0f * 0.4f) + std::exp(-1.1f * 0.4f)) / 3.0f;
    FreeFlightSegment segment;
    EXPECT_EQ(segment.towardEnd(true), 1.0f);  // no medium: nothing to sample
    segment.add(fog, 1.0f);
    segment.add(dense, 0.4f);
    segment.add(fog, 0.7f);
    EXPECT_NEAR(segment.towardEnd(true), std::exp(-0.5f) * passDense * 0.5f * std::exp(-0.35f), 1e-6f);
    EXPECT_NEAR(segment.towardStart(true), 0.5f * std::exp(-0.5f) * passDense * std::exp(-0.35f), 1e-6f);
    EXPECT_NEAR(segment.towardEnd(false), std::exp(-0.85f) * passDense, 1e-6f);
    EXPECT_NEAR(segment.towardStart(false), segment.towardEnd(false), 1e-7f);

    FreeFlightSegment shortened, whole;
    shortened.add(fog, 1.0f);
    shortened.extendEnd(0.5f);
    whole.add(fog, 1.5f);
    EXPECT_EQ(shortened.towardEnd(true), whole.towardEnd(true));
}

TEST(FreeFlightSegment, GreyMediumMatchesTheSamplersDensity) {
    // In a grey medium the channel choice does not matter: the density the
    // sampler divides by, sigma_s T / weight, is the segment's sigma_t T.
    const HomogeneousMedium grey(Rgb(0.2f), Rgb(0.6f), 0.0f);
    jobs::Rng rng(9, jobs::streamKey("segment"), 0);
    int checked = 0;
    for (int i = 0; i < 200; ++i) {
        const DistanceSample s = grey.sampleDistance(4.0f, rng.uniform(), rng.uniform(), Rgb(1.0f, 0.3f, 0.05f));
        if (!s.scattered) continue;
        FreeFlightSegment segment;
        segment.add(grey, s.t);
        const float samplerPdf = 0.6f * std::exp(-0.8f * s.t) / s.weight.x;
        EXPECT_NEAR(segment.towardEnd(true), samplerPdf, 1e-5f * samplerPdf);
        ++checked;
    }
    EXPECT_GT(checked, 150);
}

}  // namespace
}  // namespace fg
