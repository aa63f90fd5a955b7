// Piecewise-constant 1D and 2D distributions for discrete and continuous
// importance sampling (light selection by power, triangle selection by area,
// environment maps by luminance x sin(theta)).
#pragma once

#include "engine/core/math.h"

#include <cstddef>
#include <span>
#include <vector>

namespace fg {

class Distribution1D {
public:
    Distribution1D() = default;
    // Weights must be non-negative; an all-zero input becomes uniform.
    explicit Distribution1D(std::span<const float> weights);

    std::size_t size() const { return weights_.size(); }
    float total() const { return total_; }
    // Probability of picking index i by sampleDiscrete.
    float discretePmf(std::size_t i) const { return weights_[i] / total_; }
    // Index with probability weights[i] / total; `u` is reused as uRemapped in [0,1).
    std::size_t sampleDiscrete(float u, float* pmf = nullptr, float* uRemapped = nullptr) const;
    // Continuous sample in [0,1) with density size() * weights[i] / total on cell i.
    float sampleContinuous(float u, float* pdf = nullptr, std::size_t* cell = nullptr) const;
    float continuousPdf(float x) const;

private:
    std::vector<float> weights_;
    std::vector<double> cdf_;  // size()+1 entries, cdf_[0] = 0, cdf_.back() = 1
    float total_ = 0.0f;
};

// Density over [0,1)^2 proportional to a row-major width x height grid of weights.
class Distribution2D {
public:
    Distribution2D() = default;
    Distribution2D(std::span<const float> weights, int width, int height);

    Vec2 sample(const Vec2& u, float* pdf = nullptr) const;
    float pdf(const Vec2& p) const;

private:
    std::vector<Distribution1D> conditional_;  // one per row
    Distribution1D marginal_;                  // over rows
    int width_ = 0, height_ = 0;
};

}  // namespace fg
