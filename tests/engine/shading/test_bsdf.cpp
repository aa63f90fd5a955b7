// Tests of the surface scattering models: Fresnel terms against closed forms,
// specular directions (reflection law, Snell's law, total internal reflection),
// consistency of sample() with pdf() and eval(), reciprocity, and energy
// (white-furnace) checks with Monte Carlo albedos compared against quadrature
// of eval() and against analytic values.
#include "engine/shading/bsdf.h"
#include "engine/shading/texture.h"
#include "jobs/random.h"
#include "tests/engine/shading/bsdf_test_util.h"

#include <gtest/gtest.h>

#include <cmath>
#include <string>
#include <vector>

namespace fg {
namespace {

using test::albedoByQuadrature;
using test::albedoBySampling;
using test::directionFromAngles;

std::shared_ptr<Texture> constant(float v) { return makeConstantTexture(Rgb(v)); }

// Fresnel reflectance of a dielectric from its textbook definition, in double
// precision, independent of the implementation under test.
double referenceFresnel(double cosI, double etaI, double etaT) {
    const double sinT = etaI / etaT * std::sqrt(std::max(0.0, 1.0 - cosI * cosI));
    if (sinT >= 1.0) return 1.0;
    const double cosT = std::sqrt(1.0 - sinT * sinT);
    const double rs = (etaI * cosI - etaT * cosT) / (etaI * cosI + etaT * cosT);
    const double rp = (etaT * cosI - etaI * cosT) / (etaT * cosI + etaI * cosT);
    return 0.5 * (rs * rs + rp * rp);
}

// Hemispherical average 2 * integral of F(mu) mu dmu by Simpson's rule.
double referenceDiffuseFresnel(double etaI, double etaT) {
    constexpr int kSteps = 20000;
    double sum = 0.0;
    for (int i = 0; i <= kSteps; ++i) {
        const double mu = static_cast<double>(i) / kSteps;
        const double w = (i == 0 || i == kSteps) ? 1.0 : (i % 2 ? 4.0 : 2.0);
        sum += w * referenceFresnel(mu, etaI, etaT) * mu;
    }
    return 2.0 * sum / (3.0 * kSteps);
}

Vec3 randomDirection(jobs::Rng& rng) { return sampleUniformSphere(rng.uniform2()); }

// --------------------------------------------------------------------------
// Fresnel terms

TEST(Fresnel, DielectricNormalIncidenceFromBothSides) {
    for (float eta : {1.333f, 1.5f, 2.419f, 0.8f}) {
        const float expected = sqr((eta - 1.0f) / (eta + 1.0f));
        EXPECT_NEAR(fresnelDielectric(1.0f, eta), expected, 1e-6f) << eta;
        EXPECT_NEAR(fresnelDielectric(-1.0f, eta), expected, 1e-6f) << eta;
    }
    EXPECT_EQ(fresnelDielectric(0.3f, 1.0f), 0.0f);
}

TEST(Fresnel, DielectricMatchesReferenceAndSnell) {
    const float eta = 1.5f;
    for (int i = 1; i <= 50; ++i) {
        const float cosI = static_cast<float>(i) / 50.0f;
        float cosT = 0.0f;
        const float outside = fresnelDielectric(cosI, eta, &cosT);
        EXPECT_NEAR(outside, referenceFresnel(cosI, 1.0, eta), 2e-6) << cosI;
        EXPECT_LT(cosT, 0.0f);
        EXPECT_NEAR(1.0f * std::sqrt(1.0f - cosI * cosI), eta * std::sqrt(1.0f - cosT * cosT), 1e-5f);

        const float inside = fresnelDielectric(-cosI, eta, &cosT);
        EXPECT_NEAR(inside, referenceFresnel(cosI, eta, 1.0), 2e-6) << cosI;
        if (inside < 1.0f) {
            EXPECT_GT(cosT, 0.0f);
            EXPECT_NEAR(eta * std::sqrt(1.0f - cosI * cosI), std::sqrt(1.0f - cosT * cosT), 1e-5f);
        }
    }
}

TEST(Fresnel, TotalInternalReflectionBeyondCriticalAngle) {
    const float eta = 1.5f;
    const float critical = std::asin(1.0f / eta);
    const float justBelow = std::cos(critical - 0.01f), justAbove = std::cos(critical + 0.01f);
    EXPECT_LT(fresnelDielectric(-justBelow, eta), 1.0f);
    EXPECT_EQ(fresnelDielectric(-justAbove, eta), 1.0f);
    // The same configuration expressed with the reciprocal relative IOR.
    EXPECT_EQ(fresnelDielectric(justAbove, 1.0f / eta), 1.0f);
    // From the outside there is no critical angle.
    EXPECT_LT(fresnelDielectric(justAbove, eta), 1.0f);
}

TEST(Fresnel, ConductorWithoutAbsorptionIsADielectric) {
    for (int i = 0; i <= 20; ++i) {
        const float cosI = std::max(static_cast<float>(i) / 20.0f, 1e-3f);
        const Rgb f = fresnelConductor(cosI, Rgb(1.2f, 1.5f, 2.0f), Rgb(0.0f));
        EXPECT_NEAR(f.x, fresnelDielectric(cosI, 1.2f), 1e-5f);
        EXPECT_NEAR(f.y, fresnelDielectric(cosI, 1.5f), 1e-5f);
        EXPECT_NEAR(f.z, fresnelDielectric(cosI, 2.0f), 1e-5f);
    }
}

TEST(Fresnel, ConductorNormalIncidenceAndGrazing) {
    for (const char* name : {"Au", "Ag", "Al", "Cu", "Cr"}) {
        const std::optional<ConductorIor> ior = conductorPreset(name);
        ASSERT_TRUE(ior) << name;
        const Rgb f = fresnelConductor(1.0f, ior->eta, ior->k);
        for (int c = 0; c < 3; ++c) {
            const float n = ior->eta[c], k = ior->k[c];
            const float expected = (sqr(n - 1.0f) + k * k) / (sqr(n + 1.0f) + k * k);
            EXPECT_NEAR(f[c], expected, 1e-5f) << name << " channel " << c;
        }
        const Rgb grazing = fresnelConductor(1e-4f, ior->eta, ior->k);
        EXPECT_GT(grazing.x, 0.99f) << name;
        // Metals dip below their normal-incidence reflectance before rising to 1
        // (for p polarisation); the unpolarised value stays within [0, 1].
        for (int i = 0; i <= 100; ++i) {
            const Rgb v = fresnelConductor(static_cast<float>(i) / 100.0f, ior->eta, ior->k);
            for (int c = 0; c < 3; ++c) {
                EXPECT_GE(v[c], 0.0f);
                EXPECT_LE(v[c], 1.0f);
            }
        }
    }
}

TEST(Fresnel, PresetsLookLikeTheirMetals) {
    const auto reflectance = [](const char* name) {
        const ConductorIor ior = *conductorPreset(name);
        return fresnelConductor(1.0f, ior.eta, ior.k);
    };
    const Rgb au = reflectance("Au"), cu = reflectance("Cu"), ag = reflectance("Ag"), al = reflectance("Al");
    EXPECT_GT(au.x, 0.9f);
    EXPECT_LT(au.z, 0.5f);  // gold absorbs blue
    EXPECT_GT(cu.x, cu.y);
    EXPECT_GT(cu.y, cu.z);
    EXPECT_GT(ag.z, 0.85f);  // silver is bright and neutral
    EXPECT_GT(al.y, 0.85f);
    const ConductorIor mirror = *conductorPreset("none");
    for (float c : {1.0f, 0.5f, 0.1f}) {
        const Rgb f = fresnelConductor(c, mirror.eta, mirror.k);
        EXPECT_NEAR(f.x, 1.0f, 1e-6f);
        EXPECT_NEAR(f.z, 1.0f, 1e-6f);
    }
    EXPECT_FALSE(conductorPreset("unobtainium"));
}

TEST(Fresnel, DielectricPresets) {
    EXPECT_EQ(*dielectricIorPreset("vacuum"), 1.0f);
    EXPECT_NEAR(*dielectricIorPreset("air"), 1.000277f, 1e-6f);
    EXPECT_NEAR(*dielectricIorPreset("water"), 1.333f, 1e-6f);
    EXPECT_NEAR(*dielectricIorPreset("bk7"), 1.5046f, 1e-6f);
    EXPECT_NEAR(*dielectricIorPreset("glass"), 1.5f, 1e-6f);
    EXPECT_NEAR(*dielectricIorPreset("diamond"), 2.419f, 1e-6f);
    EXPECT_NEAR(*dielectricIorPreset("acrylic glass"), 1.49f, 1e-6f);
    EXPECT_NEAR(*dielectricIorPreset("polycarbonate"), 1.585f, 1e-6f);
    EXPECT_FALSE(dielectricIorPreset("kryptonite"));
}

// --------------------------------------------------------------------------
// Specular materials

TEST(SmoothDielectric, ReflectionAndRefractionDirections) {
    const float eta = 1.5f;
    const std::shared_ptr<Bsdf> glass = makeDielectric(eta);
    jobs::Rng rng(7, jobs::streamKey("smooth-dielectric"), 0);
    int refractions = 0;
    for (int i = 0; i < 2000; ++i) {
        const Vec3 wo = randomDirection(rng);
        const bool outside = wo.z > 0.0f;
        const float etaO = outside ? 1.0f : eta, etaI = outside ? eta : 1.0f;
        const float fresnel = fresnelDielectric(wo.z, eta);

        const auto r = glass->sample(wo, Vec2(0.0f), 0.0f, rng.uniform2(), TransportMode::Radiance);
        ASSERT_TRUE(r);
        EXPECT_TRUE(r->isSpecular());
        EXPECT_EQ(r->lobe, BsdfLobe::Reflection | BsdfLobe::Specular);
        EXPECT_NEAR(glm::length(r->wi - Vec3(-wo.x, -wo.y, wo.z)), 0.0f, 1e-6f);
        EXPECT_NEAR(r->pdf, fresnel, 1e-6f);
        EXPECT_EQ(r->eta, 1.0f);
        EXPECT_NEAR(r->weight.x, 1.0f, 1e-6f);

        for (TransportMode mode : {TransportMode::Radiance, TransportMode::Importance}) {
            const auto t = glass->sample(wo, Vec2(0.0f), 0.99999f, rng.uniform2(), mode);
            ASSERT_TRUE(t);
            if (fresnel >= 1.0f) {  // total internal reflection
                EXPECT_EQ(t->lobe & BsdfLobe::Reflection, BsdfLobe::Reflection);
                continue;
            }
            ++refractions;
            EXPECT_EQ(t->lobe, BsdfLobe::Transmission | BsdfLobe::Specular);
            EXPECT_NEAR(glm::length(t->wi), 1.0f, 1e-5f);
            EXPECT_LT(t->wi.z * wo.z, 0.0f);
            // Snell's law, and the refracted ray stays in the plane of incidence on the far side.
            // (sin theta from the tangential components: 1 - cos^2 cancels badly near the pole.)
            const float sinO = std::hypot(wo.x, wo.y), sinI = std::hypot(t->wi.x, t->wi.y);
            EXPECT_NEAR(etaO * sinO, etaI * sinI, 2e-6f + 1e-5f * sinO);
            const Vec2 tangentO(wo.x, wo.y), tangentI(t->wi.x, t->wi.y);
            EXPECT_LE(glm::dot(tangentO, tangentI), 1e-7f);
            EXPECT_NEAR(std::abs(tangentO.x * tangentI.y - tangentO.y * tangentI.x), 0.0f, 1e-5f);
            EXPECT_NEAR(t->pdf, 1.0f - fresnel, 1e-6f);
            EXPECT_NEAR(t->eta, etaI / etaO, 1e-6f);
            const float expectedWeight = mode == TransportMode::Radiance ? sqr(etaO / etaI) : 1.0f;
            EXPECT_NEAR(t->weight.y, expectedWeight, 1e-5f);
        }
        EXPECT_EQ(glass->pdf(wo, Vec3(-wo.x, -wo.y, wo.z), Vec2(0.0f)), 0.0f);
        EXPECT_TRUE(isBlack(glass->eval(wo, Vec3(-wo.x, -wo.y, wo.z), Vec2(0.0f), TransportMode::Radiance)));
    }
    EXPECT_GT(refractions, 2000);
}

TEST(SmoothDielectric, TotalInternalReflectionAlwaysReflects) {
    const std::shared_ptr<Bsdf> glass = makeDielectric(1.5f);
    Vec3 wo = directionFromAngles(45.0f, 30.0f);  // beyond the critical angle of 41.8 degrees
    wo.z = -wo.z;
    for (float uLobe : {0.0f, 0.5f, 0.99999f}) {
        const auto s = glass->sample(wo, Vec2(0.0f), uLobe, Vec2(0.5f), TransportMode::Radiance);
        ASSERT_TRUE(s);
        EXPECT_EQ(s->lobe, BsdfLobe::Reflection | BsdfLobe::Specular);
        EXPECT_EQ(s->pdf, 1.0f);
        EXPECT_NEAR(glm::length(s->wi - Vec3(-wo.x, -wo.y, wo.z)), 0.0f, 1e-6f);
    }
}

TEST(SmoothDielectric, LobeFrequenciesFollowFresnelAndEnergyIsConserved) {
    const float eta = 1.5f;
    const std::shared_ptr<Bsdf> glass = makeDielectric(eta);
    constexpr int kSamples = 100000;
    for (float angle : {0.0f, 30.0f, 60.0f, 85.0f}) {
        for (bool inside : {false, true}) {
            Vec3 wo = directionFromAngles(angle, 10.0f);
            if (inside) wo.z = -wo.z;
            const double reference =
                inside ? referenceFresnel(std::abs(wo.z), eta, 1.0) : referenceFresnel(wo.z, 1.0, eta);
            const double etaRatio = inside ? 1.0 / eta : eta;  // eta_t / eta_i
            jobs::Rng rng(11, jobs::streamKey("dielectric-freq"), static_cast<std::uint64_t>(angle));
            int reflections = 0;
            double importance = 0.0, radiance = 0.0;
            for (int i = 0; i < kSamples; ++i) {
                const float uLobe = rng.uniform();
                const auto si = glass->sample(wo, Vec2(0.0f), uLobe, Vec2(0.5f), TransportMode::Importance);
                const auto sr = glass->sample(wo, Vec2(0.0f), uLobe, Vec2(0.5f), TransportMode::Radiance);
                ASSERT_TRUE(si && sr);
                reflections += (si->lobe & BsdfLobe::Reflection) ? 1 : 0;
                importance += si->weight.x;
                radiance += sr->weight.x;
            }
            const double fraction = static_cast<double>(reflections) / kSamples;
            const double sigma = std::sqrt(std::max(reference * (1.0 - reference), 1e-6) / kSamples);
            EXPECT_NEAR(fraction, reference, 5.0 * sigma + 1e-6) << angle << (inside ? " inside" : " outside");
            // R + T = 1 for importance; radiance transmission carries 1/eta^2.
            EXPECT_NEAR(importance / kSamples, 1.0, 1e-6);
            const double expectedRadiance = fraction + (1.0 - fraction) / (etaRatio * etaRatio);
            EXPECT_NEAR(radiance / kSamples, expectedRadiance, 1e-6);
        }
    }
}

TEST(ThinDielectric, ReflectanceSumsInterreflectionsAndConservesEnergy) {
    const float eta = 1.5f;
    const std::shared_ptr<Bsdf> sheet = makeThinDielectric(eta);
    constexpr int kSamples = 100000;
    for (float angle : {0.0f, 45.0f, 80.0f}) {
        for (bool back : {false, true}) {
            Vec3 wo = directionFromAngles(angle, 0.0f);
            if (back) wo.z = -wo.z;
            const double single = referenceFresnel(std::abs(wo.z), 1.0, eta);
            // R + T^2 R (1 + R^2 + R^4 + ...), T = 1 - R.
            const double expected = single + sqr(1.0 - single) * single / (1.0 - single * single);
            jobs::Rng rng(5, jobs::streamKey("thin"), static_cast<std::uint64_t>(angle));
            int reflections = 0;
            double weight = 0.0;
            for (int i = 0; i < kSamples; ++i) {
                const auto s = sheet->sample(wo, Vec2(0.0f), rng.uniform(), Vec2(0.5f), TransportMode::Radiance);
                ASSERT_TRUE(s);
                weight += s->weight.x;
                if (s->lobe & BsdfLobe::Reflection) {
                    ++reflections;
                    EXPECT_NEAR(glm::length(s->wi - Vec3(-wo.x, -wo.y, wo.z)), 0.0f, 1e-6f);
                    EXPECT_NEAR(s->pdf, expected, 1e-5);
                } else {
                    EXPECT_NEAR(glm::length(s->wi + wo), 0.0f, 1e-6f);  // undeviated
                    EXPECT_EQ(s->eta, 1.0f);
                }
            }
            const double fraction = static_cast<double>(reflections) / kSamples;
            EXPECT_NEAR(fraction, expected, 5.0 * std::sqrt(expected * (1.0 - expected) / kSamples) + 1e-6);
            EXPECT_NEAR(weight / kSamples, 1.0, 1e-6);
        }
    }
}

TEST(SmoothConductor, WeightIsFresnelAndOneSided) {
    const ConductorIor gold = *conductorPreset("Au");
    const std::shared_ptr<Bsdf> metal = makeConductor(gold, Rgb(0.5f, 1.0f, 1.0f));
    const std::shared_ptr<Bsdf> mirror = makeConductor(*conductorPreset("none"));
    for (float angle : {0.0f, 40.0f, 85.0f}) {
        const Vec3 wo = directionFromAngles(angle, 50.0f);
        const auto s = metal->sample(wo, Vec2(0.0f), 0.3f, Vec2(0.3f), TransportMode::Radiance);
        ASSERT_TRUE(s);
        EXPECT_TRUE(s->isSpecular());
        EXPECT_NEAR(glm::length(s->wi - Vec3(-wo.x, -wo.y, wo.z)), 0.0f, 1e-6f);
        const Rgb f = fresnelConductor(wo.z, gold.eta, gold.k);
        EXPECT_NEAR(s->weight.x, 0.5f * f.x, 1e-6f);
        EXPECT_NEAR(s->weight.z, f.z, 1e-6f);
        EXPECT_EQ(s->pdf, 1.0f);
        const auto m = mirror->sample(wo, Vec2(0.0f), 0.3f, Vec2(0.3f), TransportMode::Importance);
        ASSERT_TRUE(m);
        EXPECT_NEAR(m->weight.y, 1.0f, 1e-6f);
        EXPECT_FALSE(metal->sample(-wo, Vec2(0.0f), 0.3f, Vec2(0.3f), TransportMode::Radiance));
    }
    const Rgb normal = fresnelConductor(1.0f, gold.eta, gold.k);
    const float expectedRed = (sqr(gold.eta.x - 1.0f) + sqr(gold.k.x)) / (sqr(gold.eta.x + 1.0f) + sqr(gold.k.x));
    EXPECT_NEAR(normal.x, expectedRed, 1e-5f);
}

TEST(NullBsdf, PassesStraightThrough) {
    const std::shared_ptr<Bsdf> pass = makeNull();
    EXPECT_TRUE(pass->isNull());
    EXPECT_FALSE(pass->hasSmoothLobe());
    EXPECT_FALSE(pass->isPurelySpecular());
    const Vec3 wo = glm::normalize(Vec3(0.3f, -0.2f, -0.8f));
    const auto s = pass->sample(wo, Vec2(0.0f), 0.7f, Vec2(0.1f), TransportMode::Radiance);
    ASSERT_TRUE(s);
    EXPECT_EQ(s->wi, -wo);
    EXPECT_EQ(s->weight, Rgb(1.0f));
    EXPECT_EQ(s->lobe, BsdfLobe::Null | BsdfLobe::Transmission);
    EXPECT_EQ(s->eta, 1.0f);
    EXPECT_TRUE(isBlack(pass->eval(wo, -wo, Vec2(0.0f), TransportMode::Radiance)));
    EXPECT_EQ(pass->pdf(wo, -wo, Vec2(0.0f)), 0.0f);
}

TEST(BsdfLobes, ClassificationHelpers) {
    EXPECT_TRUE(makeDielectric(1.5f)->isPurelySpecular());
    EXPECT_TRUE(makeThinDielectric(1.5f)->isPurelySpecular());
    EXPECT_TRUE(makeConductor(*conductorPreset("Cu"))->isPurelySpecular());
    EXPECT_TRUE(makeDiffuse(constant(0.5f))->hasSmoothLobe());
    EXPECT_TRUE(makeRoughDielectric(1.5f, 0.2f)->hasSmoothLobe());
    EXPECT_TRUE(makePlastic(constant(0.5f), 1.5f)->hasSmoothLobe());
    EXPECT_EQ(makeRoughDielectric(1.5f, 0.2f)->lobes() & BsdfLobe::Transmission, BsdfLobe::Transmission);
    EXPECT_EQ(makeTwoSided(makeDiffuse(constant(0.5f)))->lobes(), makeDiffuse(constant(0.5f))->lobes());
}

// --------------------------------------------------------------------------
// sample() consistent with pdf() and eval()

struct NamedBsdf {
    std::string name;
    std::shared_ptr<Bsdf> bsdf;
};

std::vector<NamedBsdf> smoothMaterials() {
    return {
        {"diffuse checker", makeDiffuse(makeCheckerboardTexture(Rgb(0.8f, 0.2f, 0.1f), Rgb(0.1f, 0.5f, 0.9f)))},
        {"rough Au 0.05", makeRoughConductor(*conductorPreset("Au"), 0.05f)},
        {"rough Cu 0.3", makeRoughConductor(*conductorPreset("Cu"), 0.3f, Rgb(0.9f, 0.8f, 0.7f))},
        {"rough Al 0.9", makeRoughConductor(*conductorPreset("Al"), 0.9f)},
        {"rough glass 0.05", makeRoughDielectric(1.5f, 0.05f)},
        {"rough glass 0.3", makeRoughDielectric(1.5f, 0.3f)},
        {"rough water 0.8", makeRoughDielectric(1.333f, 0.8f)},
        {"plastic", makePlastic(makeCheckerboardTexture(Rgb(0.8f), Rgb(0.1f, 0.3f, 0.6f)), 1.5f)},
        {"plastic nonlinear", makePlastic(constant(0.6f), 1.9f, true)},
        {"two-sided rough", makeTwoSided(makeRoughConductor(*conductorPreset("Ag"), 0.2f))},
        {"two-sided plastic", makeTwoSided(makePlastic(constant(0.4f), 1.5f))},
        {"beckmann Au 0.05", makeRoughConductor(*conductorPreset("Au"), 0.05f, Rgb(1.0f), MicrofacetType::Beckmann)},
        {"beckmann Al 0.9", makeRoughConductor(*conductorPreset("Al"), 0.9f, Rgb(1.0f), MicrofacetType::Beckmann)},
        {"beckmann glass 0.05", makeRoughDielectric(1.5f, 0.05f, MicrofacetType::Beckmann)},
        {"beckmann water 0.8", makeRoughDielectric(1.333f, 0.8f, MicrofacetType::Beckmann)},
        {"roughplastic beckmann 0.1",
         makeRoughPlastic(makeCheckerboardTexture(Rgb(0.8f), Rgb(0.1f, 0.3f, 0.6f)), 1.5f, 0.1f, MicrofacetType::Beckmann)},
        {"roughplastic ggx 0.6 nonlinear", makeRoughPlastic(constant(0.6f), 1.9f, 0.6f, MicrofacetType::Ggx, true)},
        {"two-sided roughplastic", makeTwoSided(makeRoughPlastic(constant(0.4f), 1.5f, 0.3f, MicrofacetType::Beckmann))},
    };
}

TEST(BsdfConsistency, SamplePdfAndWeightMatchPdfAndEval) {
    for (const NamedBsdf& material : smoothMaterials()) {
        jobs::Rng rng(3, jobs::streamKey("consistency"), std::hash<std::string>{}(material.name));
        int checked = 0, mismatches = 0;
        for (int i = 0; i < 20000; ++i) {
            const Vec3 wo = randomDirection(rng);
            const Vec2 uv = rng.uniform2();
            const float uLobe = rng.uniform();
            const Vec2 u = rng.uniform2();
            const TransportMode mode = (i & 1) ? TransportMode::Radiance : TransportMode::Importance;
            const std::optional<BsdfSample> s = material.bsdf->sample(wo, uv, uLobe, u, mode);
            if (!s || s->isSpecular()) continue;
            ++checked;
            EXPECT_NEAR(glm::length(s->wi), 1.0f, 1e-4f);
            const float pdf = material.bsdf->pdf(wo, s->wi, uv);
            const Rgb value = material.bsdf->eval(wo, s->wi, uv, mode);
            const bool pdfOk = std::abs(pdf - s->pdf) <= 2e-3f * std::max(pdf, s->pdf);
            const Rgb expectedWeight = value / pdf;
            const bool weightOk =
                pdf > 0.0f && glm::all(glm::lessThanEqual(glm::abs(expectedWeight - s->weight),
                                                          2e-3f * glm::max(expectedWeight, s->weight) + 1e-6f));
            if (!pdfOk || !weightOk) {
                if (mismatches++ < 3) {
                    ADD_FAILURE() << material.name << ": wo (" << wo.x << ", " << wo.y << ", " << wo.z << "), wi ("
                                  << s->wi.x << ", " << s->wi.y << ", " << s->wi.z << "): sample pdf " << s->pdf
                                  << " vs pdf() " << pdf << "; weight " << s->weight.x << " vs eval/pdf "
                                  << expectedWeight.x;
                }
            }
        }
        EXPECT_EQ(mismatches, 0) << material.name;
        EXPECT_GT(checked, 3000) << material.name;
    }
}

TEST(BsdfConsistency, TwoSidedMirrorsTheFrontSide) {
    const std::shared_ptr<Bsdf> inner = makeRoughConductor(*conductorPreset("Au"), 0.25f);
    const std::shared_ptr<Bsdf> twoSided = makeTwoSided(inner);
    jobs::Rng rng(8, jobs::streamKey("two-sided"), 0);
    for (int i = 0; i < 1000; ++i) {
        Vec3 wo = sampleCosineHemisphere(rng.uniform2()), wi = sampleCosineHemisphere(rng.uniform2());
        const Vec3 woBack(wo.x, wo.y, -wo.z), wiBack(wi.x, wi.y, -wi.z);
        EXPECT_EQ(twoSided->eval(woBack, wiBack, Vec2(0.0f), TransportMode::Radiance),
                  inner->eval(wo, wi, Vec2(0.0f), TransportMode::Radiance));
        EXPECT_EQ(twoSided->pdf(woBack, wiBack, Vec2(0.0f)), inner->pdf(wo, wi, Vec2(0.0f)));
        EXPECT_TRUE(isBlack(inner->eval(woBack, wiBack, Vec2(0.0f), TransportMode::Radiance)));
        const Vec2 u = rng.uniform2();
        const auto front = inner->sample(wo, Vec2(0.0f), 0.5f, u, TransportMode::Radiance);
        const auto back = twoSided->sample(woBack, Vec2(0.0f), 0.5f, u, TransportMode::Radiance);
        ASSERT_EQ(front.has_value(), back.has_value());
        if (front) {
            EXPECT_EQ(back->wi, Vec3(front->wi.x, front->wi.y, -front->wi.z));
            EXPECT_EQ(back->weight, front->weight);
            EXPECT_EQ(back->pdf, front->pdf);
        }
    }
}

TEST(Diffuse, UsesTextureAndIsOneSided) {
    const std::shared_ptr<Bsdf> diffuse =
        makeDiffuse(makeCheckerboardTexture(Rgb(0.8f, 0.2f, 0.1f), Rgb(0.1f, 0.5f, 0.9f)));
    const Vec3 wo = directionFromAngles(30.0f, 0.0f), wi = directionFromAngles(60.0f, 120.0f);
    const Rgb even = diffuse->eval(wo, wi, Vec2(0.1f, 0.1f), TransportMode::Radiance);
    const Rgb odd = diffuse->eval(wo, wi, Vec2(0.6f, 0.1f), TransportMode::Radiance);
    EXPECT_NEAR(even.x, 0.8f * wi.z / kPi, 1e-6f);
    EXPECT_NEAR(odd.z, 0.9f * wi.z / kPi, 1e-6f);
    const Vec3 below(wi.x, wi.y, -wi.z);
    EXPECT_TRUE(isBlack(diffuse->eval(wo, below, Vec2(0.1f), TransportMode::Radiance)));
    EXPECT_TRUE(isBlack(diffuse->eval(Vec3(wo.x, wo.y, -wo.z), wi, Vec2(0.1f), TransportMode::Radiance)));
    EXPECT_EQ(diffuse->pdf(wo, below, Vec2(0.1f)), 0.0f);
    EXPECT_FALSE(diffuse->sample(Vec3(wo.x, wo.y, -wo.z), Vec2(0.1f), 0.5f, Vec2(0.5f), TransportMode::Radiance));
}

// --------------------------------------------------------------------------
// Reciprocity

TEST(Reciprocity, ReflectionModelsAreSymmetric) {
    const std::vector<NamedBsdf> materials = {
        {"diffuse", makeDiffuse(constant(0.6f))},
        {"rough Au 0.2", makeRoughConductor(*conductorPreset("Au"), 0.2f)},
        {"rough Cr 0.6", makeRoughConductor(*conductorPreset("Cr"), 0.6f)},
        {"plastic", makePlastic(constant(0.6f), 1.5f)},
        {"plastic nonlinear", makePlastic(constant(0.6f), 1.5f, true)},
        {"beckmann Au 0.2", makeRoughConductor(*conductorPreset("Au"), 0.2f, Rgb(1.0f), MicrofacetType::Beckmann)},
        {"beckmann Cr 0.6", makeRoughConductor(*conductorPreset("Cr"), 0.6f, Rgb(1.0f), MicrofacetType::Beckmann)},
        {"roughplastic beckmann", makeRoughPlastic(constant(0.6f), 1.5f, 0.3f, MicrofacetType::Beckmann)},
        {"roughplastic ggx nonlinear", makeRoughPlastic(constant(0.6f), 1.5f, 0.1f, MicrofacetType::Ggx, true)},
    };
    jobs::Rng rng(12, jobs::streamKey("reciprocity"), 0);
    for (const NamedBsdf& m : materials) {
        for (int i = 0; i < 2000; ++i) {
            const Vec3 a = sampleUniformSphere(rng.uniform2()), b = sampleUniformSphere(rng.uniform2());
            const Vec3 wo(a.x, a.y, std::abs(a.z)), wi(b.x, b.y, std::abs(b.z));
            if (wo.z < 1e-3f || wi.z < 1e-3f) continue;
            const Rgb forward = m.bsdf->eval(wo, wi, Vec2(0.0f), TransportMode::Radiance) / wi.z;
            const Rgb backward = m.bsdf->eval(wi, wo, Vec2(0.0f), TransportMode::Radiance) / wo.z;
            for (int c = 0; c < 3; ++c)
                EXPECT_NEAR(forward[c], backward[c], 1e-4f * std::max(1.0f, forward[c])) << m.name;
        }
    }
}

TEST(Reciprocity, RoughDielectricObeysGeneralisedReciprocityAndAdjoint) {
    const float eta = 1.5f;
    for (MicrofacetType type : {MicrofacetType::Ggx, MicrofacetType::Beckmann}) {
        const std::shared_ptr<Bsdf> glass = makeRoughDielectric(eta, 0.4f, type);
        jobs::Rng rng(13, jobs::streamKey("reciprocity-dielectric"), 0);
        int transmissions = 0;
        for (int i = 0; i < 8000; ++i) {
            const Vec3 wo = randomDirection(rng), wi = randomDirection(rng);
            if (std::abs(wo.z) < 1e-2f || std::abs(wi.z) < 1e-2f) continue;
            const float etaO = wo.z > 0.0f ? 1.0f : eta, etaI = wi.z > 0.0f ? 1.0f : eta;
            const float radianceForward = glass->eval(wo, wi, Vec2(0.0f), TransportMode::Radiance).x / std::abs(wi.z);
            const float radianceBackward = glass->eval(wi, wo, Vec2(0.0f), TransportMode::Radiance).x / std::abs(wo.z);
            const float importanceForward =
                glass->eval(wo, wi, Vec2(0.0f), TransportMode::Importance).x / std::abs(wi.z);
            if (wo.z * wi.z < 0.0f && radianceForward > 0.0f) ++transmissions;
            // f(wo, wi) / eta_o^2 = f(wi, wo) / eta_i^2 (Veach 1997, Sec. 5.2), radiance form.
            const float lhs = radianceForward / (etaO * etaO), rhs = radianceBackward / (etaI * etaI);
            EXPECT_NEAR(lhs, rhs, 1e-4f * std::max(1.0f, lhs));
            // The importance form is the adjoint of the radiance form.
            EXPECT_NEAR(importanceForward, radianceBackward, 1e-4f * std::max(1.0f, importanceForward));
        }
        EXPECT_GT(transmissions, 600) << microfacetTypeName(type);
    }
}

// --------------------------------------------------------------------------
// Energy

std::vector<Vec3> incidentDirections(bool bothSides) {
    std::vector<Vec3> dirs;
    for (float angle : {0.0f, 20.0f, 40.0f, 60.0f, 75.0f, 85.0f, 89.0f}) {
        dirs.push_back(directionFromAngles(angle, 17.0f));
        if (bothSides) dirs.push_back(Vec3(dirs.back().x, dirs.back().y, -dirs.back().z));
    }
    return dirs;
}

TEST(Energy, EveryMaterialConservesEnergy) {
    const std::vector<NamedBsdf> materials = {
        {"diffuse white", makeDiffuse(constant(1.0f))},
        {"dielectric", makeDielectric(1.5f)},
        {"thin dielectric", makeThinDielectric(1.5f)},
        {"conductor Au", makeConductor(*conductorPreset("Au"))},
        {"conductor none", makeConductor(*conductorPreset("none"))},
        {"rough none 0.1", makeRoughConductor(*conductorPreset("none"), 0.1f)},
        {"rough none 1.0", makeRoughConductor(*conductorPreset("none"), 1.0f)},
        {"rough Ag 0.4", makeRoughConductor(*conductorPreset("Ag"), 0.4f)},
        {"rough glass 0.1", makeRoughDielectric(1.5f, 0.1f)},
        {"rough glass 0.5", makeRoughDielectric(1.5f, 0.5f)},
        {"rough diamond 0.3", makeRoughDielectric(2.419f, 0.3f)},
        {"plastic white", makePlastic(constant(1.0f), 1.5f)},
        {"plastic white nonlinear", makePlastic(constant(1.0f), 1.5f, true)},
        {"plastic high ior", makePlastic(constant(0.9f), 2.2f)},
        {"beckmann none 0.1", makeRoughConductor(*conductorPreset("none"), 0.1f, Rgb(1.0f), MicrofacetType::Beckmann)},
        {"beckmann none 1.0", makeRoughConductor(*conductorPreset("none"), 1.0f, Rgb(1.0f), MicrofacetType::Beckmann)},
        {"beckmann glass 0.1", makeRoughDielectric(1.5f, 0.1f, MicrofacetType::Beckmann)},
        {"beckmann diamond 0.5", makeRoughDielectric(2.419f, 0.5f, MicrofacetType::Beckmann)},
        {"roughplastic white beckmann 0.05", makeRoughPlastic(constant(1.0f), 1.5f, 0.05f, MicrofacetType::Beckmann)},
        {"roughplastic white ggx 0.7", makeRoughPlastic(constant(1.0f), 1.5f, 0.7f, MicrofacetType::Ggx)},
        {"roughplastic white high ior", makeRoughPlastic(constant(1.0f), 2.2f, 0.4f, MicrofacetType::Beckmann, true)},
        {"null", makeNull()},
        {"two-sided diffuse", makeTwoSided(makeDiffuse(constant(1.0f)))},
    };
    for (const NamedBsdf& m : materials) {
        for (const Vec3& wo : incidentDirections(true)) {
            const test::AlbedoEstimate albedo = albedoBySampling(*m.bsdf, wo, TransportMode::Importance, 20000, 21);
            for (int c = 0; c < 3; ++c) {
                EXPECT_LE(albedo.mean[c], 1.0f + 1e-4f + 4.0f * albedo.standardError[c])
                    << m.name << " at cos " << wo.z;
                EXPECT_GE(albedo.mean[c], 0.0f) << m.name;
            }
        }
    }
}

TEST(Energy, WhiteDiffuseReflectsEverything) {
    const std::shared_ptr<Bsdf> diffuse = makeDiffuse(constant(1.0f));
    for (const Vec3& wo : incidentDirections(false)) {
        const test::AlbedoEstimate sampled = albedoBySampling(*diffuse, wo, TransportMode::Radiance, 10000, 1);
        EXPECT_NEAR(sampled.mean.y, 1.0f, 1e-4f);
        const Rgb integrated = albedoByQuadrature(*diffuse, wo, TransportMode::Radiance, 512, 64);
        EXPECT_NEAR(integrated.y, 1.0f, 1e-3f);
    }
    const Vec3 below = -directionFromAngles(30.0f, 0.0f);
    EXPECT_EQ(albedoBySampling(*diffuse, below, TransportMode::Radiance, 1000, 1).mean.y, 0.0f);
}

TEST(Energy, RoughConductorLosesOnlySingleScatteringEnergy) {
    const ConductorIor mirror = *conductorPreset("none");
    // Directional albedo without Fresnel loss: the remainder is light that
    // would scatter more than once between microfacets.
    for (const Vec3& wo : incidentDirections(false)) {
        if (wo.z < std::cos(80.0f * test::kDegree)) continue;
        const std::shared_ptr<Bsdf> rough = makeRoughConductor(mirror, 0.3f);
        const test::AlbedoEstimate albedo = albedoBySampling(*rough, wo, TransportMode::Radiance, 50000, 2);
        EXPECT_GT(albedo.mean.x, 0.8f) << wo.z;
        EXPECT_LE(albedo.mean.x, 1.0f) << wo.z;
    }
    for (float angle : {0.0f, 45.0f, 70.0f}) {
        const Vec3 wo = directionFromAngles(angle, 0.0f);
        float previous = 1.0f + 1e-6f;
        for (float alpha : {0.05f, 0.2f, 0.4f, 0.7f, 1.0f}) {
            const test::AlbedoEstimate albedo =
                albedoBySampling(*makeRoughConductor(mirror, alpha), wo, TransportMode::Radiance, 100000, 3);
            EXPECT_LT(albedo.mean.x, previous) << "alpha " << alpha << " at " << angle << " degrees";
            previous = albedo.mean.x;
        }
        EXPECT_LT(previous, 0.95f);  // a very rough surface loses a visible fraction
    }
}

TEST(Energy, RoughConductorSmoothLimitMatchesFresnel) {
    const ConductorIor gold = *conductorPreset("Au");
    for (float angle : {0.0f, 30.0f, 60.0f}) {
        const Vec3 wo = directionFromAngles(angle, 0.0f);
        const Rgb expected = fresnelConductor(wo.z, gold.eta, gold.k);
        const test::AlbedoEstimate albedo =
            albedoBySampling(*makeRoughConductor(gold, 0.002f), wo, TransportMode::Radiance, 20000, 4);
        for (int c = 0; c < 3; ++c) EXPECT_NEAR(albedo.mean[c], expected[c], 2e-3f) << angle;
    }
}

TEST(Energy, RoughDielectricSmoothLimitMatchesFresnel) {
    const float eta = 1.5f;
    const std::shared_ptr<Bsdf> rough = makeRoughDielectric(eta, 0.002f);
    for (float angle : {0.0f, 30.0f, 60.0f}) {
        for (bool inside : {false, true}) {
            Vec3 wo = directionFromAngles(angle, 0.0f);
            if (inside) wo.z = -wo.z;
            const double fresnel =
                inside ? referenceFresnel(std::abs(wo.z), eta, 1.0) : referenceFresnel(wo.z, 1.0, eta);
            const double etaRatio = inside ? 1.0 / eta : eta;
            const test::AlbedoEstimate importance =
                albedoBySampling(*rough, wo, TransportMode::Importance, 40000, 5);
            const test::AlbedoEstimate radiance = albedoBySampling(*rough, wo, TransportMode::Radiance, 40000, 5);
            EXPECT_NEAR(importance.mean.x, 1.0, 3e-3) << angle << inside;
            const double expected = fresnel + (1.0 - fresnel) / (etaRatio * etaRatio);
            EXPECT_NEAR(radiance.mean.x, expected, 4.0 * radiance.standardError.x + 3e-3) << angle << inside;
        }
    }
}

TEST(Energy, RoughDielectricReflectsAndTransmitsAtMostEverything) {
    // Single scattering loses the light that would bounce between microfacets
    // (much of it trapped by total internal reflection when arriving from the
    // inside), so R + T < 1 and the loss grows with roughness.
    const std::shared_ptr<Bsdf> glass[] = {makeRoughDielectric(1.5f, 0.1f), makeRoughDielectric(1.5f, 0.3f),
                                           makeRoughDielectric(1.5f, 0.7f)};
    for (const Vec3& wo : incidentDirections(true)) {
        float previous = 1.0f;
        for (const std::shared_ptr<Bsdf>& bsdf : glass) {
            const test::AlbedoEstimate albedo = albedoBySampling(*bsdf, wo, TransportMode::Importance, 40000, 6);
            EXPECT_LE(albedo.mean.x, previous + 3.0f * albedo.standardError.x) << "cos " << wo.z;
            EXPECT_GT(albedo.mean.x, 0.4f) << "cos " << wo.z;
            previous = albedo.mean.x;
        }
        if (wo.z > 0.9f) {
            EXPECT_GT(previous, 0.9f) << "alpha 0.7 from outside near normal incidence";
        }
    }
}

// The Monte Carlo estimate from sample() weights must agree with an
// independent quadrature of eval(): this checks the weights, not just the pdf.
TEST(Energy, SampledAlbedoAgreesWithIntegratedEval) {
    const std::vector<NamedBsdf> materials = {
        {"diffuse", makeDiffuse(constant(0.6f))},
        {"rough Cu 0.3", makeRoughConductor(*conductorPreset("Cu"), 0.3f)},
        {"rough none 0.7", makeRoughConductor(*conductorPreset("none"), 0.7f)},
        {"rough glass 0.3", makeRoughDielectric(1.5f, 0.3f)},
        {"rough glass 0.6", makeRoughDielectric(1.5f, 0.6f)},
        {"two-sided rough", makeTwoSided(makeRoughConductor(*conductorPreset("Au"), 0.4f))},
        {"beckmann Cu 0.3", makeRoughConductor(*conductorPreset("Cu"), 0.3f, Rgb(1.0f), MicrofacetType::Beckmann)},
        {"beckmann glass 0.5", makeRoughDielectric(1.5f, 0.5f, MicrofacetType::Beckmann)},
        {"roughplastic beckmann 0.4", makeRoughPlastic(constant(0.7f), 1.5f, 0.4f, MicrofacetType::Beckmann, false, Rgb(0.8f))},
    };
    for (const NamedBsdf& m : materials) {
        for (float angle : {15.0f, 60.0f}) {
            for (bool back : {false, true}) {
                Vec3 wo = directionFromAngles(angle, 33.0f);
                if (back) wo.z = -wo.z;
                for (TransportMode mode : {TransportMode::Radiance, TransportMode::Importance}) {
                    const test::AlbedoEstimate sampled = albedoBySampling(*m.bsdf, wo, mode, 100000, 9);
                    const Rgb integrated = albedoByQuadrature(*m.bsdf, wo, mode, 768, 384);
                    for (int c = 0; c < 3; ++c) {
                        EXPECT_NEAR(sampled.mean[c], integrated[c], 5.0f * sampled.standardError[c] + 3e-3f)
                            << m.name << " at " << angle << (back ? " back" : " front")
                            << (mode == TransportMode::Radiance ? " radiance" : " importance");
                    }
                }
            }
        }
    }
}

TEST(Energy, PlasticMatchesItsLayeredModel) {
    const float eta = 1.5f;
    const double fdrInternal = referenceDiffuseFresnel(eta, 1.0);
    for (bool nonlinear : {false, true}) {
        for (float rho : {1.0f, 0.5f, 0.1f}) {
            const std::shared_ptr<Bsdf> plastic = makePlastic(constant(rho), eta, nonlinear);
            for (float angle : {0.0f, 45.0f, 80.0f}) {
                const Vec3 wo = directionFromAngles(angle, 0.0f);
                const double fresnel = referenceFresnel(wo.z, 1.0, eta);
                // Light entering the coating (1 - F) is eventually reflected with
                // the base albedo, renormalised by the internal reflections.
                const double base = nonlinear ? rho * (1.0 - fdrInternal) / (1.0 - rho * fdrInternal) : rho;
                const double expected = fresnel + (1.0 - fresnel) * base;
                const test::AlbedoEstimate albedo =
                    albedoBySampling(*plastic, wo, TransportMode::Radiance, 100000, 10);
                EXPECT_NEAR(albedo.mean.x, expected, 4.0 * albedo.standardError.x + 2e-3)
                    << (nonlinear ? "nonlinear" : "linear") << " rho " << rho << " at " << angle;
                // The diffuse lobe alone, integrated, is the part without specular reflection.
                const Rgb diffuse = albedoByQuadrature(*plastic, wo, TransportMode::Radiance, 512, 64);
                EXPECT_NEAR(diffuse.x, expected - fresnel, 2e-3);
            }
        }
    }
}

TEST(Plastic, SpecularLobeProbabilityAndWeight) {
    const float eta = 1.5f, rho = 0.5f;
    const std::shared_ptr<Bsdf> plastic = makePlastic(constant(rho), eta);
    for (float angle : {0.0f, 50.0f, 85.0f}) {
        const Vec3 wo = directionFromAngles(angle, 0.0f);
        const float fresnel = fresnelDielectric(wo.z, eta);
        // Lobe weights: specular albedo 1 times F against the mean diffuse albedo times 1 - F.
        const float specularWeight = 1.0f / (1.0f + rho);
        const float expectedProbability =
            fresnel * specularWeight / (fresnel * specularWeight + (1.0f - fresnel) * (1.0f - specularWeight));
        const auto specular = plastic->sample(wo, Vec2(0.0f), expectedProbability * 0.999f, Vec2(0.5f),
                                              TransportMode::Radiance);
        ASSERT_TRUE(specular);
        EXPECT_EQ(specular->lobe, BsdfLobe::Reflection | BsdfLobe::Specular);
        EXPECT_NEAR(specular->pdf, expectedProbability, 1e-5f);
        EXPECT_NEAR(specular->weight.x * specular->pdf, fresnel, 1e-5f);
        EXPECT_NEAR(glm::length(specular->wi - Vec3(-wo.x, -wo.y, wo.z)), 0.0f, 1e-6f);
        const auto diffuse = plastic->sample(wo, Vec2(0.0f), expectedProbability * 1.001f + 1e-6f, Vec2(0.3f, 0.6f),
                                             TransportMode::Radiance);
        ASSERT_TRUE(diffuse);
        EXPECT_EQ(diffuse->lobe, BsdfLobe::Reflection | BsdfLobe::Diffuse);
        EXPECT_NEAR(diffuse->pdf, (1.0f - expectedProbability) * diffuse->wi.z / kPi, 1e-5f);
    }
}

}  // namespace
}  // namespace fg
