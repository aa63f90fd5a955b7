// Error metrics between a rendered image and a reference, and a false-colour
// map of the per-pixel relative error. Used by `fluxgraph compare`, the
// benchmark scripts and the convergence tests.
//
// Definitions (sums over the N pixels of the compared region and the 3 RGB
// channels, v the test value, r the reference value, both linear):
//   rmse    sqrt( sum (v - r)^2 / 3N )
//   relmse  sum (v - r)^2 / (r + 0.01)^2 / 3N          (pbrt-v4's MRSE)
//   mae     sum |v - r| / 3N
//   psnr    10 log10( peak^2 / mse ) with peak = 1, i.e. -20 log10(rmse); +inf when identical
//   ssim    mean SSIM (Wang et al. 2004) of the tone-mapped luminance, below
// Non-finite pixel values are not skipped: they make the metrics nan or inf.
#pragma once

#include "engine/image/image_io.h"

#include <optional>
#include <string>

namespace fg {

struct ImageMetrics {
    double rmse = 0.0;
    double relmse = 0.0;
    double mae = 0.0;
    double ssim = 0.0;
    double psnr = 0.0;
    // Largest per-pixel relative squared error (mean over the channels): relmse
    // of a few pixels can dominate the image's, and this tells them apart.
    double worstRelse = 0.0;
};

// A pixel rectangle: top-left corner (x to the right, y down from the top row) and size.
struct CropRect {
    int x = 0;
    int y = 0;
    int width = 0;
    int height = 0;
};

inline constexpr double kRelMseEpsilon = 0.01;
inline constexpr double kPsnrPeak = 1.0;
// SSIM on luminance Y (Rec.709 weights) tone-mapped by t = Y / (1 + Y) (Y < 0
// counts as 0), which maps [0, inf) onto [0, 1) without clipping highlights,
// so the dynamic range is L = 1 for every image; C1 = (K1 L)^2, C2 = (K2 L)^2.
// Local statistics use an 11x11 Gaussian window (sigma 1.5, weights normalised)
// and population (co)variances; the score is the mean of the SSIM map over the
// pixels whose whole window lies inside the region, so the region must be at
// least 11x11 pixels, else ssim is nan.
inline constexpr double kSsimK1 = 0.01;
inline constexpr double kSsimK2 = 0.03;
inline constexpr double kSsimDynamicRange = 1.0;
inline constexpr double kSsimSigma = 1.5;
inline constexpr int kSsimWindowRadius = 5;

// The value SSIM sees for one pixel: Y / (1 + Y), Y the Rec.709 luminance.
double ssimToneMappedLuminance(const Rgb& linear);

// Throws InputError when the sizes differ or the crop is empty or reaches
// outside the images. Without a crop the whole image is compared.
ImageMetrics compareImages(const ImageChannels& test, const ImageChannels& reference,
                           std::optional<CropRect> crop = std::nullopt);

// Per-pixel relative error e = sqrt( sum_c (v - r)^2 / (r + 0.01)^2 / 3 ) shown on
// a log scale: e <= minError is black, e >= maxError the brightest colour of a
// black - blue - crimson - orange - pale yellow ramp; a nan or inf error is cyan.
struct HeatmapScale {
    double minError = 1e-3;
    double maxError = 1.0;
};
// The heatmap of the compared region as linear RGB, ready for writePngPreview
// (exposure 0), which stores exactly the ramp's 8-bit sRGB colours.
ImageChannels relativeErrorHeatmap(const ImageChannels& test, const ImageChannels& reference,
                                   std::optional<CropRect> crop = std::nullopt, const HeatmapScale& scale = {});
// Writes relativeErrorHeatmap as an 8-bit sRGB PNG, atomically.
void writeRelativeErrorHeatmap(const std::string& path, const ImageChannels& test, const ImageChannels& reference,
                               std::optional<CropRect> crop = std::nullopt, const HeatmapScale& scale = {});

// Reads an image's R, G, B as linear values: float and half formats (EXR, PFM,
// HDR) as stored; integer formats (PNG, JPEG, 8/16-bit TIFF) are taken as
// sRGB-encoded and decoded. Throws InputError when unreadable.
ImageChannels readImageLinear(const std::string& path);

}  // namespace fg
