// The environment sampler of guided environment emission (Vorba et al. 2014,
// §4.4): equal-area cells, the disk frame and map, and the densities the
// photon pass divides by: the direction density (p_L p_W and its mixture with
// p_L) and the position density on the emission disk (the disk GMM mixed with
// the uniform density) integrate to one (minus the GMM's mass outside its
// square) and match their sampling routines by chi².
#include "engine/guiding/environment_guide.h"

#include "engine/core/codec.h"
#include "engine/core/error.h"
#include "engine/shading/light.h"
#include "engine/shading/texture.h"
#include "jobs/random.h"
#include "tests/support/chi2.h"
#include "tests/support/cli_helpers.h"
#include "tests/support/input_error.h"
#include "tests/support/gmm_fixtures.h"
#include "tests/support/sun_sky.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <fstream>
#include <memory>
#include <vector>

namespace fg {
namespace {

using test::gmmComponent;
using test::gmmMixture;

// A 16 x 8 model with importance in an uneven patch of cells (a lobe around
// `towards` and a few scattered cells), and an anisotropic disk GMM in some.
EnvironmentGuide syntheticGuide(const Vec3& towards) {
    EnvironmentGuide guide;
    guide.columns = 16;
    guide.rows = 8;
    guide.center = Vec3(0.2f, -0.1f, 0.3f);
    guide.radius = 2.0f;
    guide.passes = 1;
    guide.cells.resize(guide.cellCount());
    auto density = guide.cells.column<EnvCellDensity>();
    auto gmms = guide.cells.column<EnvCellMixture>();
    auto fitted = guide.cells.column<EnvCellFitted>();
    for (std::uint32_t c = 0; c < guide.cellCount(); ++c) {
        const float mu = glm::dot(guide.cellCentre(c), glm::normalize(towards));
        density[c] = mu > 0.5f ? 3.0f * (mu - 0.5f) : (c % 37 == 3 ? 0.2f : 0.0f);
        if (c % 3 == 0) {
            gmms[c] = gmmMixture({gmmComponent(0.6f, Vec2(0.35f, 0.6f), 0.01f, 0.004f, 0.006f),
                                  gmmComponent(0.4f, Vec2(0.8f, 0.2f), 0.002f, 0.0f, 0.03f)});
            fitted[c] = 1;
        }
    }
    return guide;
}

std::shared_ptr<Light> gradientEnvironmentMap() {
    RgbImage image{8, 5, {}};
    for (int y = 0; y < image.height; ++y)
        for (int x = 0; x < image.width; ++x)
            image.pixels.push_back(Rgb(0.1f + 0.3f * float(x) + float(y * y), 0.5f, 0.2f + 0.1f * float(x * y)));
    auto light = makeEnvironmentMap(image, 1.0f);
    light->setSceneBounds(Vec3(0.0f), 2.0f);
    return light;
}

// A 256 x 128 sky with a sun of 1.5° radius (about 80 % of the radiant
// integral) towards `towardsSun`, a direction in the map's frame (+Y up).
std::shared_ptr<Light> sunEnvironmentMap(const Vec3& towardsSun) {
    RgbImage image{256, 128, test::sunSkyPixels(256, 128, towardsSun, 1.5f, 20000.0f)};
    auto light = makeEnvironmentMap(image, 1.0f);
    light->setSceneBounds(Vec3(0.0f), 2.0f);
    return light;
}

const Vec3 kSun = glm::normalize(Vec3(0.4f, 0.5f, 0.75f));

// Midpoint rule over the sphere in (z, φ), which is equal-area.
template <class F>
double integrateSphere(F&& f, int nz = 512, int nphi = 1024) {
    double sum = 0.0;
    for (int i = 0; i < nz; ++i) {
        const double z = 1.0 - 2.0 * (i + 0.5) / nz;
        const double r = std::sqrt(std::max(0.0, 1.0 - z * z));
        for (int k = 0; k < nphi; ++k) {
            const double phi = 2.0 * M_PI * (k + 0.5) / nphi;
            sum += f(Vec3(float(r * std::cos(phi)), float(r * std::sin(phi)), float(z)));
        }
    }
    return sum * 4.0 * M_PI / (double(nz) * nphi);
}

TEST(EnvironmentGuide, CellsAreEqualAreaAndContainTheirDirections) {
    const EnvironmentGuide guide = syntheticGuide(Vec3(0, 0, 1));
    EXPECT_NEAR(guide.cellSolidAngle() * float(guide.cellCount()), 4.0f * kPi, 1e-4f);
    jobs::Rng rng(1, jobs::streamKey("env-cells"), 0);
    for (std::uint32_t c = 0; c < guide.cellCount(); ++c) {
        EXPECT_EQ(guide.cellOf(guide.cellCentre(c)), c);
        for (int k = 0; k < 20; ++k) {
            const Vec2 u(0.02f + 0.96f * rng.uniform(), 0.02f + 0.96f * rng.uniform());
            const Vec3 w = guide.directionInCell(c, u);
            EXPECT_NEAR(glm::length(w), 1.0f, 1e-5f);
            EXPECT_EQ(guide.cellOf(w), c);
        }
    }
}

TEST(EnvironmentGuide, DiskMapAndFrameAreConsistent) {
    const EnvironmentGuide guide = syntheticGuide(Vec3(0, 0, 1));
    jobs::Rng rng(2, jobs::streamKey("env-disk"), 0);
    for (int k = 0; k < 2000; ++k) {
        const Vec2 s(rng.uniform(), rng.uniform());
        const Vec2 d = squareToUnitDisk(s);
        EXPECT_LE(glm::length(d), 1.0f + 1e-5f);
        const Vec2 back = unitDiskToSquare(d);
        EXPECT_NEAR(back.x, s.x, 2e-4f);
        EXPECT_NEAR(back.y, s.y, 2e-4f);

        const std::uint32_t cell = static_cast<std::uint32_t>(k % guide.cellCount());
        const Vec3 w = guide.directionInCell(cell, Vec2(rng.uniform(), rng.uniform()));
        const Frame f = guide.diskFrame(cell, w);
        EXPECT_NEAR(glm::dot(f.s, f.t), 0.0f, 1e-5f);
        EXPECT_NEAR(glm::dot(f.s, w), 0.0f, 1e-5f);
        EXPECT_NEAR(glm::dot(f.t, w), 0.0f, 1e-5f);
        EXPECT_NEAR(glm::length(f.s), 1.0f, 1e-5f);
        EXPECT_GT(glm::dot(glm::cross(f.s, f.t), w), 0.99f);
        // The photon's start lies on the disk tangent to the bounding sphere on
        // the light's side, and the line back through it has the same disk point.
        const Vec3 origin = guide.diskOrigin(cell, w, d);
        EXPECT_NEAR(glm::dot(origin - guide.center, w), guide.radius, 1e-4f);
        const Vec2 again = guide.diskPoint(cell, w, origin - 0.7f * w);
        EXPECT_NEAR(again.x, d.x, 1e-4f);
        EXPECT_NEAR(again.y, d.y, 1e-4f);
    }
}

// The photon pass's direction density over the sphere: the product sampler
// alone and its mixture with the light's own density, for a constant sky and
// an image, integrate to one.
TEST(EnvironmentGuide, DirectionPdfIntegratesToOne) {
    const EnvironmentGuide guide = syntheticGuide(Vec3(0.3f, -0.2f, 1.0f));
    auto constant = makeConstantEnvironment(Rgb(1.0f));
    constant->setSceneBounds(Vec3(0.0f), 2.0f);
    for (const auto& light : {constant, gradientEnvironmentMap()}) {
        const EnvironmentSampler sampler(guide, *light);
        ASSERT_TRUE(sampler.usable());
        EXPECT_NEAR(integrateSphere([&](const Vec3& w) { return sampler.pdf(w); }), 1.0, 2e-3);
        const double mixture = integrateSphere([&](const Vec3& w) {
            return environmentDirectionPdf(0.5f, sampler.pdf(w), light->pdfLi(Vec3(0.0f), Vec3(0.0f), Vec3(0.0f), w));
        });
        EXPECT_NEAR(mixture, 1.0, 2e-3);
    }
}

// With a small sun: the product sampler alone and its mixture with p_L
// integrate to one (on a grid fine enough for the sun's 1.5°).
TEST(EnvironmentGuide, DirectionPdfIntegratesToOneWithASmallSun) {
    const EnvironmentGuide guide = syntheticGuide(kSun + Vec3(0.2f, 0.0f, -0.1f));
    const auto light = sunEnvironmentMap(kSun);
    const EnvironmentSampler sampler(guide, *light);
    ASSERT_TRUE(sampler.usable());
    const auto lightPdf = [&](const Vec3& w) { return light->pdfLi(Vec3(0.0f), Vec3(0.0f), Vec3(0.0f), w); };
    EXPECT_NEAR(integrateSphere([&](const Vec3& w) { return sampler.pdf(w); }, 2048, 4096), 1.0, 2e-3);
    EXPECT_NEAR(integrateSphere([&](const Vec3& w) { return environmentDirectionPdf(0.5f, sampler.pdf(w), lightPdf(w)); },
                                2048, 4096),
                1.0, 2e-3);
    // Most of what the product samples is sun: p_W is smooth around it.
    double inSun = 0.0;
    integrateSphere([&](const Vec3& w) {
        if (glm::dot(w, kSun) > std::cos(4.0f * kPi / 180.0f)) inSun += sampler.pdf(w);
        return 0.0;
    });
    EXPECT_GT(inSun * 4.0 * M_PI / (512.0 * 1024.0), 0.5);
}

// Where p_W is the same in every cell the product is p_L itself, direction by
// direction: the sampler follows the light's density within a cell (down to
// the sun's pixels) rather than a cell's mean.
TEST(EnvironmentGuide, ProductWithConstantImportanceIsTheLightsDensity) {
    EnvironmentGuide guide = syntheticGuide(kSun);
    for (float& d : guide.cells.column<EnvCellDensity>()) d = 2.0f;
    for (const auto& light : {sunEnvironmentMap(kSun), gradientEnvironmentMap()}) {
        const EnvironmentSampler sampler(guide, *light);
        ASSERT_TRUE(sampler.usable());
        jobs::Rng rng(4, jobs::streamKey("env-product-exact"), 0);
        for (int k = 0; k < 20000; ++k) {
            // Half the directions near the sun, half anywhere.
            const Vec3 w = k % 2 ? sampleUniformSphere(rng.uniform2())
                                 : glm::normalize(kSun + 0.05f * (sampleUniformSphere(rng.uniform2())));
            const float pL = light->pdfLi(Vec3(0.0f), Vec3(0.0f), Vec3(0.0f), w);
            EXPECT_NEAR(sampler.pdf(w), pL, 1e-4f * pL + 1e-7f) << w.x << " " << w.y << " " << w.z;
        }
    }
}

// Sampling the product with a small sun against its density.
TEST(EnvironmentGuide, Chi2DirectionSamplingWithASmallSun) {
    const EnvironmentGuide guide = syntheticGuide(kSun + Vec3(0.2f, 0.0f, -0.1f));
    const auto light = sunEnvironmentMap(kSun);
    const EnvironmentSampler sampler(guide, *light);
    test::Chi2Config config;
    config.samples = 400'000;
    const test::Chi2Result product = test::chi2SphereTest(
        [&](const Vec2& u) -> std::optional<Vec3> {
            float pdf = 0.0f;
            const std::optional<Vec3> w = sampler.sample(u, &pdf);
            if (w) {
                EXPECT_NEAR(pdf, sampler.pdf(*w), 1e-5f * pdf);
            }
            return w;
        },
        [&](const Vec3& w) { return double(sampler.pdf(w)); }, config);
    EXPECT_TRUE(product.passed) << product.message;
}

TEST(EnvironmentGuide, EmptyModelDoesNotGuide) {
    EnvironmentGuide empty;
    EXPECT_FALSE(empty.guides());
    EnvironmentGuide zero = syntheticGuide(Vec3(0, 0, 1));
    for (float& d : zero.cells.column<EnvCellDensity>()) d = 0.0f;
    EXPECT_FALSE(zero.guides());
    EXPECT_FALSE(EnvironmentSampler(zero, *makeConstantEnvironment(Rgb(1.0f))).usable());
}

// Sampling the product, and the mixture with the light's sampling, against
// their densities.
TEST(EnvironmentGuide, Chi2DirectionSampling) {
    const EnvironmentGuide guide = syntheticGuide(Vec3(0.3f, -0.2f, 1.0f));
    const auto light = gradientEnvironmentMap();
    const EnvironmentSampler sampler(guide, *light);
    test::Chi2Config config;
    config.samples = 400'000;
    config.testCount = 2;
    const test::Chi2Result product = test::chi2SphereTest(
        [&](const Vec2& u) -> std::optional<Vec3> {
            return sampler.sample(u);
        },
        [&](const Vec3& w) { return double(sampler.pdf(w)); }, config);
    EXPECT_TRUE(product.passed) << product.message;

    jobs::Rng strategy(config.seed, jobs::streamKey("env-chi2-strategy"), 0);
    const test::Chi2Result mixture = test::chi2SphereTest(
        [&](const Vec2& u) -> std::optional<Vec3> {
            if (strategy.uniform() < 0.5f) {
                return sampler.sample(u);
            }
            const std::optional<LightSample> ls = light->sampleLi(Vec3(0.0f), u);
            if (!ls) return std::nullopt;
            return ls->wi;
        },
        [&](const Vec3& w) {
            return double(environmentDirectionPdf(0.5f, sampler.pdf(w),
                                                  light->pdfLi(Vec3(0.0f), Vec3(0.0f), Vec3(0.0f), w)));
        },
        config);
    EXPECT_TRUE(mixture.passed) << mixture.message;
}

// The position density on the disk of radius R: the uniform part integrates
// to 1 − γ, the GMM part to γ times its mass inside the square.
TEST(EnvironmentGuide, PositionPdfIntegratesToOneMinusMassOutsideSquare) {
    const EnvironmentGuide guide = syntheticGuide(Vec3(0, 0, 1));
    const DirectionalGmm* gmm = guide.diskMixture(0);
    ASSERT_NE(gmm, nullptr);
    EXPECT_EQ(guide.diskMixture(1), nullptr);
    double inside = 0.0;
    const int n = 1000;
    for (int i = 0; i < n; ++i)
        for (int j = 0; j < n; ++j) inside += gmm->pdfSquare(Vec2((i + 0.5f) / n, (j + 0.5f) / n));
    inside /= double(n) * n;
    ASSERT_GT(inside, 0.8);
    ASSERT_LT(inside, 0.999);
    const float gamma = 0.5f, R = guide.radius;
    double integral = 0.0, uniform = 0.0;
    const int m = 1600;
    const double cell = (2.0 * R / m) * (2.0 * R / m);
    for (int i = 0; i < m; ++i) {
        for (int j = 0; j < m; ++j) {
            const Vec2 x(-R + 2.0f * R * (i + 0.5f) / m, -R + 2.0f * R * (j + 0.5f) / m);
            if (glm::length(x) >= R) continue;
            integral += environmentPositionPdf(gmm, gamma, x / R, R) * cell;
            uniform += environmentPositionPdf(nullptr, gamma, x / R, R) * cell;
        }
    }
    EXPECT_NEAR(uniform, 1.0, 3e-3);
    EXPECT_NEAR(integral, gamma * inside + (1.0 - gamma), 3e-3);
}

// Sampling positions as the photon pass does (the GMM with probability γ, a
// sample outside its square ending the photon; otherwise uniform), against
// the density: the unit disk is lifted to the hemisphere by the equal-area
// map of Shirley and Chiu (Jacobian 2: pdf_ω = pdf_unit disk / 2), where
// chi2SphereTest bins it.
TEST(EnvironmentGuide, Chi2PositionSampling) {
    const EnvironmentGuide guide = syntheticGuide(Vec3(0, 0, 1));
    const DirectionalGmm* gmm = guide.diskMixture(0);
    ASSERT_NE(gmm, nullptr);
    const float gamma = 0.5f, R = guide.radius;
    const auto lift = [](const Vec2& d) {
        const float r2 = std::min(1.0f, glm::dot(d, d));
        return Vec3(d * std::sqrt(2.0f - r2), 1.0f - r2);
    };
    test::Chi2Config config;
    config.samples = 400'000;
    jobs::Rng extra(config.seed, jobs::streamKey("env-chi2-disk"), 0);
    const test::Chi2Result result = test::chi2SphereTest(
        [&](const Vec2& u) -> std::optional<Vec3> {
            if (extra.uniform() < gamma) {
                const Vec2 s = gmm->samplePlane(extra.uniform(), u);
                if (!(s.x >= 0.0f && s.x <= 1.0f && s.y >= 0.0f && s.y <= 1.0f)) return std::nullopt;
                return lift(squareToUnitDisk(s));
            }
            return lift(sampleConcentricDisk(u));
        },
        [&](const Vec3& w) {
            if (w.z < 0.0f) return 0.0;
            const float r2 = 1.0f - w.z;
            const float scale = std::sqrt(std::max(1e-12f, 2.0f - r2));
            const Vec2 d(w.x / scale, w.y / scale);
            return double(environmentPositionPdf(gmm, gamma, d, R)) * R * R / 2.0;
        },
        config);
    EXPECT_TRUE(result.passed) << result.message;
}

// The model is saved and imported like the caches: it loads as saved, and a
// truncated file or another codec version is refused.
TEST(EnvironmentGuideCodec, LoadsAsSavedAndRefusesDamage) {
    const std::filesystem::path dir = test::scratchDirectory("environment-guide-codec");
    auto guide = std::make_shared<EnvironmentGuide>(syntheticGuide(Vec3(0.0f, 0.4f, 1.0f)));
    guide->kernelCap = 0.01f;
    BufferHandle handle;
    handle.type = BufferTypeName<EnvironmentGuide>::value;
    handle.bytes = [raw = guide.get()] { return raw->bytes(); };
    handle.data = guide;
    const std::string path = (dir / "model.fgbuf").string();
    saveBuffer(handle, path, "");
    const BufferHandle loaded = loadBuffer(path, "EnvironmentGuide");
    const auto& back = *static_cast<const EnvironmentGuide*>(loaded.data.get());
    EXPECT_EQ(back.columns, guide->columns);
    EXPECT_EQ(back.rows, guide->rows);
    EXPECT_EQ(back.center, guide->center);
    EXPECT_EQ(back.radius, guide->radius);
    EXPECT_EQ(back.kernelCap, guide->kernelCap);
    ASSERT_EQ(back.cells.size(), guide->cells.size());
    for (std::uint32_t c = 0; c < guide->cellCount(); ++c) {
        EXPECT_EQ(back.cells.column<EnvCellDensity>()[c], guide->cells.column<EnvCellDensity>()[c]);
        EXPECT_EQ(back.diskMixture(c) != nullptr, guide->diskMixture(c) != nullptr);
        if (guide->diskMixture(c)) {
            EXPECT_EQ(back.diskMixture(c)->pdfSquare(Vec2(0.4f, 0.5f)), guide->diskMixture(c)->pdfSquare(Vec2(0.4f, 0.5f)));
        }
    }
    const std::string bytes = test::readText(path);
    const std::string cut = (dir / "cut.fgbuf").string();
    for (std::size_t length = 0; length < bytes.size(); length += std::max<std::size_t>(1, bytes.size() / 97)) {
        std::ofstream(cut, std::ios::binary) << bytes.substr(0, length);
        EXPECT_THROW(loadBuffer(cut, "EnvironmentGuide"), InputError) << "cut to " << length;
    }
    // The codec version is the payload's first u32, after the header: find and change it.
    const std::string version("\x01\x00\x00\x00\x10\x00\x00\x00\x08\x00\x00\x00", 12);
    const std::size_t at = bytes.find(version);
    ASSERT_NE(at, std::string::npos);
    std::string other = bytes;
    other[at] = 2;
    std::ofstream(cut, std::ios::binary) << other;
    EXPECT_NE(test::inputErrorOf([&] { loadBuffer(cut, "EnvironmentGuide"); })
                  .find("an environment sampler of codec version 2 (this build reads version 1)"),
              std::string::npos);
}

}  // namespace
}  // namespace fg
