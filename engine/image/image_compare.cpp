// Image comparison metrics: RMSE, MAE, PSNR, the relative MSE of pbrt-v4
// (Pharr, Jakob and Humphreys, pbrt-v4 Image::MRSE: (v - r)^2 / (r + 0.01)^2)
// and the structural similarity index of Wang, Bovik, Sheikh and Simoncelli,
// "Image Quality Assessment: From Error Visibility to Structural Similarity",
// IEEE TIP 2004 (eq. 13 with the Gaussian window of section III.C, averaged
// as in eq. 17). SSIM is defined for a bounded signal; renders are HDR, so it
// is computed on luminance compressed by the global operator Y / (1 + Y) of
// Reinhard et al., "Photographic Tone Reproduction for Digital Images",
// SIGGRAPH 2002 (eq. 3), which keeps highlight and caustic structure instead
// of clipping it, and gives the image-independent dynamic range L = 1.
// All sums run in double, in pixel order, so results are reproducible.
#include "engine/image/image_compare.h"

#include "engine/core/error.h"
#include "engine/image/image_diagnostics.h"
#include "engine/image/image_file_input.h"
#include "engine/image/image_guard.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <memory>
#include <vector>

namespace fg {

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

std::string sizeText(const ImageChannels& image) {
    return std::to_string(image.width) + "x" + std::to_string(image.height);
}

CropRect checkedRegion(const ImageChannels& test, const ImageChannels& reference, std::optional<CropRect> crop) {
    if (test.width != reference.width || test.height != reference.height)
        throw InputError("image sizes differ: " + sizeText(test) + " against reference " + sizeText(reference));
    const std::size_t pixels = static_cast<std::size_t>(test.width) * static_cast<std::size_t>(test.height);
    if (test.width <= 0 || test.height <= 0 || test.rgb.size() != pixels || reference.rgb.size() != pixels)
        throw InputError("image is empty or its pixel count does not match its size");
    if (!crop) return CropRect{0, 0, test.width, test.height};
    const CropRect& c = *crop;
    const std::string text = std::to_string(c.x) + "," + std::to_string(c.y) + "," + std::to_string(c.width) + "," +
                             std::to_string(c.height);
    if (c.width <= 0 || c.height <= 0) throw InputError("crop " + text + ": width and height must be positive");
    // Compared in 64 bits so that a huge width cannot wrap around.
    if (c.x < 0 || c.y < 0 || static_cast<long long>(c.x) + c.width > test.width ||
        static_cast<long long>(c.y) + c.height > test.height)
        throw InputError("crop " + text + " reaches outside the " + sizeText(test) + " image");
    return c;
}

// Visits the region's pixels row by row as (test, reference, region-local index).
template <class Visit>
void forEachPixel(const ImageChannels& test, const ImageChannels& reference, const CropRect& region, Visit&& visit) {
    for (int y = 0; y < region.height; ++y) {
        const std::size_t row = static_cast<std::size_t>(region.y + y) * static_cast<std::size_t>(test.width);
        for (int x = 0; x < region.width; ++x) {
            const std::size_t source = row + static_cast<std::size_t>(region.x + x);
            visit(test.rgb[source], reference.rgb[source],
                  static_cast<std::size_t>(y) * static_cast<std::size_t>(region.width) + static_cast<std::size_t>(x));
        }
    }
}

double relativeSquaredError(double value, double reference) {
    const double difference = value - reference;
    const double denominator = reference + kRelMseEpsilon;
    return difference * difference / (denominator * denominator);
}

std::array<double, 2 * kSsimWindowRadius + 1> ssimWindowWeights() {
    std::array<double, 2 * kSsimWindowRadius + 1> weights{};
    double sum = 0.0;
    for (int k = -kSsimWindowRadius; k <= kSsimWindowRadius; ++k) {
        const double w = std::exp(-0.5 * k * k / (kSsimSigma * kSsimSigma));
        weights[static_cast<std::size_t>(k + kSsimWindowRadius)] = w;
        sum += w;
    }
    for (double& w : weights) w /= sum;
    return weights;
}

// Mean SSIM of two tone-mapped luminance planes of size width x height.
// The separable Gaussian filter is evaluated only where the whole window fits,
// which is exactly where the score is averaged.
double meanSsim(const std::vector<double>& a, const std::vector<double>& b, int width, int height) {
    const int r = kSsimWindowRadius;
    if (width < 2 * r + 1 || height < 2 * r + 1) return kNaN;
    const auto weights = ssimWindowWeights();
    const int innerWidth = width - 2 * r;
    const int innerHeight = height - 2 * r;

    // Horizontal pass: five moments (a, b, a^2, b^2, ab) per row, inner columns only.
    constexpr int kMoments = 5;
    std::vector<std::array<double, kMoments>> horizontal(static_cast<std::size_t>(innerWidth) *
                                                         static_cast<std::size_t>(height));
    for (int y = 0; y < height; ++y) {
        for (int x = 0; x < innerWidth; ++x) {
            std::array<double, kMoments> m{};
            for (int k = 0; k <= 2 * r; ++k) {
                const std::size_t i = static_cast<std::size_t>(y) * static_cast<std::size_t>(width) +
                                      static_cast<std::size_t>(x + k);
                const double w = weights[static_cast<std::size_t>(k)];
                m[0] += w * a[i];
                m[1] += w * b[i];
                m[2] += w * a[i] * a[i];
                m[3] += w * b[i] * b[i];
                m[4] += w * a[i] * b[i];
            }
            horizontal[static_cast<std::size_t>(y) * static_cast<std::size_t>(innerWidth) +
                       static_cast<std::size_t>(x)] = m;
        }
    }

    const double c1 = (kSsimK1 * kSsimDynamicRange) * (kSsimK1 * kSsimDynamicRange);
    const double c2 = (kSsimK2 * kSsimDynamicRange) * (kSsimK2 * kSsimDynamicRange);
    double sum = 0.0;
    for (int y = 0; y < innerHeight; ++y) {
        for (int x = 0; x < innerWidth; ++x) {
            std::array<double, kMoments> m{};
            for (int k = 0; k <= 2 * r; ++k) {
                const auto& h = horizontal[static_cast<std::size_t>(y + k) * static_cast<std::size_t>(innerWidth) +
                                           static_cast<std::size_t>(x)];
                const double w = weights[static_cast<std::size_t>(k)];
                for (int j = 0; j < kMoments; ++j) m[static_cast<std::size_t>(j)] += w * h[static_cast<std::size_t>(j)];
            }
            const double meanA = m[0], meanB = m[1];
            const double varianceA = m[2] - meanA * meanA;
            const double varianceB = m[3] - meanB * meanB;
            const double covariance = m[4] - meanA * meanB;
            sum += (2.0 * meanA * meanB + c1) * (2.0 * covariance + c2) /
                   ((meanA * meanA + meanB * meanB + c1) * (varianceA + varianceB + c2));
        }
    }
    return sum / (static_cast<double>(innerWidth) * static_cast<double>(innerHeight));
}

double srgbDecode(double encoded) {
    return encoded <= 0.04045 ? encoded / 12.92 : std::pow((encoded + 0.055) / 1.055, 2.4);
}

// The ramp's stops as 8-bit sRGB, evenly spaced over [0, 1].
constexpr std::array<std::array<double, 3>, 5> kHeatmapRamp{{
    {0.0, 0.0, 0.0},
    {40.0, 30.0, 160.0},
    {200.0, 40.0, 80.0},
    {250.0, 160.0, 20.0},
    {255.0, 255.0, 220.0},
}};
constexpr std::array<double, 3> kHeatmapNonFinite{0.0, 255.0, 255.0};

Rgb heatmapColour(double error, const HeatmapScale& scale) {
    std::array<double, 3> srgb8 = kHeatmapNonFinite;
    if (std::isfinite(error)) {
        double u = 0.0;
        if (error > scale.minError)
            u = std::clamp(std::log10(error / scale.minError) / std::log10(scale.maxError / scale.minError), 0.0, 1.0);
        const double position = u * static_cast<double>(kHeatmapRamp.size() - 1);
        const std::size_t lower = std::min(static_cast<std::size_t>(position), kHeatmapRamp.size() - 2);
        const double t = position - static_cast<double>(lower);
        for (std::size_t c = 0; c < 3; ++c)
            srgb8[c] = std::round((1.0 - t) * kHeatmapRamp[lower][c] + t * kHeatmapRamp[lower + 1][c]);
    }
    return Rgb(static_cast<float>(srgbDecode(srgb8[0] / 255.0)), static_cast<float>(srgbDecode(srgb8[1] / 255.0)),
               static_cast<float>(srgbDecode(srgb8[2] / 255.0)));
}

}  // namespace

double ssimToneMappedLuminance(const Rgb& linear) {
    const double y = 0.2126 * linear.x + 0.7152 * linear.y + 0.0722 * linear.z;
    if (std::isnan(y)) return y;
    if (y == std::numeric_limits<double>::infinity()) return 1.0;
    return y > 0.0 ? y / (1.0 + y) : 0.0;
}

ImageMetrics compareImages(const ImageChannels& test, const ImageChannels& reference, std::optional<CropRect> crop) {
    const CropRect region = checkedRegion(test, reference, crop);
    const std::size_t pixels = static_cast<std::size_t>(region.width) * static_cast<std::size_t>(region.height);
    double squared = 0.0, relative = 0.0, absolute = 0.0, worst = 0.0;
    std::vector<double> lumaTest(pixels), lumaReference(pixels);
    forEachPixel(test, reference, region, [&](const Rgb& v, const Rgb& r, std::size_t i) {
        double pixelRelative = 0.0;
        for (int c = 0; c < 3; ++c) {
            const double difference = static_cast<double>(v[c]) - static_cast<double>(r[c]);
            squared += difference * difference;
            absolute += std::abs(difference);
            const double channelRelative = relativeSquaredError(v[c], r[c]);
            relative += channelRelative;
            pixelRelative += channelRelative;
        }
        worst = std::max(worst, pixelRelative / 3.0);
        lumaTest[i] = ssimToneMappedLuminance(v);
        lumaReference[i] = ssimToneMappedLuminance(r);
    });
    const double values = 3.0 * static_cast<double>(pixels);
    ImageMetrics metrics;
    const double mse = squared / values;
    metrics.rmse = std::sqrt(mse);
    metrics.relmse = relative / values;
    metrics.worstRelse = worst;
    metrics.mae = absolute / values;
    metrics.psnr = mse == 0.0 ? std::numeric_limits<double>::infinity() : 10.0 * std::log10(kPsnrPeak * kPsnrPeak / mse);
    metrics.ssim = meanSsim(lumaTest, lumaReference, region.width, region.height);
    return metrics;
}

ImageChannels relativeErrorHeatmap(const ImageChannels& test, const ImageChannels& reference,
                                   std::optional<CropRect> crop, const HeatmapScale& scale) {
    if (!(scale.minError > 0.0) || !(scale.maxError > scale.minError))
        throw InputError("heatmap scale: need 0 < minError < maxError");
    const CropRect region = checkedRegion(test, reference, crop);
    ImageChannels heatmap;
    heatmap.width = region.width;
    heatmap.height = region.height;
    heatmap.rgb.resize(static_cast<std::size_t>(region.width) * static_cast<std::size_t>(region.height));
    forEachPixel(test, reference, region, [&](const Rgb& v, const Rgb& r, std::size_t i) {
        double relative = 0.0;
        for (int c = 0; c < 3; ++c) relative += relativeSquaredError(v[c], r[c]);
        heatmap.rgb[i] = heatmapColour(std::sqrt(relative / 3.0), scale);
    });
    return heatmap;
}

void writeRelativeErrorHeatmap(const std::string& path, const ImageChannels& test, const ImageChannels& reference,
                               std::optional<CropRect> crop, const HeatmapScale& scale) {
    writePngPreview(path, relativeErrorHeatmap(test, reference, crop, scale), 0.0f);
}

ImageChannels readImageLinear(const std::string& path) {
    bool srgbEncoded = false;
    {
        checkImageStructure(path);
        CapturedStderr libraryMessages;
        std::string openError;
        std::unique_ptr<ImageFileInput> input = openImageFile(path, openError);
        if (!input) throw InputError(path, 0, "cannot read image: " + imageReadFailure(openError, libraryMessages));
        srgbEncoded = input->spec().sampleType != SampleType::Float;
    }
    ImageChannels image = readExr(path);
    if (srgbEncoded) {
        for (Rgb& pixel : image.rgb)
            for (int c = 0; c < 3; ++c) pixel[c] = static_cast<float>(srgbDecode(pixel[c]));
    }
    return image;
}

}  // namespace fg
