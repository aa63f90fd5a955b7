// Per-pixel batch statistics of a progressively accumulated film (the
// film_noise pass): what the film's sums were after the previous batch, and
// Welford's running mean and squared deviations of each batch's estimate.
#pragma once

#include "engine/core/math.h"
#include "engine/core/pass.h"

#include <cstdint>
#include <vector>

namespace fg {

struct FilmNoise {
    FilmNoise() = default;
    explicit FilmNoise(std::size_t pixels)
        : previousSums(pixels, Rgb(0.0f)), previousWeights(pixels, 0.0f), mean(pixels, 0.0), m2(pixels, 0.0) {}
    std::vector<Rgb> previousSums;
    std::vector<float> previousWeights;
    std::vector<double> mean;  // luminance of the batch estimates
    std::vector<double> m2;
    std::int64_t batches = 0;
    double relativeError = 0.0;
    std::size_t bytes() const {
        return previousSums.capacity() * sizeof(Rgb) + previousWeights.capacity() * sizeof(float) +
               (mean.capacity() + m2.capacity()) * sizeof(double);
    }
};
template <>
struct BufferTypeName<FilmNoise> {
    static constexpr const char* value = "FilmNoise";
};

}  // namespace fg
