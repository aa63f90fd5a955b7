// Linear RGB film with box, tent or Gaussian reconstruction and per-pixel AOVs.
// Samples arrive in rounds: a round holds `samplesPerPixel` samples for every
// pixel of a contiguous pixel range, stored in pixel order (SoA: raster
// position, radiance). Reconstruction is a gather: each output pixel visits the
// samples of the pixels its filter reaches in a fixed order, so the image is
// bit-identical whatever the thread count.
#pragma once

#include "engine/core/math.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

namespace fg {

enum class FilterKind { Box, Gaussian, Tent };

struct FilmSettings {
    int width = 256;
    int height = 256;
    FilterKind filter = FilterKind::Box;
    float filterRadius = 0.5f;  // pixels; box: half-width (0.5 = the pixel), tent and Gaussian: support radius
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

    // The accumulated state, for saving a film and restoring it later.
    const std::vector<Rgb>& weightedSums() const { return weightedSum_; }
    const std::vector<float>& weightSums() const { return weightSum_; }
    const std::vector<Rgb>& directSums() const { return direct_; }  // empty unless hasDirect()
    bool hasDirect() const { return hasDirect_; }
    // A film in the state the accessors above reported. Throws
    // std::invalid_argument if the settings are invalid or an array does not
    // hold one value per pixel (direct: none when !hasDirect).
    static Film restore(const FilmSettings& settings, std::vector<Rgb> weightedSums, std::vector<float> weightSums,
                        std::vector<Rgb> direct, bool hasDirect,
                        std::vector<std::pair<std::string, std::vector<float>>> aovs);

private:
    FilmSettings settings_;
    std::vector<Rgb> weightedSum_;
    std::vector<float> weightSum_;
    std::vector<Rgb> direct_;
    bool hasDirect_ = false;
    std::vector<std::pair<std::string, std::vector<float>>> aovs_;
};

// The film's reconstruction filter w(dx, dy), offsets in pixels from the pixel
// centre, with its constants computed once: build one per round or batch, not
// per sample.
class PixelFilter {
public:
    explicit PixelFilter(const FilmSettings& s);

    float operator()(float dx, float dy) const { return axis(dx) * axis(dy); }

    // The filter is separable: w(dx, dy) = axis(dx) * axis(dy), bit for bit.
    float axis(float d) const {
        if (kind_ == FilterKind::Box) {
            // Half-open on purpose: with radius 0.5 a sample on the edge shared by two
            // pixels belongs to exactly one of them (the one whose raster cell [i, i+1)
            // contains it), so the box filter is exactly the per-pixel mean.
            return (d >= -radius_ && d < radius_) ? 1.0f : 0.0f;
        }
        if (kind_ == FilterKind::Tent) return tent1D(d);
        return gaussian1D(d);
    }

private:
    // Mitsuba's tent: 1 - |d| / r inside the radius, separable in x and y.
    float tent1D(float d) const { return std::max(0.0f, 1.0f - std::abs(d) / radius_); }
    // Shifted down by its value at the radius so the filter reaches zero there
    // instead of stepping, clamped so nothing beyond the radius counts.
    float gaussian1D(float d) const {
        if (std::abs(d) >= radius_) return 0.0f;
        return std::max(0.0f, std::exp(-d * d * inverseTwoSigmaSquared_) - gaussianAtRadius_);
    }

    FilterKind kind_;
    float radius_;
    float inverseTwoSigmaSquared_;
    float gaussianAtRadius_;
};

}  // namespace fg
