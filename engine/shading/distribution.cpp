#include "engine/shading/distribution.h"

#include <algorithm>

namespace fg {

Distribution1D::Distribution1D(std::span<const float> weights) : weights_(weights.begin(), weights.end()) {
    if (weights_.empty()) weights_.push_back(1.0f);
    double sum = 0.0;
    for (float& w : weights_) {
        w = std::max(w, 0.0f);
        sum += w;
    }
    if (sum <= 0.0) {
        std::fill(weights_.begin(), weights_.end(), 1.0f);
        sum = static_cast<double>(weights_.size());
    }
    total_ = static_cast<float>(sum);
    cdf_.resize(weights_.size() + 1);
    cdf_[0] = 0.0;
    double running = 0.0;
    for (std::size_t i = 0; i < weights_.size(); ++i) {
        running += weights_[i];
        cdf_[i + 1] = running / sum;
    }
    cdf_.back() = 1.0;
}

std::size_t Distribution1D::sampleDiscrete(float u, float* pmf, float* uRemapped) const {
    // One cell (a scene's single light, chosen at every path vertex): the search
    // below would land on it anyway.
    if (weights_.size() == 1) {
        if (pmf) *pmf = discretePmf(0);
        if (uRemapped) {
            const double width = cdf_[1] - cdf_[0];
            *uRemapped = width > 0 ? std::min(static_cast<float>((u - cdf_[0]) / width), 0x1.fffffep-1f) : 0.0f;
        }
        return 0;
    }
    const auto it = std::upper_bound(cdf_.begin(), cdf_.end(), static_cast<double>(u));
    std::size_t i = static_cast<std::size_t>(std::max<std::ptrdiff_t>(0, it - cdf_.begin() - 1));
    i = std::min(i, weights_.size() - 1);
    // Skip zero-weight cells that upper_bound can land on at their shared cdf value.
    while (weights_[i] == 0.0f && i + 1 < weights_.size()) ++i;
    if (pmf) *pmf = discretePmf(i);
    if (uRemapped) {
        const double width = cdf_[i + 1] - cdf_[i];
        *uRemapped = width > 0 ? std::min(static_cast<float>((u - cdf_[i]) / width), 0x1.fffffep-1f) : 0.0f;
    }
    return i;
}

float Distribution1D::sampleContinuous(float u, float* pdf, std::size_t* cell) const {
    float remapped = 0.0f;
    const std::size_t i = sampleDiscrete(u, nullptr, &remapped);
    if (pdf) *pdf = weights_[i] / total_ * static_cast<float>(weights_.size());
    if (cell) *cell = i;
    return std::min((static_cast<float>(i) + remapped) / static_cast<float>(weights_.size()), 0x1.fffffep-1f);
}

float Distribution1D::continuousPdf(float x) const {
    const auto n = weights_.size();
    const std::size_t i = std::min(n - 1, static_cast<std::size_t>(std::max(0.0f, x) * static_cast<float>(n)));
    return weights_[i] / total_ * static_cast<float>(n);
}

Distribution2D::Distribution2D(std::span<const float> weights, int width, int height) : width_(width), height_(height) {
    std::vector<float> rowTotals(static_cast<std::size_t>(height));
    conditional_.reserve(static_cast<std::size_t>(height));
    for (int y = 0; y < height; ++y) {
        conditional_.emplace_back(weights.subspan(static_cast<std::size_t>(y) * width, static_cast<std::size_t>(width)));
        float sum = 0.0f;
        for (int x = 0; x < width; ++x) sum += std::max(0.0f, weights[static_cast<std::size_t>(y) * width + x]);
        rowTotals[static_cast<std::size_t>(y)] = sum;
    }
    marginal_ = Distribution1D(rowTotals);
}

Vec2 Distribution2D::sample(const Vec2& u, float* pdf) const {
    float pdfY = 0.0f, pdfX = 0.0f;
    std::size_t row = 0;
    const float y = marginal_.sampleContinuous(u.y, &pdfY, &row);
    const float x = conditional_[row].sampleContinuous(u.x, &pdfX);
    if (pdf) *pdf = pdfX * pdfY;
    return {x, y};
}

float Distribution2D::pdf(const Vec2& p) const {
    const int row = std::clamp(static_cast<int>(p.y * static_cast<float>(height_)), 0, height_ - 1);
    return marginal_.continuousPdf(p.y) * conditional_[static_cast<std::size_t>(row)].continuousPdf(p.x);
}

}  // namespace fg
