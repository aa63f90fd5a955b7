// The image-space radiance cache of photon ray splatting (Herzog et al. 2007,
// §8.3), placed by the multi-pass cache splatting of Gautron et al. 2005,
// shared by the cache_select and radiance_cache passes and their tests.
//
// A record k is used at a point x with normal n where Ward et al.'s (1988)
// weight
//   w_k(x) = 1 / (‖x − x_k‖ / R_k + √(1 − n·n_k))
// exceeds 1/ε, i.e. where the denominator is below ε; within that set
// ‖x − x_k‖ < ε R_k, so the record's footprint on the image is the
// projection of the sphere of radius ε R_k around x_k (Gautron et al.'s
// "cache splatting"). Placement runs in passes over ever finer grids (32, 16
// and 8 pixels by default): a grid pixel gets a record when fewer than
// `minRecords` records cover it so far. After the last pass, pixels still
// covered by fewer are reported. The interpolated coefficients at x are
//   c(x) = Σ_k w_k(x) c_k / Σ_k w_k(x)
// over the records valid at x (no gradients), in record order.
//
// R_k comes either from the photon rays splatted at the record's pixel (the
// kernel-weighted harmonic mean distance of their origins, §8.3; the whole
// map must be splatted first) or, so that the records can be chosen before
// any splatting and the rays splatted onto the records alone, from the
// geometry around x_k: Ward et al.'s harmonic mean distance of the surfaces
// seen over the hemisphere (harmonicMeanDistanceDirections).
#pragma once

#include "engine/buffers/radiance_cache_buffers.h"
#include "engine/core/error.h"
#include "engine/core/math.h"
#include "engine/core/pass.h"
#include "engine/scene/scene.h"
#include "jobs/parallel.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

namespace fg {

struct RadianceCacheSettings {
    float error = 0.7f;  // ε
    int grid = 32;       // pixel spacing of the first pass; halved in every later pass
    int passes = 3;
    int minRecords = 4;
};

// A record's candidate at one pixel: where it would sit and what it would
// hold. Pixels without a mapped eye vertex are not valid (no record, never
// reported).
struct CachePixelSample {
    Vec3 position{0.0f};
    Vec3 normal{0.0f, 0.0f, 1.0f};
    float radius = 0.0f;
    CacheCoefficientArray coefficients{};
    bool valid = false;
};

// The Ward weight's denominator ‖x − x_k‖ / R_k + √(1 − n·n_k): record k is
// valid at x where it is below ε, and w_k = 1 / denominator.
inline float wardDenominator(const Vec3& x, const Vec3& n, const Vec3& recordPosition, const Vec3& recordNormal,
                             float recordRadius) {
    return glm::length(x - recordPosition) / recordRadius +
           std::sqrt(std::max(0.0f, 1.0f - glm::dot(n, recordNormal)));
}

// At the record's own position the weight is infinite; a floor on the
// denominator keeps it finite (10^6) so that the average stays defined while
// the record still dominates it.
inline float wardWeight(float denominator) { return 1.0f / std::max(denominator, 1e-6f); }

// Pixels [x0, x1) × [y0, y1) a record may be valid in.
struct PixelWindow {
    int x0 = 0, y0 = 0, x1 = 0, y1 = 0;
    bool contains(int x, int y) const { return x >= x0 && x < x1 && y >= y0 && y < y1; }
};

// The bounding box on the image of the sphere of radius `reach` around
// `centre`, from the projections of its bounding cube's corners (the image of
// a convex set lies in the hull of the images of a convex set around it).
// If a corner is behind the camera the whole image is returned. The camera's
// width and height must be the film's.
inline PixelWindow recordWindow(const Camera& camera, const Vec3& centre, float reach) {
    const PixelWindow whole{0, 0, camera.width, camera.height};
    Vec2 lo(kInfinity), hi(-kInfinity);
    for (int corner = 0; corner < 8; ++corner) {
        const Vec3 p = centre + reach * Vec3(corner & 1 ? 1.0f : -1.0f, corner & 2 ? 1.0f : -1.0f, corner & 4 ? 1.0f : -1.0f);
        Vec2 raster;
        if (!camera.project(p, &raster) || !std::isfinite(raster.x) || !std::isfinite(raster.y)) return whole;
        lo = glm::min(lo, raster);
        hi = glm::max(hi, raster);
    }
    const auto pixelIndex = [](float v, int size) { return static_cast<int>(std::clamp(v, 0.0f, static_cast<float>(size))); };
    return {pixelIndex(std::floor(lo.x), camera.width), pixelIndex(std::floor(lo.y), camera.height),
            pixelIndex(std::floor(hi.x) + 1.0f, camera.width), pixelIndex(std::floor(hi.y) + 1.0f, camera.height)};
}

struct RadianceCachePlacement {
    std::vector<std::uint32_t> recordPixels;  // in placement order
    std::vector<PixelWindow> windows;         // per record
    std::vector<std::size_t> recordsPerPass;
    std::vector<std::uint32_t> coverage;            // per pixel: records valid at its sample
    std::vector<std::uint32_t> undercoveredPixels;  // valid pixels with coverage < minRecords, ascending
};

// Gautron et al.'s multi-pass placement over `samples` (one per pixel of a
// camera.width × camera.height image, row-major). Records of one pass are
// chosen from the coverage left by the previous passes, so each pass is
// independent of the thread count; coverage is updated row by row. Before a
// pass's records are splatted onto the image, `measureRadius(pixel)` may set
// their samples' radius (called once per record, from any thread); samples
// that no pass picks need none.
template <class MeasureRadius>
RadianceCachePlacement placeCacheRecords(std::vector<CachePixelSample>& samples, const Camera& camera,
                                         const RadianceCacheSettings& settings, const MeasureRadius& measureRadius) {
    const int width = camera.width, height = camera.height;
    RadianceCachePlacement placement;
    placement.coverage.assign(samples.size(), 0);
    std::vector<bool> hasRecord(samples.size(), false);
    for (int pass = 0; pass < settings.passes; ++pass) {
        const int step = std::max(1, settings.grid >> pass);
        const std::size_t first = placement.recordPixels.size();
        for (int y = step / 2; y < height; y += step)
            for (int x = step / 2; x < width; x += step) {
                const auto pixel = static_cast<std::uint32_t>(y * width + x);
                if (!samples[pixel].valid || hasRecord[pixel] ||
                    placement.coverage[pixel] >= static_cast<std::uint32_t>(settings.minRecords))
                    continue;
                hasRecord[pixel] = true;
                placement.recordPixels.push_back(pixel);
            }
        const std::size_t last = placement.recordPixels.size();
        placement.windows.resize(last);
        jobs::parallelFor(last - first, 1, [&](std::size_t i) { measureRadius(placement.recordPixels[first + i]); });
        jobs::parallelFor(last - first, 64, [&](std::size_t i) {
            const CachePixelSample& record = samples[placement.recordPixels[first + i]];
            placement.windows[first + i] = recordWindow(camera, record.position, settings.error * record.radius);
        });
        jobs::parallelFor(static_cast<std::size_t>(height), 1, [&](std::size_t row) {
            const int y = static_cast<int>(row);
            for (std::size_t k = first; k < last; ++k) {
                const PixelWindow& window = placement.windows[k];
                if (y < window.y0 || y >= window.y1) continue;
                const CachePixelSample& record = samples[placement.recordPixels[k]];
                for (int x = window.x0; x < window.x1; ++x) {
                    const std::size_t pixel = row * static_cast<std::size_t>(width) + static_cast<std::size_t>(x);
                    const CachePixelSample& at = samples[pixel];
                    if (at.valid && wardDenominator(at.position, at.normal, record.position, record.normal,
                                                    record.radius) < settings.error)
                        ++placement.coverage[pixel];
                }
            }
        });
        placement.recordsPerPass.push_back(last - first);
    }
    for (std::size_t pixel = 0; pixel < samples.size(); ++pixel)
        if (samples[pixel].valid && placement.coverage[pixel] < static_cast<std::uint32_t>(settings.minRecords))
            placement.undercoveredPixels.push_back(static_cast<std::uint32_t>(pixel));
    return placement;
}

// The placement's parameters, which cache_select and radiance_cache both
// declare (first, in this order).
inline std::vector<ParamSpec> placementParams() {
    return {
        {"error", ParamType::Float, 0.7, 0.01, 1.0, {},
         "ε: a record is used where its Ward weight exceeds 1/ε (smaller: more, smaller records)"},
        {"grid", ParamType::Int, std::int64_t{32}, 1, 4096, {}, "pixel spacing of the first placement pass"},
        {"passes", ParamType::Int, std::int64_t{3}, 1, 12, {},
         "placement passes; each halves the grid spacing (at least 1 pixel)"},
        {"min_records", ParamType::Int, std::int64_t{4}, 1, 64, {},
         "records a pixel should be covered by; grid pixels covered by fewer get a record in the next pass"},
    };
}

// Preflight of the placement's `grid` and `passes` parameters (cache_select,
// radiance_cache): each pass halves the grid spacing, which must stay at
// least one pixel.
inline void checkPlacementGrid(const PreflightContext& pf) {
    const auto grid = pf.params.getInt("grid");
    const auto passes = pf.params.getInt("passes");
    if ((grid >> (passes - 1)) < 1)
        throw InputError(pf.source + ": pass '" + pf.instance + "': grid " + std::to_string(grid) + " cannot be halved " +
                         std::to_string(passes - 1) + " times; use a grid of at least " +
                         std::to_string(std::int64_t{1} << (passes - 1)) + " or fewer passes");
}

// The same with every sample's radius known beforehand.
inline RadianceCachePlacement placeCacheRecords(const std::vector<CachePixelSample>& samples, const Camera& camera,
                                                const RadianceCacheSettings& settings) {
    std::vector<CachePixelSample> copy = samples;
    return placeCacheRecords(copy, camera, settings, [](std::uint32_t) {});
}

// The records valid at a point of the image, found through each row's list
// of records whose window meets it (in record order, so that every point
// sums its records in the same order on any thread count).
class CacheRecordLookup {
public:
    CacheRecordLookup(std::span<const Vec3> positions, std::span<const Vec3> normals, std::span<const float> radii,
                      std::span<const PixelWindow> windows, int height, float error)
        : positions_(positions), normals_(normals), radii_(radii), windows_(windows), error_(error),
          rowRecords_(static_cast<std::size_t>(std::max(height, 0))) {
        for (std::size_t k = 0; k < windows.size(); ++k)
            for (int y = windows[k].y0; y < windows[k].y1; ++y)
                rowRecords_[static_cast<std::size_t>(y)].push_back(static_cast<std::uint32_t>(k));
    }

    // visit(k, w_k) for every record k valid at `position` (pixel x, y) with
    // `normal`, in record order; returns how many there were.
    template <class Visit>
    std::uint32_t forEachValid(int x, int y, const Vec3& position, const Vec3& normal, const Visit& visit) const {
        std::uint32_t count = 0;
        for (std::uint32_t k : rowRecords_[static_cast<std::size_t>(y)]) {
            if (!windows_[k].contains(x, y)) continue;
            const float denominator = wardDenominator(position, normal, positions_[k], normals_[k], radii_[k]);
            if (!(denominator < error_)) continue;
            visit(k, wardWeight(denominator));
            ++count;
        }
        return count;
    }

private:
    std::span<const Vec3> positions_, normals_;
    std::span<const float> radii_;
    std::span<const PixelWindow> windows_;
    float error_;
    std::vector<std::vector<std::uint32_t>> rowRecords_;
};

// Translational gradients of a record's coefficients (Ward & Heckbert 1992
// use them to make the interpolation first-order): per coefficient and
// channel, a world-space vector in the record's tangent plane.
using CacheGradientArray = std::array<std::array<Vec3, 3>, 16>;

// Gradients by least squares over the record's neighbours, the other records
// at whose position and normal it is valid: in the tangent plane of record
// k, g minimises Σ_j (c_j − c_k − g·(x_j − x_k))². Exact for a field linear
// over the plane; zero where the neighbours do not span the plane (fewer than
// two, or all on one line). All records against all: the caches here hold
// hundreds.
inline std::vector<CacheGradientArray> neighbourGradients(std::span<const Vec3> positions, std::span<const Vec3> normals,
                                                          std::span<const float> radii,
                                                          std::span<const CacheCoefficientArray> coefficients,
                                                          float error) {
    std::vector<CacheGradientArray> gradients(positions.size());
    jobs::parallelFor(positions.size(), 8, [&](std::size_t k) {
        const Frame frame(normals[k]);
        double a00 = 0.0, a01 = 0.0, a11 = 0.0;
        std::array<std::array<double, 6>, 16> b{};  // per coefficient: (s, t) × (r, g, b)
        for (std::size_t j = 0; j < positions.size(); ++j) {
            if (j == k || !(wardDenominator(positions[j], normals[j], positions[k], normals[k], radii[k]) < error)) continue;
            const Vec3 offset = positions[j] - positions[k];
            const double u = glm::dot(offset, frame.s), v = glm::dot(offset, frame.t);
            a00 += u * u;
            a01 += u * v;
            a11 += v * v;
            for (std::size_t c = 0; c < 16; ++c)
                for (int channel = 0; channel < 3; ++channel) {
                    const double difference = static_cast<double>(coefficients[j][c][channel]) - coefficients[k][c][channel];
                    b[c][2 * channel] += u * difference;
                    b[c][2 * channel + 1] += v * difference;
                }
        }
        const double determinant = a00 * a11 - a01 * a01;
        CacheGradientArray& g = gradients[k];
        for (auto& perCoefficient : g) perCoefficient.fill(Vec3(0.0f));
        if (!(determinant > 1e-6 * (a00 + a11) * (a00 + a11))) return;
        for (std::size_t c = 0; c < 16; ++c)
            for (int channel = 0; channel < 3; ++channel) {
                const double bu = b[c][2 * channel], bv = b[c][2 * channel + 1];
                const double gu = (a11 * bu - a01 * bv) / determinant, gv = (a00 * bv - a01 * bu) / determinant;
                g[c][static_cast<std::size_t>(channel)] =
                    static_cast<float>(gu) * frame.s + static_cast<float>(gv) * frame.t;
            }
    });
    return gradients;
}

// Interpolated coefficients c(x) = Σ_k w_k (c_k + g_k·(x − x_k)) / Σ_k w_k
// over the records valid at x, g_k = 0 without gradients (`gradientsOf`
// returns null); false (and `out` untouched) where no record is valid.
template <class CoefficientsOf, class GradientsOf>
bool interpolateCache(const CacheRecordLookup& lookup, std::span<const Vec3> recordPositions, int x, int y,
                      const Vec3& position, const Vec3& normal, const CoefficientsOf& coefficientsOf,
                      const GradientsOf& gradientsOf, CacheCoefficientArray& out) {
    CacheCoefficientArray sum;
    sum.fill(Rgb(0.0f));
    float weightTotal = 0.0f;
    lookup.forEachValid(x, y, position, normal, [&](std::uint32_t k, float w) {
        const CacheCoefficientArray& c = coefficientsOf(k);
        const CacheGradientArray* g = gradientsOf(k);
        const Vec3 offset = position - recordPositions[k];
        for (std::size_t i = 0; i < sum.size(); ++i) {
            Rgb value = c[i];
            if (g)
                for (int channel = 0; channel < 3; ++channel)
                    value[channel] += glm::dot((*g)[i][static_cast<std::size_t>(channel)], offset);
            sum[i] += w * value;
        }
        weightTotal += w;
    });
    if (!(weightTotal > 0.0f)) return false;
    for (std::size_t i = 0; i < sum.size(); ++i) out[i] = sum[i] / weightTotal;
    return true;
}

// Cosine-distributed directions over the hemisphere around +z, one at the
// centre of each of strata × strata cells of the unit square (Ward et al.'s
// stratified hemisphere sampling without jitter, so that a record's radius
// does not depend on a random stream).
inline std::vector<Vec3> harmonicMeanDistanceDirections(int strata) {
    std::vector<Vec3> directions;
    directions.reserve(static_cast<std::size_t>(strata * strata));
    for (int j = 0; j < strata; ++j)
        for (int i = 0; i < strata; ++i)
            directions.push_back(sampleCosineHemisphere(
                Vec2((static_cast<float>(i) + 0.5f) / static_cast<float>(strata),
                     (static_cast<float>(j) + 0.5f) / static_cast<float>(strata))));
    return directions;
}

// Ward et al.'s R = N / Σ 1 / d_i over N hit distances (rays that meet
// nothing count as infinitely far), held to [minRadius, maxRadius].
inline float harmonicMeanRadius(std::span<const float> distances, float minRadius, float maxRadius) {
    double inverseSum = 0.0;
    for (float d : distances)
        if (d > 0.0f && std::isfinite(d)) inverseSum += 1.0 / static_cast<double>(d);
    const double mean = inverseSum > 0.0 ? static_cast<double>(distances.size()) / inverseSum : static_cast<double>(maxRadius);
    return std::clamp(static_cast<float>(mean), minRadius, maxRadius);
}

}  // namespace fg
