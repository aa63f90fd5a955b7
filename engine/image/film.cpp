// Film: reconstruction of pixel values from image samples, as a weighted mean
// sum_i w(x_i - p) L_i / sum_i w(x_i - p) over the samples x_i near the pixel
// centre p (the filtered estimate of Pharr, Jakob & Humphreys, "Physically
// Based Rendering", 3rd ed., Sec. 7.8). Two filters are offered: the
// box and the truncated Gaussian of PBR Sec. 7.8.1, both separable in x and y.
//
// Each output row is owned by exactly one task, which walks the source pixels
// its filter reaches in raster order and each pixel's samples in their stored
// order, adding each to the row's pixels it reaches (the separable filter's y
// factor is evaluated once per sample and row). The floating-point operation
// sequence per output pixel is therefore fixed, which makes the image
// bit-identical whatever the number of threads.
#include "engine/image/film.h"

#include "jobs/parallel.h"

#include <cmath>
#include <stdexcept>
#include <string>

namespace fg {

namespace {

void validateSettings(const FilmSettings& s) {
    if (s.width <= 0 || s.height <= 0)
        throw std::invalid_argument("Film: width and height must be positive");
    if (!(s.filterRadius > 0.0f) || !std::isfinite(s.filterRadius))
        throw std::invalid_argument("Film: filter radius must be positive and finite");
    if (s.filter == FilterKind::Gaussian && !(s.gaussianSigma > 0.0f))
        throw std::invalid_argument("Film: Gaussian sigma must be positive");
}

}  // namespace

PixelFilter::PixelFilter(const FilmSettings& s)
    : kind_(s.filter), radius_(s.filterRadius),
      inverseTwoSigmaSquared_(1.0f / (2.0f * s.gaussianSigma * s.gaussianSigma)),
      gaussianAtRadius_(std::exp(-s.filterRadius * s.filterRadius * inverseTwoSigmaSquared_)) {}

Film::Film(const FilmSettings& settings) : settings_(settings) {
    validateSettings(settings_);
    weightedSum_.assign(pixelCount(), Rgb(0.0f));
    weightSum_.assign(pixelCount(), 0.0f);
}

Film Film::restore(const FilmSettings& settings, std::vector<Rgb> weightedSums, std::vector<float> weightSums,
                   std::vector<Rgb> direct, bool hasDirect,
                   std::vector<std::pair<std::string, std::vector<float>>> aovs) {
    validateSettings(settings);
    // Checked before the film is made: a corrupt width * height must fail here,
    // not allocate.
    const std::size_t pixels = static_cast<std::size_t>(settings.width) * static_cast<std::size_t>(settings.height);
    if (weightedSums.size() != pixels || weightSums.size() != pixels)
        throw std::invalid_argument("Film: expected " + std::to_string(pixels) + " weighted sums and weight sums");
    if (direct.size() != (hasDirect ? pixels : 0))
        throw std::invalid_argument("Film: expected " + std::to_string(hasDirect ? pixels : 0) + " direct values");
    for (std::size_t i = 0; i < aovs.size(); ++i) {
        if (aovs[i].second.size() != pixels)
            throw std::invalid_argument("Film: AOV '" + aovs[i].first + "' does not hold one value per pixel");
        for (std::size_t j = 0; j < i; ++j)
            if (aovs[j].first == aovs[i].first) throw std::invalid_argument("Film: AOV '" + aovs[i].first + "' twice");
    }
    Film film(settings);
    film.weightedSum_ = std::move(weightedSums);
    film.weightSum_ = std::move(weightSums);
    film.direct_ = std::move(direct);
    film.hasDirect_ = hasDirect;
    film.aovs_ = std::move(aovs);
    return film;
}

void Film::addRound(const SampleRound& round) {
    if (round.pixelCount == 0) return;
    if (round.samplesPerPixel <= 0) throw std::invalid_argument("Film::addRound: samplesPerPixel must be positive");
    if (round.firstPixel > pixelCount() || round.pixelCount > pixelCount() - round.firstPixel)
        throw std::invalid_argument("Film::addRound: pixel range exceeds the image");
    const std::size_t spp = static_cast<std::size_t>(round.samplesPerPixel);
    const std::size_t sampleCount = round.pixelCount * spp;
    if (round.raster.size() != sampleCount || round.radiance.size() != sampleCount)
        throw std::invalid_argument("Film::addRound: expected pixelCount * samplesPerPixel samples");

    const PixelFilter filter(settings_);
    const std::ptrdiff_t width = settings_.width;
    const std::ptrdiff_t height = settings_.height;
    // Samples of a pixel lie inside its raster cell, so a filter of radius r
    // centred on a pixel reaches at most ceil(r) pixels away.
    const std::ptrdiff_t reach = static_cast<std::ptrdiff_t>(std::ceil(settings_.filterRadius));
    const std::ptrdiff_t roundBegin = static_cast<std::ptrdiff_t>(round.firstPixel);
    const std::ptrdiff_t roundEnd = roundBegin + static_cast<std::ptrdiff_t>(round.pixelCount);

    // Only output rows within reach of the round's rows can receive anything.
    const std::ptrdiff_t firstRow = std::max<std::ptrdiff_t>(0, roundBegin / width - reach);
    const std::ptrdiff_t lastRow = std::min<std::ptrdiff_t>(height - 1, (roundEnd - 1) / width + reach);
    const std::size_t rowCount = static_cast<std::size_t>(lastRow - firstRow + 1);
    // A few thousand samples per chunk keeps scheduling overhead negligible
    // and the two threads' shares even; the grain does not affect the result.
    const std::size_t rowGrain = std::max<std::size_t>(1, 8192 / (static_cast<std::size_t>(width) * spp));

    jobs::parallelForChunks(rowCount, rowGrain, [&](jobs::IndexRange rows) {
        // Per output pixel of the row: weighted R, G, B and weight, accumulated in
        // double so that the round's contribution is rounded to float once, not
        // once per sample.
        std::vector<double> sums(static_cast<std::size_t>(width) * 4);
        std::vector<std::uint8_t> touched(static_cast<std::size_t>(width));
        for (std::size_t rowOffset = rows.begin; rowOffset != rows.end; ++rowOffset) {
            const std::ptrdiff_t py = firstRow + static_cast<std::ptrdiff_t>(rowOffset);
            const float centreY = static_cast<float>(py) + 0.5f;
            std::fill(sums.begin(), sums.end(), 0.0);
            std::fill(touched.begin(), touched.end(), std::uint8_t{0});
            // Source samples in raster order, each added to the output pixels of
            // this row it reaches: every output pixel receives its samples in
            // raster order, whatever the chunking.
            const std::ptrdiff_t syBegin = std::max<std::ptrdiff_t>(0, py - reach);
            const std::ptrdiff_t syEnd = std::min<std::ptrdiff_t>(height - 1, py + reach);
            for (std::ptrdiff_t sy = syBegin; sy <= syEnd; ++sy) {
                const std::ptrdiff_t rowStart = sy * width;
                const std::ptrdiff_t begin = std::max(rowStart, roundBegin);
                const std::ptrdiff_t end = std::min(rowStart + width, roundEnd);
                for (std::ptrdiff_t source = begin; source < end; ++source) {
                    const std::ptrdiff_t sx = source - rowStart;
                    const std::ptrdiff_t pxBegin = std::max<std::ptrdiff_t>(0, sx - reach);
                    const std::ptrdiff_t pxEnd = std::min<std::ptrdiff_t>(width - 1, sx + reach);
                    const std::size_t first = static_cast<std::size_t>(source - roundBegin) * spp;
                    for (std::size_t i = first; i < first + spp; ++i) {
                        const Vec2 position = round.raster[i];
                        const float wy = filter.axis(position.y - centreY);
                        if (wy == 0.0f) continue;
                        const Rgb& radiance = round.radiance[i];
                        for (std::ptrdiff_t px = pxBegin; px <= pxEnd; ++px) {
                            const float w = filter.axis(position.x - (static_cast<float>(px) + 0.5f)) * wy;
                            if (w == 0.0f) continue;
                            double* sum = &sums[static_cast<std::size_t>(px) * 4];
                            sum[0] += static_cast<double>(w) * radiance.x;
                            sum[1] += static_cast<double>(w) * radiance.y;
                            sum[2] += static_cast<double>(w) * radiance.z;
                            sum[3] += w;
                            touched[static_cast<std::size_t>(px)] = 1;
                        }
                    }
                }
            }
            for (std::ptrdiff_t px = 0; px < width; ++px) {
                if (!touched[static_cast<std::size_t>(px)]) continue;
                const double* sum = &sums[static_cast<std::size_t>(px) * 4];
                const std::size_t pixel = static_cast<std::size_t>(py * width + px);
                weightedSum_[pixel] +=
                    Rgb(static_cast<float>(sum[0]), static_cast<float>(sum[1]), static_cast<float>(sum[2]));
                weightSum_[pixel] += static_cast<float>(sum[3]);
            }
        }
    });
}

void Film::addToPixels(std::span<const Rgb> perPixel, float weight) {
    if (perPixel.size() != pixelCount())
        throw std::invalid_argument("Film::addToPixels: expected one value per pixel");
    if (!hasDirect_) {
        direct_.assign(pixelCount(), Rgb(0.0f));
        hasDirect_ = true;
    }
    jobs::parallelFor(pixelCount(), 4096, [&](std::size_t p) { direct_[p] += perPixel[p] * weight; });
}

std::vector<Rgb> Film::resolve() const {
    std::vector<Rgb> image(pixelCount());
    jobs::parallelFor(pixelCount(), 4096, [&](std::size_t p) {
        Rgb value = weightSum_[p] > 0.0f ? weightedSum_[p] / weightSum_[p] : Rgb(0.0f);
        if (hasDirect_) value += direct_[p];
        image[p] = value;
    });
    return image;
}

// The returned reference stays valid until the next new AOV is created.
std::vector<float>& Film::aov(const std::string& name) {
    for (auto& [existing, values] : aovs_)
        if (existing == name) return values;
    aovs_.emplace_back(name, std::vector<float>(pixelCount(), 0.0f));
    return aovs_.back().second;
}

std::size_t Film::bytes() const {
    std::size_t total = weightedSum_.capacity() * sizeof(Rgb) + weightSum_.capacity() * sizeof(float) +
                        direct_.capacity() * sizeof(Rgb) + aovs_.capacity() * sizeof(aovs_[0]);
    for (const auto& [name, values] : aovs_) total += name.capacity() + values.capacity() * sizeof(float);
    return total;
}

}  // namespace fg
