// The projector, the textured spot and textured area emitters: their
// conventions (Mitsuba's uv and scale), direction sampling against its density
// (chi-square), and the agreement of photon fluxes with next-event values.
#include "engine/shading/light.h"

#include "jobs/random.h"
#include "tests/support/chi2.h"

#include <glm/gtc/matrix_transform.hpp>
#include <gtest/gtest.h>

#include <cmath>
#include <vector>

namespace fg {
namespace {

// A small image with a dark column and distinct colours, so that lookups and
// densities are not accidentally symmetric.
RgbImage testImage() {
    RgbImage image;
    image.width = 4;
    image.height = 3;
    for (int y = 0; y < image.height; ++y)
        for (int x = 0; x < image.width; ++x)
            image.pixels.push_back(x == 3 ? Rgb(0.0f) : Rgb(0.2f + 0.3f * x, 0.1f + 0.4f * y, 0.5f + 0.1f * (x + y)));
    return image;
}

Mat4 placement() {
    Mat4 m = glm::translate(Mat4(1.0f), Vec3(0.5f, -1.0f, 2.0f));
    m = m * glm::rotate(Mat4(1.0f), 0.7f, glm::normalize(Vec3(1.0f, 2.0f, -0.5f)));
    return m;
}

void expectRgbNear(const Rgb& a, const Rgb& b, float relative, const std::string& what) {
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(a[c], b[c], relative * std::max(1e-3f, std::abs(b[c]))) << what << " channel " << c;
}

// ---- projector ---------------------------------------------------------------------------

TEST(ProjectorLight, IrradianceOnTheImagePlaneIsPiScaleTexture) {
    const auto texture = makeBitmapTexture(testImage());
    const float tanHalfX = 0.8f, scale = 2.5f;
    const Mat4 toWorld = placement();
    const auto light = makeProjectorLight(toWorld, texture, 4, 3, tanHalfX, scale);
    const float halfY = tanHalfX * 3.0f / 4.0f;
    const Mat3 linear(toWorld);
    for (const Vec2 uv : {Vec2(0.1f, 0.2f), Vec2(0.5f, 0.5f), Vec2(0.85f, 0.9f), Vec2(0.3f, 0.7f)}) {
        // u = 0 is the frustum's +x edge, v = 0 its +y edge.
        const Vec3 local((1.0f - 2.0f * uv.x) * tanHalfX, (1.0f - 2.0f * uv.y) * halfY, 1.0f);
        for (float depth : {1.0f, 3.0f}) {
            const Vec3 p = Vec3(toWorld * Vec4(depth * local, 1.0f));
            const auto s = light->sampleLi(p, Vec2(0.5f));
            ASSERT_TRUE(s.has_value());
            // Irradiance on a plane facing the projector at this depth: I cos / d^2 with the plane's cosine.
            const float cosPlane = glm::dot(-s->wi, glm::normalize(linear[2]));
            const Rgb irradiance = s->value * cosPlane * depth * depth;
            expectRgbNear(irradiance, kPi * scale * texture->eval(uv), 1e-4f, "depth " + std::to_string(depth));
        }
    }
    // Outside the frustum and behind the projector: nothing.
    EXPECT_FALSE(light->sampleLi(Vec3(toWorld * Vec4(2.0f * tanHalfX, 0.0f, 1.0f, 1.0f)), Vec2(0.5f)).has_value());
    EXPECT_FALSE(light->sampleLi(Vec3(toWorld * Vec4(0.0f, 0.0f, -1.0f, 1.0f)), Vec2(0.5f)).has_value());
}

TEST(ProjectorLight, EmissionDirectionsMatchTheirDensityChi2) {
    const Mat4 toWorld = placement();
    const auto textured = makeProjectorLight(toWorld, makeBitmapTexture(testImage()), 4, 3, 0.8f, 1.0f);
    const auto constant = makeProjectorLight(toWorld, makeConstantTexture(Rgb(1.0f)), 1, 1, 1.5f, 1.0f);
    for (const auto& light : {textured, constant}) {
        test::Chi2Config config;
        config.testCount = 2;
        config.samples = 300'000;
        const auto result = test::chi2SphereTest(
            [&](const Vec2& u) -> std::optional<Vec3> {
                const auto e = light->sampleEmission(Vec2(0.5f), u);
                if (!e) return std::nullopt;
                return e->direction;
            },
            [&](const Vec3& w) -> double { return light->emissionDirectionPdf(w); }, config);
        EXPECT_TRUE(result.passed) << result.message;
    }
}

TEST(ProjectorLight, PhotonFluxesAgreeWithIntensityAndPower) {
    const Mat4 toWorld = placement();
    const auto light = makeProjectorLight(toWorld, makeBitmapTexture(testImage()), 4, 3, 0.8f, 1.5f);
    jobs::Rng rng(7, jobs::streamKey("projector-test"), 0);
    glm::dvec3 sum(0.0);
    constexpr int kSamples = 200'000;
    for (int i = 0; i < kSamples; ++i) {
        const auto e = light->sampleEmission(rng.uniform2(), rng.uniform2());
        ASSERT_TRUE(e.has_value());
        sum += glm::dvec3(e->flux);
        if (i < 50) {
            // flux * pdf is the intensity, which next-event estimation sees as value * d^2.
            const float distance = 2.0f;
            const auto s = light->sampleLi(e->origin + distance * e->direction, Vec2(0.5f));
            ASSERT_TRUE(s.has_value());
            expectRgbNear(e->flux * e->pdfDirection, s->value * distance * distance, 1e-3f, "intensity");
            EXPECT_NEAR(e->pdfDirection, light->emissionDirectionPdf(e->direction), 1e-3f * e->pdfDirection);
        }
    }
    // Power: pi * scale * (plane area 4ab) * mean texture, as the photons carry it on average.
    const Rgb power = light->power();
    expectRgbNear(Rgb(sum / double(kSamples)), power, 0.01f, "mean photon flux");
    const float planeArea = 4.0f * 0.8f * 0.6f;
    expectRgbNear(power, makeBitmapTexture(testImage())->mean() * (kPi * 1.5f * planeArea), 1e-5f, "power");
}

// ---- textured spot -----------------------------------------------------------------------

TEST(TexturedSpotLight, TextureScalesTheFalloffWithMitsubasUv) {
    const Mat4 toWorld = placement();
    const Mat3 linear(toWorld);
    const auto texture = makeBitmapTexture(testImage());
    const float cutoff = 30.0f, beam = 20.0f;
    const auto textured = makeTexturedSpotLight(toWorld, Rgb(3.0f), cutoff, beam, texture);
    const auto plain = makeSpotLight(Vec3(toWorld[3]), linear[2], Rgb(3.0f), cutoff, beam);
    const float uvFactor = std::tan(glm::radians(cutoff));
    for (const Vec3 local : {Vec3(0.1f, 0.2f, 1.0f), Vec3(-0.3f, 0.1f, 1.0f), Vec3(0.0f, -0.5f, 1.0f), Vec3(0.2f, 0.3f, 0.8f)}) {
        const Vec3 p = Vec3(toWorld * Vec4(2.0f * local, 1.0f));
        const auto a = textured->sampleLi(p, Vec2(0.5f));
        const auto b = plain->sampleLi(p, Vec2(0.5f));
        ASSERT_EQ(a.has_value(), b.has_value());
        if (!a) continue;
        const Vec2 uv(0.5f + 0.5f * local.x / (local.z * uvFactor), 0.5f + 0.5f * local.y / (local.z * uvFactor));
        expectRgbNear(a->value, b->value * texture->eval(uv), 1e-4f, "textured value");
    }
}

TEST(TexturedSpotLight, PhotonsCarryTheTextureAndMatchPower) {
    const Mat4 toWorld = placement();
    const auto light = makeTexturedSpotLight(toWorld, Rgb(2.0f), 35.0f, 25.0f, makeBitmapTexture(testImage()));
    test::Chi2Config config;
    config.samples = 300'000;
    const auto result = test::chi2SphereTest(
        [&](const Vec2& u) -> std::optional<Vec3> {
            const auto e = light->sampleEmission(Vec2(0.5f), u);
            if (!e) return std::nullopt;
            return e->direction;
        },
        [&](const Vec3& w) -> double { return light->emissionDirectionPdf(w); }, config);
    EXPECT_TRUE(result.passed) << result.message;

    jobs::Rng rng(11, jobs::streamKey("spot-test"), 0);
    glm::dvec3 sum(0.0);
    constexpr int kSamples = 200'000;
    for (int i = 0; i < kSamples; ++i) {
        const auto e = light->sampleEmission(rng.uniform2(), rng.uniform2());
        if (!e) continue;
        sum += glm::dvec3(e->flux);
        if (i < 50) {
            const auto s = light->sampleLi(e->origin + 3.0f * e->direction, Vec2(0.5f));
            const Rgb intensity = s ? s->value * 9.0f : Rgb(0.0f);
            expectRgbNear(e->flux * e->pdfDirection, intensity, 1e-3f, "intensity");
        }
    }
    expectRgbNear(Rgb(sum / double(kSamples)), light->power(), 0.01f, "mean photon flux");
}

// ---- textured area emitters ----------------------------------------------------------------

TEST(TexturedAreaLight, RadianceFollowsTheShapesUv) {
    Shape rectangle;
    TriangleMesh mesh = makeRectangleMesh();  // uv = ((x + 1) / 2, (y + 1) / 2), facing +z
    mesh.transform(glm::scale(Mat4(1.0f), Vec3(2.0f, 1.0f, 1.0f)));
    rectangle.geometry = mesh;
    const auto texture = makeBitmapTexture(testImage());
    const auto light = makeTexturedAreaLight(rectangle, texture);
    const Vec3 n(0.0f, 0.0f, 1.0f);
    EXPECT_EQ(light->emittedAt(n, n, Vec2(0.3f, 0.6f)), texture->eval(Vec2(0.3f, 0.6f)));
    EXPECT_EQ(light->emittedAt(n, -n, Vec2(0.3f, 0.6f)), Rgb(0.0f)) << "front side only";
    jobs::Rng rng(3, jobs::streamKey("area-test"), 0);
    const Vec3 ref(0.3f, -0.2f, 2.0f);
    glm::dvec3 sum(0.0);
    constexpr int kSamples = 100'000;
    for (int i = 0; i < kSamples; ++i) {
        const Vec2 u = rng.uniform2();
        const auto s = light->sampleLi(ref, u);
        ASSERT_TRUE(s.has_value());
        const Vec2 uv((s->p.x / 2.0f + 1.0f) / 2.0f, (s->p.y + 1.0f) / 2.0f);
        if (i < 50) expectRgbNear(s->value, texture->eval(uv), 1e-4f, "next-event radiance");
        const auto e = light->sampleEmission(u, rng.uniform2());
        ASSERT_TRUE(e.has_value());
        const Vec2 uvOrigin((e->origin.x / 2.0f + 1.0f) / 2.0f, (e->origin.y + 1.0f) / 2.0f);
        // One-sided diffuse: flux = L * pi * area.
        if (i < 50) expectRgbNear(e->flux, texture->eval(uvOrigin) * (kPi * 8.0f), 1e-4f, "photon flux");
        sum += glm::dvec3(e->flux);
    }
    // The photons' mean is the exact power, pi * area * mean radiance, which power() reports too.
    expectRgbNear(Rgb(sum / double(kSamples)), texture->mean() * (kPi * 8.0f), 0.01f, "mean photon flux");
    expectRgbNear(light->power(), texture->mean() * (kPi * 8.0f), 1e-5f, "power");
}

}  // namespace
}  // namespace fg
