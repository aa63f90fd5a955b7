// The principled BSDF: sampling against its own pdf (chi-square) for each lobe
// and from inside, the pdf's total mass, white-furnace albedo without
// transmission, and two limits with closed forms: a pure metal is a GGX
// microfacet lobe with Schlick's Fresnel towards base_color, and a white
// surface without specular reflection is Burley's diffuse lobe. The thin
// variant: chi-square from both sides, symmetry and energy.
#include "engine/shading/principled.h"

#include "engine/shading/microfacet.h"
#include "jobs/random.h"
#include "tests/engine/shading/bsdf_test_util.h"
#include "tests/support/chi2.h"

#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <ostream>
#include <string>
#include <vector>

namespace fg {
namespace {

std::shared_ptr<Texture> constant(float value) { return makeConstantTexture(Rgb(value)); }

struct PrincipledCase {
    std::string name;
    std::function<PrincipledParameters()> parameters;
    Vec3 wo;
    int thetaBins = 20;
};

void PrintTo(const PrincipledCase& c, std::ostream* os) { *os << c.name; }

PrincipledParameters diffuseOnly() {
    PrincipledParameters p;
    p.baseColor = makeConstantTexture(Rgb(0.8f, 0.5f, 0.3f));
    p.roughness = constant(0.7f);
    p.eta = principledEtaFromSpecular(0.0f);
    return p;
}

PrincipledParameters plasticLike() {
    PrincipledParameters p;
    p.baseColor = makeConstantTexture(Rgb(0.6f, 0.4f, 0.2f));
    p.roughness = constant(0.4f);
    p.sheen = constant(0.5f);
    p.sheenTint = constant(0.5f);
    p.specTint = constant(0.3f);
    return p;
}

PrincipledParameters metal(float roughness) {
    PrincipledParameters p;
    p.baseColor = makeConstantTexture(Rgb(0.9f, 0.6f, 0.3f));
    p.roughness = constant(roughness);
    p.metallic = constant(1.0f);
    return p;
}

PrincipledParameters anisotropicMetal() {
    PrincipledParameters p = metal(0.5f);
    p.metallic = constant(0.8f);
    p.anisotropic = constant(0.8f);
    return p;
}

PrincipledParameters clearcoated() {
    PrincipledParameters p;
    p.baseColor = makeConstantTexture(Rgb(0.2f, 0.3f, 0.7f));
    p.roughness = constant(0.6f);
    p.clearcoat = constant(1.0f);
    p.clearcoatGloss = constant(0.3f);
    return p;
}

PrincipledParameters transmissive() {
    PrincipledParameters p;
    p.baseColor = makeConstantTexture(Rgb(0.9f));
    p.roughness = constant(0.6f);
    p.specTrans = constant(0.7f);
    p.eta = 1.5f;
    return p;
}

Vec3 below(Vec3 w) {
    w.z = -w.z;
    return w;
}

std::vector<PrincipledCase> chi2Cases() {
    using test::directionFromAngles;
    return {
        {"DiffuseOnly_20deg", diffuseOnly, directionFromAngles(20.0f, 30.0f)},
        {"DiffuseOnly_75deg", diffuseOnly, directionFromAngles(75.0f, 30.0f)},
        {"SheenSpecTint_45deg", plasticLike, directionFromAngles(45.0f, 120.0f)},
        {"Metallic_r30_10deg", [] { return metal(0.3f); }, directionFromAngles(10.0f, 40.0f), 40},
        {"Metallic_r30_70deg", [] { return metal(0.3f); }, directionFromAngles(70.0f, 40.0f), 40},
        {"Anisotropic_30deg", anisotropicMetal, directionFromAngles(30.0f, 60.0f)},
        {"Anisotropic_80deg", anisotropicMetal, directionFromAngles(80.0f, 10.0f)},
        {"Clearcoat_15deg", clearcoated, directionFromAngles(15.0f, 200.0f), 40},
        {"Clearcoat_60deg", clearcoated, directionFromAngles(60.0f, 200.0f), 40},
        {"SpecTrans_30deg", transmissive, directionFromAngles(30.0f, -60.0f)},
        {"SpecTrans_70deg", transmissive, directionFromAngles(70.0f, -60.0f)},
        {"SpecTrans_inside_25deg", transmissive, below(directionFromAngles(25.0f, 80.0f))},
        {"SpecTrans_inside_60deg", transmissive, below(directionFromAngles(60.0f, 80.0f))},
    };
}

const int kChi2TestCount = static_cast<int>(chi2Cases().size());

class PrincipledChi2 : public ::testing::TestWithParam<PrincipledCase> {};

TEST_P(PrincipledChi2, SampleMatchesPdf) {
    const PrincipledCase& c = GetParam();
    const std::shared_ptr<Bsdf> bsdf = makePrincipled(c.parameters());
    const Vec3 wo = glm::normalize(c.wo);
    const Vec2 uv(0.5f);

    test::Chi2Config config;
    config.thetaBins = c.thetaBins;
    config.phiBins = 2 * c.thetaBins;
    config.samples = 500'000;
    config.testCount = kChi2TestCount;
    config.seed = std::hash<std::string>{}(c.name);

    jobs::Rng lobeRng(config.seed, jobs::streamKey("principled-chi2-lobe"), 0);
    const test::DirectionSampler sampler = [&](const Vec2& u) -> std::optional<Vec3> {
        const std::optional<BsdfSample> s = bsdf->sample(wo, uv, lobeRng.uniform(), u, TransportMode::Radiance);
        if (!s) return std::nullopt;
        return s->wi;
    };
    const test::DirectionPdf density = [&](const Vec3& wi) { return static_cast<double>(bsdf->pdf(wo, wi, uv)); };
    const test::Chi2Result result = test::chi2SphereTest(sampler, density, config);
    EXPECT_TRUE(result.passed) << c.name << ": " << result.message;
}

INSTANTIATE_TEST_SUITE_P(Principled, PrincipledChi2, ::testing::ValuesIn(chi2Cases()),
                         [](const ::testing::TestParamInfo<PrincipledCase>& param) { return param.param.name; });

// The harness must notice a sampler that disagrees with the pdf: a clearcoat
// sampled with one gloss and claimed with another.
TEST(PrincipledChi2Sanity, DetectsMismatchedClearcoatGloss) {
    PrincipledParameters sampledParameters = clearcoated();
    PrincipledParameters claimedParameters = clearcoated();
    claimedParameters.clearcoatGloss = constant(0.6f);
    const auto sampled = makePrincipled(sampledParameters);
    const auto claimed = makePrincipled(claimedParameters);
    const Vec3 wo = test::directionFromAngles(30.0f, 0.0f);
    test::Chi2Config config;
    config.thetaBins = 40;
    config.phiBins = 80;
    config.samples = 500'000;
    jobs::Rng lobeRng(config.seed, jobs::streamKey("principled-chi2-lobe"), 0);
    const test::Chi2Result result = test::chi2SphereTest(
        [&](const Vec2& u) -> std::optional<Vec3> {
            const auto s = sampled->sample(wo, Vec2(0.5f), lobeRng.uniform(), u, TransportMode::Radiance);
            return s ? std::optional<Vec3>(s->wi) : std::nullopt;
        },
        [&](const Vec3& wi) { return static_cast<double>(claimed->pdf(wo, wi, Vec2(0.5f))); }, config);
    EXPECT_FALSE(result.passed) << result.message;
}

// Integral of pdf(wo, .) over the sphere by the midpoint rule in (cos(theta), phi).
double pdfMass(const Bsdf& bsdf, const Vec3& wo) {
    constexpr int kCosSteps = 1024, kPhiSteps = 512;
    double sum = 0.0;
    for (int i = 0; i < kCosSteps; ++i) {
        const double z = -1.0 + 2.0 * (i + 0.5) / kCosSteps;
        const double r = std::sqrt(std::max(0.0, 1.0 - z * z));
        for (int j = 0; j < kPhiSteps; ++j) {
            const double phi = 2.0 * M_PI * (j + 0.5) / kPhiSteps;
            const Vec3 wi(static_cast<float>(r * std::cos(phi)), static_cast<float>(r * std::sin(phi)),
                          static_cast<float>(z));
            sum += bsdf.pdf(wo, wi, Vec2(0.5f));
        }
    }
    return sum * (2.0 / kCosSteps) * (2.0 * M_PI / kPhiSteps);
}

TEST(Principled, PdfIntegratesToAtMostOne) {
    const std::vector<std::pair<std::string, PrincipledParameters>> settings = {
        {"diffuse", diffuseOnly()}, {"clearcoat", clearcoated()}, {"anisotropic", anisotropicMetal()},
        {"transmissive", transmissive()}};
    for (const auto& [name, parameters] : settings) {
        const auto bsdf = makePrincipled(parameters);
        for (float angle : {0.0f, 40.0f, 80.0f}) {
            const Vec3 wo = test::directionFromAngles(angle, 25.0f);
            const double mass = pdfMass(*bsdf, wo);
            EXPECT_LE(mass, 1.0 + 2e-3) << name << " at " << angle;
            // Only microfacet samples leaving on the wrong side are lost.
            EXPECT_GT(mass, 0.8) << name << " at " << angle;
        }
    }
}

// White furnace. Without a dielectric specular lobe (specular 0) or as a
// metal, no setting reflects more than it receives. Burley's model adds the
// dielectric specular to a diffuse lobe that it does not attenuate, so a white
// dielectric base reflects more (as in Mitsuba): at most about the specular
// lobe's albedo, the Fresnel reflectance (plus a margin for the clearcoat). Sampling and quadrature agree where
// the quadrature resolves the lobes (below grazing incidence).
TEST(Principled, WhiteFurnaceAlbedo) {
    struct Setting {
        std::string name;
        PrincipledParameters parameters;
        bool addsDielectricSpecular;
    };
    std::vector<Setting> settings;
    PrincipledParameters white = diffuseOnly();
    white.baseColor = constant(1.0f);
    white.roughness = constant(0.3f);
    settings.push_back({"diffuse_r30", white, false});
    PrincipledParameters whiteSheen = white;
    whiteSheen.sheen = constant(1.0f);
    whiteSheen.roughness = constant(0.0f);
    settings.push_back({"diffuse_sheen_r0", whiteSheen, false});
    PrincipledParameters whiteMetal = metal(0.5f);
    whiteMetal.baseColor = constant(1.0f);
    settings.push_back({"metal_r50", whiteMetal, false});
    PrincipledParameters whiteAnisotropic = anisotropicMetal();
    whiteAnisotropic.baseColor = constant(1.0f);
    whiteAnisotropic.metallic = constant(1.0f);
    settings.push_back({"anisotropic_metal", whiteAnisotropic, false});
    PrincipledParameters whitePlastic = plasticLike();
    whitePlastic.baseColor = constant(1.0f);
    whitePlastic.roughness = constant(0.2f);
    settings.push_back({"dielectric_sheen_spec_tint", whitePlastic, true});
    PrincipledParameters whiteClearcoat = clearcoated();
    whiteClearcoat.baseColor = constant(1.0f);
    whiteClearcoat.roughness = constant(0.2f);
    settings.push_back({"dielectric_clearcoat", whiteClearcoat, true});
    for (const Setting& setting : settings) {
        const auto bsdf = makePrincipled(setting.parameters);
        for (float angle : {0.0f, 30.0f, 60.0f, 85.0f}) {
            const Vec3 wo = test::directionFromAngles(angle, 10.0f);
            const float bound =
                setting.addsDielectricSpecular ? 1.05f + fresnelDielectric(wo.z, setting.parameters.eta) : 1.0f;
            const test::AlbedoEstimate sampled =
                test::albedoBySampling(*bsdf, wo, TransportMode::Radiance, 200'000, 7);
            const Rgb quadrature = test::albedoByQuadrature(*bsdf, wo, TransportMode::Radiance, 512, 256);
            for (int c = 0; c < 3; ++c) {
                EXPECT_LE(sampled.mean[c], bound + 4.0f * sampled.standardError[c] + 1e-3f)
                    << setting.name << " at " << angle;
                if (angle > 60.0f) continue;
                EXPECT_LE(quadrature[c], bound + 5e-3f) << setting.name << " at " << angle;
                EXPECT_NEAR(sampled.mean[c], quadrature[c], 4.0f * sampled.standardError[c] + 1e-2f)
                    << setting.name << " at " << angle;
            }
        }
    }
}

// metallic = 1 without the other lobes: D G F / (4 cos_o) cos_i with GGX of
// alpha = roughness^2 and Schlick's F = F0 + (1 - F0)(1 - cos_d)^5, F0 = base_color.
TEST(Principled, PureMetalIsGgxWithSchlickFresnel) {
    const float roughness = 0.55f;
    const PrincipledParameters parameters = metal(roughness);
    const Rgb f0 = parameters.baseColor->eval(Vec2(0.5f));
    const auto bsdf = makePrincipled(parameters);
    const GgxDistribution ggx(roughness * roughness);
    jobs::Rng rng(3, jobs::streamKey("principled-metal"), 0);
    for (int i = 0; i < 200; ++i) {
        const Vec3 wo = sampleCosineHemisphere(rng.uniform2());
        const Vec3 wi = sampleCosineHemisphere(rng.uniform2());
        if (wo.z < 1e-3f || wi.z < 1e-3f) continue;
        const Vec3 m = glm::normalize(wo + wi);
        const float weight = std::pow(1.0f - glm::dot(wo, m), 5.0f);
        const Rgb fresnel = f0 + (Rgb(1.0f) - f0) * weight;
        const Rgb expected = fresnel * (ggx.D(m) * ggx.G(wo, wi) / (4.0f * wo.z));
        const Rgb actual = bsdf->eval(wo, wi, Vec2(0.5f), TransportMode::Radiance);
        for (int c = 0; c < 3; ++c) EXPECT_NEAR(actual[c], expected[c], 1e-4f * (1.0f + expected[c])) << i;
        // Nothing below the surface and nothing on the back.
        EXPECT_EQ(bsdf->eval(wo, below(wi), Vec2(0.5f), TransportMode::Radiance), Rgb(0.0f));
        EXPECT_EQ(bsdf->eval(below(wo), below(wi), Vec2(0.5f), TransportMode::Radiance), Rgb(0.0f));
    }
}

// base_color 1, specular 0 (eta 1: no dielectric reflection), roughness 1: the
// value is Lambert's cos_i / pi times Burley's factor (1 - F_o/2)(1 - F_i/2)
// plus the retro-reflection R_R (F_o + F_i + F_o F_i (R_R - 1)), R_R = 2 cos_d^2.
TEST(Principled, WhiteRoughDiffuseIsLambertWithRetroReflection) {
    PrincipledParameters parameters;
    parameters.baseColor = constant(1.0f);
    parameters.roughness = constant(1.0f);
    parameters.eta = principledEtaFromSpecular(0.0f);
    EXPECT_FLOAT_EQ(parameters.eta, 1.0f);
    const auto bsdf = makePrincipled(parameters);
    const auto schlick = [](float c) { return std::pow(1.0f - c, 5.0f); };
    jobs::Rng rng(5, jobs::streamKey("principled-diffuse"), 0);
    for (int i = 0; i < 200; ++i) {
        const Vec3 wo = sampleCosineHemisphere(rng.uniform2());
        const Vec3 wi = sampleCosineHemisphere(rng.uniform2());
        if (wo.z < 1e-3f || wi.z < 1e-3f) continue;
        const float cosD = glm::dot(wi, glm::normalize(wo + wi));
        const float fo = schlick(wo.z), fi = schlick(wi.z), rr = 2.0f * cosD * cosD;
        const float factor = (1.0f - 0.5f * fo) * (1.0f - 0.5f * fi) + rr * (fo + fi + fo * fi * (rr - 1.0f));
        const Rgb actual = bsdf->eval(wo, wi, Vec2(0.5f), TransportMode::Radiance);
        EXPECT_NEAR(actual.x, kInvPi * wi.z * factor, 1e-5f) << i;
    }
    // At normal incidence and exit the Schlick weights vanish: exactly Lambert.
    const Rgb normal = bsdf->eval(Vec3(0, 0, 1), Vec3(0, 0, 1), Vec2(0.5f), TransportMode::Radiance);
    EXPECT_NEAR(normal.x, kInvPi, 1e-6f);
    // Close to Lambert's albedo of 1 overall: within the retro-reflection's gain.
    const Rgb albedo = test::albedoByQuadrature(*bsdf, test::directionFromAngles(30.0f, 0.0f),
                                                TransportMode::Radiance, 512, 256);
    EXPECT_NEAR(albedo.x, 1.0f, 0.1f);
}

TEST(Principled, EtaFromSpecularMatchesSchlickF0) {
    for (float specular : {0.1f, 0.5f, 1.0f}) {
        const float eta = principledEtaFromSpecular(specular);
        const float f0 = (eta - 1.0f) * (eta - 1.0f) / ((eta + 1.0f) * (eta + 1.0f));
        EXPECT_NEAR(f0, 0.08f * specular, 1e-6f);
    }
    EXPECT_NEAR(principledEtaFromSpecular(0.5f), 1.5f, 1e-5f);
}

// Transmission exists only with spec_trans; then the material refracts from
// both sides, with eta on the sample as the rough dielectric's.
TEST(Principled, TransmissionOnlyWithSpecTrans) {
    EXPECT_EQ(makePrincipled(diffuseOnly())->lobes() & BsdfLobe::Transmission, 0u);
    const auto glass = makePrincipled(transmissive());
    EXPECT_NE(glass->lobes() & BsdfLobe::Transmission, 0u);
    const Vec3 wo = test::directionFromAngles(20.0f, 0.0f);
    int refracted = 0;
    jobs::Rng rng(9, jobs::streamKey("principled-trans"), 0);
    for (int i = 0; i < 2000; ++i) {
        const auto s = glass->sample(wo, Vec2(0.5f), rng.uniform(), rng.uniform2(), TransportMode::Radiance);
        if (!s || s->wi.z > 0.0f) continue;
        ++refracted;
        EXPECT_FLOAT_EQ(s->eta, 1.5f);
        EXPECT_NE(s->lobe & BsdfLobe::Transmission, 0u);
    }
    EXPECT_GT(refracted, 500);
    EXPECT_FALSE(makePrincipled(diffuseOnly())->sample(below(wo), Vec2(0.5f), 0.5f, Vec2(0.5f),
                                                       TransportMode::Radiance));
}

// ---------------------------------------------------------------------------
// principledthin

PrincipledThinParameters thinSheet(float specTrans, float diffTrans) {
    PrincipledThinParameters p;
    p.baseColor = makeConstantTexture(Rgb(0.8f, 0.6f, 0.4f));
    p.roughness = constant(0.5f);
    p.eta = constant(1.4f);
    p.sheen = constant(0.3f);
    p.specTint = constant(0.2f);
    if (specTrans > 0.0f) p.specTrans = constant(specTrans);
    if (diffTrans > 0.0f) p.diffTrans = constant(diffTrans);
    return p;
}

struct ThinCase {
    std::string name;
    std::function<PrincipledThinParameters()> parameters;
    Vec3 wo;
    int thetaBins = 20;
};

void PrintTo(const ThinCase& c, std::ostream* os) { *os << c.name; }

std::vector<ThinCase> thinCases() {
    using test::directionFromAngles;
    return {
        {"Diffuse_30deg", [] { return thinSheet(0.0f, 0.0f); }, directionFromAngles(30.0f, 10.0f)},
        {"DiffTrans_50deg", [] { return thinSheet(0.0f, 1.2f); }, directionFromAngles(50.0f, 10.0f)},
        {"SpecTrans_20deg", [] { return thinSheet(0.6f, 0.5f); }, directionFromAngles(20.0f, 80.0f), 40},
        {"SpecTrans_70deg", [] { return thinSheet(0.6f, 0.5f); }, directionFromAngles(70.0f, 80.0f), 40},
        {"SpecTrans_back_40deg", [] { return thinSheet(0.8f, 0.0f); }, below(directionFromAngles(40.0f, 200.0f)), 40},
    };
}

class PrincipledThinChi2 : public ::testing::TestWithParam<ThinCase> {};

TEST_P(PrincipledThinChi2, SampleMatchesPdf) {
    const ThinCase& c = GetParam();
    const std::shared_ptr<Bsdf> bsdf = makePrincipledThin(c.parameters());
    const Vec3 wo = glm::normalize(c.wo);
    test::Chi2Config config;
    // The transmitted lobe's roughness is scaled down (0.28 for roughness 0.5
    // and eta 1.4), so its cells must be finer.
    config.thetaBins = c.thetaBins;
    config.phiBins = 2 * c.thetaBins;
    config.samples = 500'000;
    config.testCount = static_cast<int>(thinCases().size());
    config.seed = std::hash<std::string>{}(c.name);
    jobs::Rng lobeRng(config.seed, jobs::streamKey("principled-thin-chi2-lobe"), 0);
    const test::Chi2Result result = test::chi2SphereTest(
        [&](const Vec2& u) -> std::optional<Vec3> {
            const auto s = bsdf->sample(wo, Vec2(0.5f), lobeRng.uniform(), u, TransportMode::Radiance);
            return s ? std::optional<Vec3>(s->wi) : std::nullopt;
        },
        [&](const Vec3& wi) { return static_cast<double>(bsdf->pdf(wo, wi, Vec2(0.5f))); }, config);
    EXPECT_TRUE(result.passed) << c.name << ": " << result.message;
}

INSTANTIATE_TEST_SUITE_P(PrincipledThin, PrincipledThinChi2, ::testing::ValuesIn(thinCases()),
                         [](const ::testing::TestParamInfo<ThinCase>& param) { return param.param.name; });

// The sheet is the same seen from either side, passes light without bending
// it (eta 1 on samples), and with a white base neither reflects nor
// transmits more than it receives.
TEST(PrincipledThin, SymmetricAndEnergyBounded) {
    PrincipledThinParameters parameters = thinSheet(0.6f, 1.0f);
    parameters.baseColor = constant(1.0f);
    parameters.sheen = nullptr;
    const auto sheet = makePrincipledThin(parameters);
    EXPECT_NE(sheet->lobes() & BsdfLobe::Transmission, 0u);
    jobs::Rng rng(11, jobs::streamKey("principled-thin"), 0);
    for (int i = 0; i < 100; ++i) {
        const Vec3 wo = sampleCosineHemisphere(rng.uniform2());
        Vec3 wi = sampleCosineHemisphere(rng.uniform2());
        if (rng.uniform() < 0.5f) wi = below(wi);
        const Rgb front = sheet->eval(wo, wi, Vec2(0.5f), TransportMode::Radiance);
        const Rgb back = sheet->eval(-wo, -wi, Vec2(0.5f), TransportMode::Radiance);
        EXPECT_EQ(front, back) << i;
        EXPECT_EQ(sheet->pdf(wo, wi, Vec2(0.5f)), sheet->pdf(-wo, -wi, Vec2(0.5f))) << i;
        const auto s = sheet->sample(wo, Vec2(0.5f), rng.uniform(), rng.uniform2(), TransportMode::Radiance);
        if (s) {
            EXPECT_EQ(s->eta, 1.0f);
        }
    }
    for (float angle : {0.0f, 45.0f, 80.0f}) {
        const Vec3 wo = test::directionFromAngles(angle, 30.0f);
        const test::AlbedoEstimate albedo = test::albedoBySampling(*sheet, wo, TransportMode::Radiance, 200'000, 13);
        const Rgb quadrature = test::albedoByQuadrature(*sheet, wo, TransportMode::Radiance, 512, 256);
        for (int c = 0; c < 3; ++c) {
            EXPECT_LE(albedo.mean[c], 1.0f + 4.0f * albedo.standardError[c]) << angle;
            // The quadrature does not resolve the narrow transmitted lobe at grazing incidence.
            if (angle > 60.0f) continue;
            EXPECT_NEAR(albedo.mean[c], quadrature[c], 4.0f * albedo.standardError[c] + 1e-2f) << angle;
        }
    }
}

}  // namespace
}  // namespace fg
