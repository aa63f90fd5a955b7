// Texture lookups: uv maps with offsets and rotations, wrap modes, nearest and
// bilinear filtering, and the scalar gradient bump mapping reads.
#include "engine/shading/texture.h"

#include <gtest/gtest.h>

#include <cmath>
#include <string>

namespace fg {
namespace {

// 4 x 2 texels (top row first), each its own colour.
Rgb texelColour(int x, int y) { return Rgb(0.1f * static_cast<float>(x + 1), 0.5f * static_cast<float>(y), 0.25f); }

RgbImage texels() {
    RgbImage image;
    image.width = 4;
    image.height = 2;
    for (int y = 0; y < 2; ++y)
        for (int x = 0; x < 4; ++x) image.pixels.push_back(texelColour(x, y));
    return image;
}

void expectNear(const Rgb& a, const Rgb& b, float tolerance, const std::string& what) {
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(a[c], b[c], tolerance) << what << " component " << c;
}

// uv' = R(30 deg) * diag(2, 1) * uv + (0.1, -0.3), by hand.
UvTransform rotatedScaledShifted() {
    const float c = std::cos(kPi / 6.0f), s = std::sin(kPi / 6.0f);
    UvTransform t;
    t.linear = glm::mat2(2.0f * c, 2.0f * s, -s, c);  // columns: R * (2, 0) and R * (0, 1)
    t.offset = Vec2(0.1f, -0.3f);
    return t;
}

TEST(UvTransform, AppliesLinearPartThenOffsetAndComposes) {
    const UvTransform t = rotatedScaledShifted();
    const Vec2 uv(0.4f, 0.7f);
    const float c = std::cos(kPi / 6.0f), s = std::sin(kPi / 6.0f);
    const Vec2 expected(c * 0.8f - s * 0.7f + 0.1f, s * 0.8f + c * 0.7f - 0.3f);
    EXPECT_NEAR(t.apply(uv).x, expected.x, 1e-6f);
    EXPECT_NEAR(t.apply(uv).y, expected.y, 1e-6f);
    const UvTransform twice = UvTransform::scale(Vec2(3.0f, 5.0f)).after(t);
    EXPECT_NEAR(twice.apply(uv).x, 3.0f * expected.x, 1e-5f);
    EXPECT_NEAR(twice.apply(uv).y, 5.0f * expected.y, 1e-5f);
}

TEST(BitmapTexture, NearestLookupThroughARotationAndOffset) {
    BitmapLookup lookup;
    lookup.filter = TextureFilter::Nearest;
    lookup.toUv = rotatedScaledShifted();
    const auto texture = makeBitmapTexture(texels(), lookup);
    // uv (0.4, 0.7) -> uv' = (0.6928 - 0.35 + 0.1, 0.4 + 0.6062 - 0.3) = (0.4428, 0.7062):
    // column floor(4 u') = 1; v' is in the upper half, v = 0 being the bottom row: row 0.
    expectNear(texture->eval(Vec2(0.4f, 0.7f)), texelColour(1, 0), 0.0f, "inside");
    // uv (0.1, 0.2) -> uv' = (0.1732 - 0.1 + 0.1, 0.1 + 0.1732 - 0.3) = (0.1732, -0.0268):
    // column 0, and v' < 0 lies below the bottom row: repeat wraps to the top row.
    expectNear(texture->eval(Vec2(0.1f, 0.2f)), texelColour(0, 0), 0.0f, "wrapped in v");
}

TEST(BitmapTexture, WrapModesOutsideTheImage) {
    const auto at = [](TextureWrap wrap, const Vec2& uv) {
        BitmapLookup lookup;
        lookup.filter = TextureFilter::Nearest;
        lookup.wrapU = wrap;
        lookup.wrapV = wrap;
        return makeBitmapTexture(texels(), lookup)->eval(uv);
    };
    // u = -0.3 -> column floor(-1.2) = -2; u = 1.6 -> column 6; v = 0.75 -> row 0.
    expectNear(at(TextureWrap::Repeat, Vec2(-0.3f, 0.75f)), texelColour(2, 0), 0.0f, "repeat -2");
    expectNear(at(TextureWrap::Mirror, Vec2(-0.3f, 0.75f)), texelColour(1, 0), 0.0f, "mirror -2");
    expectNear(at(TextureWrap::Clamp, Vec2(-0.3f, 0.75f)), texelColour(0, 0), 0.0f, "clamp -2");
    expectNear(at(TextureWrap::Repeat, Vec2(1.6f, 0.75f)), texelColour(2, 0), 0.0f, "repeat 6");
    expectNear(at(TextureWrap::Mirror, Vec2(1.6f, 0.75f)), texelColour(1, 0), 0.0f, "mirror 6");
    expectNear(at(TextureWrap::Clamp, Vec2(1.6f, 0.75f)), texelColour(3, 0), 0.0f, "clamp 6");
    // v = -0.25 -> one row below the bottom: repeat gives the top row, mirror the bottom one.
    expectNear(at(TextureWrap::Repeat, Vec2(0.1f, -0.25f)), texelColour(0, 0), 0.0f, "repeat below");
    expectNear(at(TextureWrap::Mirror, Vec2(0.1f, -0.25f)), texelColour(0, 1), 0.0f, "mirror below");
}

TEST(BitmapTexture, BilinearClampBlendsOnlyInsideTexels) {
    BitmapLookup lookup;
    lookup.wrapU = TextureWrap::Clamp;
    lookup.wrapV = TextureWrap::Clamp;
    const auto texture = makeBitmapTexture(texels(), lookup);
    // At the left edge of the image the clamped neighbour is the texel itself.
    expectNear(texture->eval(Vec2(0.0f, 0.75f)), texelColour(0, 0), 1e-6f, "edge");
    // Halfway between the centres of columns 1 and 2 and of both rows.
    expectNear(texture->eval(Vec2(0.5f, 0.5f)),
               0.25f * (texelColour(1, 0) + texelColour(2, 0) + texelColour(1, 1) + texelColour(2, 1)), 1e-6f,
               "centre");
}

TEST(BitmapTexture, ScalarGradientIsTheBilinearSlope) {
    BitmapLookup lookup;
    lookup.toUv = rotatedScaledShifted();
    const auto texture = makeBitmapTexture(texels(), lookup);
    // Away from texel-centre lines the interpolant is smooth: central differences agree.
    for (const Vec2 uv : {Vec2(0.4f, 0.7f), Vec2(0.13f, 0.29f), Vec2(0.77f, 0.52f)}) {
        constexpr float h = 1e-3f;
        const Vec2 numeric((texture->evalScalar(uv + Vec2(h, 0)) - texture->evalScalar(uv - Vec2(h, 0))) / (2 * h),
                           (texture->evalScalar(uv + Vec2(0, h)) - texture->evalScalar(uv - Vec2(0, h))) / (2 * h));
        const Vec2 analytic = texture->scalarGradient(uv);
        EXPECT_NEAR(analytic.x, numeric.x, 2e-2f * (1.0f + std::abs(numeric.x))) << uv.x << ", " << uv.y;
        EXPECT_NEAR(analytic.y, numeric.y, 2e-2f * (1.0f + std::abs(numeric.y))) << uv.x << ", " << uv.y;
    }
    EXPECT_EQ(makeConstantTexture(Rgb(0.3f))->scalarGradient(Vec2(0.2f)), Vec2(0.0f));
}

TEST(CheckerboardTexture, CellsFollowTheTransform) {
    // Mitsuba's checkerboard: cells of half a unit after to_uv, here a 90 degree rotation.
    UvTransform rotate;
    rotate.linear = glm::mat2(0.0f, 1.0f, -1.0f, 0.0f);  // (u, v) -> (-v, u)
    const auto texture = makeCheckerboardTexture(Rgb(1.0f), Rgb(0.0f), UvTransform::scale(Vec2(2.0f)).after(rotate));
    // uv (0.1, 0.3) -> (-0.3, 0.1) -> cells (-1, 0): odd.
    EXPECT_EQ(texture->eval(Vec2(0.1f, 0.3f)).x, 0.0f);
    // uv (0.6, 0.3) -> (-0.3, 0.6) -> cells (-1, 1): even.
    EXPECT_EQ(texture->eval(Vec2(0.6f, 0.3f)).x, 1.0f);
}

}  // namespace
}  // namespace fg
