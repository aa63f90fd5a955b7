// Image comparison metrics on small images whose answers are worked out by
// hand: identical images, constant offsets, a relMSE sum written out term by
// term, SSIM of constant images in closed form, crops, size mismatches, the
// heatmap's colours and the reading of sRGB-encoded files. (SSIM on textured
// images is checked against scikit-image by tests/tools/check_ssim.py.)
#include "engine/image/image_compare.h"

#include "engine/core/error.h"
#include "tests/support/cli_helpers.h"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <limits>
#include <random>

namespace fg {
namespace {

namespace fs = std::filesystem;

fs::path scratchDirectory() { return test::scratchDirectory("image_compare"); }

ImageChannels filled(int width, int height, const Rgb& value) {
    ImageChannels image;
    image.width = width;
    image.height = height;
    image.rgb.assign(static_cast<std::size_t>(width) * static_cast<std::size_t>(height), value);
    return image;
}

ImageChannels randomImage(int width, int height, std::uint32_t seed, float maxValue = 2.0f) {
    std::mt19937 rng(seed);
    std::uniform_real_distribution<float> value(0.0f, maxValue);
    ImageChannels image = filled(width, height, Rgb(0.0f));
    for (Rgb& p : image.rgb) p = Rgb(value(rng), value(rng), value(rng));
    return image;
}

Rgb& pixel(ImageChannels& image, int x, int y) {
    return image.rgb[static_cast<std::size_t>(y) * static_cast<std::size_t>(image.width) + static_cast<std::size_t>(x)];
}

TEST(ImageCompare, IdenticalImagesHaveZeroErrorAndSsimOne) {
    const ImageChannels image = randomImage(23, 17, 7);
    const ImageMetrics m = compareImages(image, image);
    EXPECT_EQ(m.rmse, 0.0);
    EXPECT_EQ(m.relmse, 0.0);
    EXPECT_EQ(m.mae, 0.0);
    EXPECT_NEAR(m.ssim, 1.0, 1e-12);
    EXPECT_EQ(m.psnr, std::numeric_limits<double>::infinity());
}

TEST(ImageCompare, ConstantOffsetGivesExactRmseMaeAndPsnr) {
    // Values on a 1/64 grid, so that reference + 0.25 is exact in float.
    ImageChannels reference = filled(16, 8, Rgb(0.0f));
    for (std::size_t i = 0; i < reference.rgb.size(); ++i) {
        const float k = static_cast<float>(i % 128);
        reference.rgb[i] = Rgb(k / 64.0f, (127.0f - k) / 64.0f, static_cast<float>(i % 5) / 64.0f);
    }
    ImageChannels test = reference;
    for (Rgb& p : test.rgb) p += Rgb(0.25f);
    const ImageMetrics m = compareImages(test, reference);
    EXPECT_DOUBLE_EQ(m.rmse, 0.25);
    EXPECT_DOUBLE_EQ(m.mae, 0.25);
    EXPECT_NEAR(m.psnr, -20.0 * std::log10(0.25), 1e-12);  // 12.0412 dB for peak 1

    double relative = 0.0;
    for (const Rgb& r : reference.rgb)
        for (int c = 0; c < 3; ++c) relative += 0.0625 / ((r[c] + 0.01) * (r[c] + 0.01));
    EXPECT_NEAR(m.relmse, relative / (3.0 * static_cast<double>(reference.rgb.size())), 1e-12 * m.relmse);

    // A negative offset of the same size is the same error.
    ImageChannels below = reference;
    for (Rgb& p : below.rgb) p -= Rgb(0.25f);
    EXPECT_DOUBLE_EQ(compareImages(below, reference).rmse, 0.25);
}

TEST(ImageCompare, RelMseWorkedByHand) {
    // Per channel (v - r)^2 / (r + 0.01)^2:
    //   pixel 0  v (1.99, 0.49, 0.01)  r (0.99, 0.49, 0)     ->  1/1^2, 0, 0.01^2/0.01^2 = 1, 0, 1
    //   pixel 1  v (0.99, 0.19, 3.99)  r (1.99, 0.09, 3.99)  ->  1/2^2, 0.1^2/0.1^2, 0 = 0.25, 1, 0
    // relMSE = 3.25 / 6; MAE = (1 + 0.01 + 1 + 0.1) / 6; RMSE = sqrt((1 + 1e-4 + 1 + 0.01) / 6).
    ImageChannels reference = filled(2, 1, Rgb(0.0f));
    ImageChannels test = reference;
    reference.rgb = {Rgb(0.99f, 0.49f, 0.0f), Rgb(1.99f, 0.09f, 3.99f)};
    test.rgb = {Rgb(1.99f, 0.49f, 0.01f), Rgb(0.99f, 0.19f, 3.99f)};
    const ImageMetrics m = compareImages(test, reference);
    EXPECT_NEAR(m.relmse, 3.25 / 6.0, 1e-5);
    EXPECT_NEAR(m.mae, 2.11 / 6.0, 1e-6);
    EXPECT_NEAR(m.rmse, std::sqrt(2.0101 / 6.0), 1e-6);
    // Worst pixel: pixel 0's mean over its channels, 2 / 3 (pixel 1's is 1.25 / 3).
    EXPECT_NEAR(m.worstRelse, 2.0 / 3.0, 1e-5);
    // relMSE divides by the reference, not the test image: swapping them changes it.
    EXPECT_GT(std::abs(compareImages(reference, test).relmse - m.relmse), 0.1);
}

TEST(ImageCompare, SsimOfConstantImagesMatchesClosedForm) {
    // Constant images: variances and covariance vanish, so SSIM is the luminance
    // term (2 a b + C1) / (a^2 + b^2 + C1) of the tone-mapped values
    // a = 1 / (1 + 1) and b = 3 / (1 + 3), with C1 = (0.01 * 1)^2.
    const ImageChannels reference = filled(15, 13, Rgb(1.0f));
    const ImageChannels test = filled(15, 13, Rgb(3.0f));
    const double a = 0.5, b = 0.75, c1 = 1e-4;
    EXPECT_NEAR(compareImages(test, reference).ssim, (2.0 * a * b + c1) / (a * a + b * b + c1), 1e-9);
    EXPECT_NEAR(ssimToneMappedLuminance(Rgb(3.0f)), 0.75, 1e-12);
    EXPECT_EQ(ssimToneMappedLuminance(Rgb(-2.0f)), 0.0);
    EXPECT_EQ(ssimToneMappedLuminance(Rgb(std::numeric_limits<float>::infinity())), 1.0);
}

TEST(ImageCompare, SsimSeesRec709LuminanceOnly) {
    // Pure red, green or blue pixels of luminance 1 against grey 1: same Y, so
    // SSIM is 1 while the RGB errors are large. (A mean over channels would differ.)
    const ImageChannels reference = filled(12, 12, Rgb(1.0f));
    for (const Rgb& colour :
         {Rgb(1.0f / 0.2126f, 0.0f, 0.0f), Rgb(0.0f, 1.0f / 0.7152f, 0.0f), Rgb(0.0f, 0.0f, 1.0f / 0.0722f)}) {
        const ImageMetrics m = compareImages(filled(12, 12, colour), reference);
        EXPECT_NEAR(m.ssim, 1.0, 1e-6);
        EXPECT_GT(m.rmse, 0.5);
    }
}

TEST(ImageCompare, SsimFallsWithNoiseAndKeepsHighlightStructure) {
    const ImageChannels reference = randomImage(32, 24, 11, 1.0f);
    double previous = 1.0;
    for (float amplitude : {0.05f, 0.2f, 0.8f}) {
        ImageChannels noisy = reference;
        std::mt19937 rng(3);
        std::normal_distribution<float> noise(0.0f, amplitude);
        for (Rgb& p : noisy.rgb) p = glm::max(p + Rgb(noise(rng), noise(rng), noise(rng)), Rgb(0.0f));
        const double ssim = compareImages(noisy, reference).ssim;
        EXPECT_LT(ssim, previous) << "amplitude " << amplitude;
        EXPECT_GT(ssim, -1.0);
        previous = ssim;
    }
    // A highlight at 2 against one at 4: clipping to [0, 1] would call them
    // equal; Y / (1 + Y) (0.67 against 0.8) still tells them apart.
    ImageChannels dim = filled(20, 20, Rgb(0.2f));
    ImageChannels bright = dim;
    for (int y = 8; y < 12; ++y)
        for (int x = 8; x < 12; ++x) {
            pixel(dim, x, y) = Rgb(2.0f);
            pixel(bright, x, y) = Rgb(4.0f);
        }
    EXPECT_LT(compareImages(bright, dim).ssim, 0.99);
}

TEST(ImageCompare, SsimNeedsElevenByElevenPixels) {
    const ImageChannels a = randomImage(10, 30, 1), b = randomImage(10, 30, 2);
    const ImageMetrics m = compareImages(a, b);
    EXPECT_TRUE(std::isnan(m.ssim));
    EXPECT_GT(m.rmse, 0.0);  // the other metrics do not need a window
    EXPECT_FALSE(std::isnan(compareImages(randomImage(11, 11, 1), randomImage(11, 11, 2)).ssim));
}

TEST(ImageCompare, CropSelectsTheRectangleFromTheTopLeft) {
    const ImageChannels reference = randomImage(9, 7, 5);
    const CropRect crop{2, 1, 4, 3};  // columns 2..5, rows 1..3
    ImageChannels test = reference;
    // Differences just outside the rectangle on every side must not count.
    pixel(test, 1, 2) += Rgb(9.0f);
    pixel(test, 6, 2) += Rgb(9.0f);
    pixel(test, 3, 0) += Rgb(9.0f);
    pixel(test, 3, 4) += Rgb(9.0f);
    ImageMetrics m = compareImages(test, reference, crop);
    EXPECT_EQ(m.rmse, 0.0);
    EXPECT_EQ(m.mae, 0.0);
    EXPECT_GT(compareImages(test, reference).rmse, 0.0);

    // One pixel inside (its far corner) off by 0.5 in every channel: MAE = 0.5 / 12.
    test = reference;
    pixel(test, 5, 3) += Rgb(0.5f);
    m = compareImages(test, reference, crop);
    EXPECT_NEAR(m.mae, 0.5 / 12.0, 1e-7);
    EXPECT_NEAR(m.rmse, std::sqrt(0.25 / 12.0), 1e-7);
}

TEST(ImageCompare, RejectsMismatchedSizesAndCropsOutsideTheImage) {
    const ImageChannels a = randomImage(8, 6, 1);
    EXPECT_THROW(compareImages(a, randomImage(6, 8, 1)), InputError);
    EXPECT_THROW(compareImages(a, randomImage(8, 7, 1)), InputError);
    for (const CropRect& crop : {CropRect{0, 0, 9, 6}, CropRect{0, 0, 8, 7}, CropRect{5, 0, 4, 2},
                                 CropRect{-1, 0, 2, 2}, CropRect{0, -1, 2, 2}, CropRect{0, 0, 0, 3},
                                 CropRect{2, 2, 3, -1}, CropRect{1, 1, 2147483647, 1}})
        EXPECT_THROW(compareImages(a, a, crop), InputError)
            << crop.x << "," << crop.y << "," << crop.width << "," << crop.height;
    EXPECT_NO_THROW(compareImages(a, a, CropRect{0, 0, 8, 6}));
    EXPECT_NO_THROW(compareImages(a, a, CropRect{7, 5, 1, 1}));
    ImageChannels broken = a;
    broken.rgb.pop_back();
    EXPECT_THROW(compareImages(broken, a), InputError);
}

TEST(ImageCompare, NonFiniteValuesAreNotHidden) {
    const ImageChannels reference = randomImage(12, 12, 3);
    ImageChannels test = reference;
    pixel(test, 4, 4).y = std::numeric_limits<float>::quiet_NaN();
    const ImageMetrics m = compareImages(test, reference);
    EXPECT_TRUE(std::isnan(m.rmse));
    EXPECT_TRUE(std::isnan(m.mae));
    EXPECT_TRUE(std::isnan(m.ssim));
}

// The heatmap's 8-bit colour at a pixel, as the PNG will store it.
Rgb heatmapBytes(const ImageChannels& heatmap, std::size_t index) {
    const auto encode = [](float linear) {
        const float e = linear <= 0.0031308f ? 12.92f * linear : 1.055f * std::pow(linear, 1.0f / 2.4f) - 0.055f;
        return std::round(e * 255.0f);
    };
    const Rgb& p = heatmap.rgb[index];
    return Rgb(encode(p.x), encode(p.y), encode(p.z));
}

TEST(ImageCompare, HeatmapRampRunsFromBlackToPaleYellowWithErrorOnALogScale) {
    // Reference 1 everywhere; pixel i off by a relative error of 10^(i-4), i = 0..5,
    // then one nan pixel. Relative error of a pixel = |v - r| / (r + 0.01).
    const int count = 7;
    const ImageChannels reference = filled(count, 1, Rgb(1.0f));
    ImageChannels test = reference;
    for (int i = 0; i < 6; ++i) test.rgb[static_cast<std::size_t>(i)] += Rgb(1.01f * std::pow(10.0f, i - 4.0f));
    test.rgb[6] = Rgb(std::numeric_limits<float>::quiet_NaN());
    const ImageChannels heatmap = relativeErrorHeatmap(test, reference);
    ASSERT_EQ(heatmap.width, count);
    ASSERT_EQ(heatmap.height, 1);
    EXPECT_EQ(heatmapBytes(heatmap, 0), Rgb(0.0f));                 // 1e-4: below the 1e-3 floor
    EXPECT_EQ(heatmapBytes(heatmap, 4), Rgb(255.0f, 255.0f, 220.0f));  // 1: the top of the ramp
    EXPECT_EQ(heatmapBytes(heatmap, 5), Rgb(255.0f, 255.0f, 220.0f));  // 10: clamped
    EXPECT_EQ(heatmapBytes(heatmap, 6), Rgb(0.0f, 255.0f, 255.0f));    // nan: cyan, off the ramp
    // Brightness grows with the error along the ramp.
    float previous = -1.0f;
    for (double e = 1e-3; e <= 1.0001; e *= std::pow(10.0, 0.25)) {
        const ImageChannels one = relativeErrorHeatmap(filled(1, 1, Rgb(1.0f + static_cast<float>(1.01 * e))),
                                                       filled(1, 1, Rgb(1.0f)));
        const float y = luminance(one.rgb[0]);
        EXPECT_GT(y, previous) << "relative error " << e;
        previous = y;
    }
    // Identical images are black everywhere; a crop gives a heatmap of the crop's size.
    const ImageChannels same = relativeErrorHeatmap(test, test, CropRect{1, 0, 3, 1});
    EXPECT_EQ(same.width, 3);
    for (const Rgb& p : same.rgb) EXPECT_EQ(p, Rgb(0.0f));
    EXPECT_THROW(relativeErrorHeatmap(test, reference, std::nullopt, HeatmapScale{1.0, 0.5}), InputError);
}

TEST(ImageCompare, HeatmapPngIsWrittenAtomicallyWithTheRampColours) {
    const fs::path dir = scratchDirectory();
    const ImageChannels reference = filled(5, 4, Rgb(1.0f));
    ImageChannels test = reference;
    pixel(test, 4, 3) = Rgb(3.0f);  // relative error ~2: top of the ramp
    const fs::path path = dir / "heat.png";
    writeRelativeErrorHeatmap(path.string(), test, reference);
    std::size_t files = 0;
    for (const auto& entry : fs::directory_iterator(dir)) files += entry.path().filename() == "heat.png" ? 1 : 100;
    EXPECT_EQ(files, 1u) << "a temporary file was left behind";
    const ImageChannels back = readExr(path.string());
    ASSERT_EQ(back.width, 5);
    ASSERT_EQ(back.height, 4);
    EXPECT_EQ(back.rgb[0], Rgb(0.0f));
    const Rgb top = back.rgb.back() * 255.0f;
    EXPECT_NEAR(top.x, 255.0f, 1e-3f);
    EXPECT_NEAR(top.y, 255.0f, 1e-3f);
    EXPECT_NEAR(top.z, 220.0f, 1e-3f);
}

TEST(ImageCompare, ReadImageLinearDecodesSrgbFilesAndKeepsFloatFiles) {
    const fs::path dir = scratchDirectory();
    ImageChannels image = filled(4, 1, Rgb(0.0f));
    image.rgb = {Rgb(0.0f, 0.01f, 0.2f), Rgb(0.5f, 1.0f, 0.05f), Rgb(0.7f, 0.3f, 0.9f), Rgb(1.0f, 0.0f, 0.001f)};
    writeExr((dir / "image.exr").string(), image, {});
    writePngPreview((dir / "image.png").string(), image);

    const ImageChannels exr = readImageLinear((dir / "image.exr").string());
    EXPECT_EQ(exr.rgb, image.rgb);
    const ImageChannels png = readImageLinear((dir / "image.png").string());
    ASSERT_EQ(png.rgb.size(), image.rgb.size());
    for (std::size_t i = 0; i < image.rgb.size(); ++i)
        for (int c = 0; c < 3; ++c)  // half an 8-bit sRGB step is under 2% of the linear value above 0.05
            EXPECT_NEAR(png.rgb[i][c], image.rgb[i][c], 0.02f * image.rgb[i][c] + 5e-4f) << i << " " << c;
    EXPECT_THROW(readImageLinear((dir / "missing.exr").string()), InputError);
}

}  // namespace
}  // namespace fg
