// Linear RGB film with box or Gaussian reconstruction and per-pixel AOVs.
// Samples arrive in rounds: a round holds `samplesPerPixel` samples for every
// pixel of a contiguous pixel range, stored in pixel order (SoA: raster
// position, radiance). Reconstruction is a gather: each output pixel visits the
// samples of the pixels its filter reaches in a fixed order, so the image is
// bit-identical whatever the thread count.
#pragma once

#include "engine/math.h"

#include <cstdint>
#include <span>
#include <string>
#include <vector>

namespace fg {

enum class FilterKind { Box, Gaussian };

struct FilmSettings {
    int width = 256;
    int height = 256;
    FilterKind filter = FilterKind::Box;
    float filterRadius = 0.5f;  // pixels; box: half-width (0.5 = the pixel), Gaussian: support radius
    float gaussianSigma = 0.5f; // pixels, Gaussian only
};

// One round of samples for pixels [firstPixel, firstPixel + pixelCount).
struct SampleRound {
    std::size_t firstPixel = 0;
    std::size_t pixelCount = 0;
    int samplesPerPixel = 1;
    std::span<const Vec2> raster;  // pixelCount * samplesPerPixel entries
    std::span<const Rgb> radiance;
};

class Film {
public:
    explicit Film(const FilmSettings& settings);

    const FilmSettings& settings() const { return settings_; }
    int width() const { return settings_.width; }
    int height() const { return settings_.height; }
    std::size_t pixelCount() const { return static_cast<std::size_t>(settings_.width) * settings_.height; }

    // Accumulates one round (parallel over output pixels, deterministic).
    void addRound(const SampleRound& round);
    // Adds radiance straight to pixels (already filtered, e.g. splatting passes), in pixel order.
    void addToPixels(std::span<const Rgb> perPixel, float weight);

    // Reconstructed image: weighted sum / weight sum per pixel, plus any direct additions.
    std::vector<Rgb> resolve() const;

    // Named per-pixel float channels (e.g. "time_ns", "samples"), created on first use.
    std::vector<float>& aov(const std::string& name);
    const std::vector<std::pair<std::string, std::vector<float>>>& aovs() const { return aovs_; }

    std::size_t bytes() const;

private:
    FilmSettings settings_;
    std::vector<Rgb> weightedSum_;
    std::vector<float> weightSum_;
    std::vector<Rgb> direct_;
    bool hasDirect_ = false;
    std::vector<std::pair<std::string, std::vector<float>>> aovs_;
};

float filterWeight(const FilmSettings& s, float dx, float dy);

}  // namespace fg
