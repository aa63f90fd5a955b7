// Guiding cache of Vorba et al. 2014, §4.3: record selection (Eq. 11) and
// validity radii.
#include "engine/guiding/guiding_cache.h"

#include "jobs/parallel.h"

#include <algorithm>
#include <cmath>
#include <vector>

namespace fg {

std::optional<std::uint32_t> GuidingCache::select(const Vec3& x, const Vec3& n, const GuidingCacheQuery& query) const {
    if (tree_.empty()) return std::nullopt;
    constexpr std::size_t kMaxCandidates = 64;
    const std::size_t m = std::min<std::size_t>(std::max<std::uint32_t>(1, query.candidates), kMaxCandidates);
    std::uint32_t ids[kMaxCandidates];
    float dist2[kMaxCandidates];
    const std::size_t found = tree_.nearest(x, m, kInfinity, std::span(ids, m), std::span(dist2, m));
    if (found == 0) return std::nullopt;
    // nearest() orders by distance: the last one found is the furthest.
    const float h = std::max(std::sqrt(dist2[found - 1]), 1e-12f);
    const auto normals = records.column<GuideNormal>();
    std::optional<std::uint32_t> best;
    float bestScore = kInfinity;
    for (std::size_t k = 0; k < found; ++k) {
        const float cosine = glm::dot(n, normals[ids[k]]);
        if (!(cosine > 0.0f)) continue;
        const float score = dist2[k] / h + 2.0f * std::sqrt(std::max(0.0f, 1.0f - cosine));
        if (score < bestScore || (score == bestScore && best && ids[k] < *best)) {
            bestScore = score;
            best = ids[k];
        }
    }
    return best;
}

std::optional<std::uint32_t> GuidingCache::lookup(const Vec3& x, const Vec3& n, const GuidingCacheQuery& query) const {
    const std::optional<std::uint32_t> chosen = select(x, n, query);
    if (!chosen) return std::nullopt;
    const float radius = records.column<GuideValidityRadius>()[*chosen];
    if (KdTree::distance2(x, records.column<GuidePosition>()[*chosen]) > radius * radius) return std::nullopt;
    return chosen;
}

// The supplement with the paper's derivation is not available; this follows
// Fig. 5. A lobe j points at a highlight at distance d; moving the record by Δx
// across the lobe's axis turns that direction by about Δx / d radians, which
// moves the lobe's mean on the square by about Δx / (d sqrt(2π)) (the map
// stretches areas by 2π, so lengths by sqrt(2π) on average). Between two
// Gaussians of covariance Σ whose means differ by Δμ, KL = ½ Δμᵀ Σ⁻¹ Δμ
// <= ½ |Δμ|² / λ_min(Σ); keeping it below τ in every direction gives
// Δx <= d sqrt(2π) sqrt(2 τ λ_min). The highlight's distance d is not known
// from the particles' directions alone; the training radius stands in for it.
// Lobes are combined by the π-weighted harmonic mean, then clamped to
// [0.5, 1] x the training radius as in the paper.
float validityRadius(const DirectionalGmm& gmm, float trainingRadius, float klThreshold) {
    double inverseSum = 0.0, weightSum = 0.0;
    for (const GmmComponent& c : gmm.components) {
        if (c.weight <= 0.0f) continue;
        const double trace = double(c.covXX) + c.covYY;
        const double det = double(c.covXX) * c.covYY - double(c.covXY) * c.covXY;
        const double lambdaMin = std::max(1e-12, 0.5 * trace - std::sqrt(std::max(0.0, 0.25 * trace * trace - det)));
        const double lobeRadius =
            double(trainingRadius) * std::sqrt(2.0 * M_PI) * std::sqrt(2.0 * double(klThreshold) * lambdaMin);
        inverseSum += c.weight / std::max(lobeRadius, 1e-30);
        weightSum += c.weight;
    }
    const float lo = 0.5f * trainingRadius, hi = trainingRadius;
    if (!(inverseSum > 0.0)) return hi;
    return std::clamp(static_cast<float>(weightSum / inverseSum), lo, hi);
}

void clampNeighbourRadii(GuidingCache& cache, std::uint32_t neighbours) {
    const std::size_t count = cache.records.size();
    if (count == 0) return;
    const auto positions = cache.records.column<GuidePosition>();
    const std::vector<float> before(cache.records.column<GuideValidityRadius>().begin(),
                                    cache.records.column<GuideValidityRadius>().end());
    auto radii = cache.records.column<GuideValidityRadius>();
    const std::size_t m = std::min<std::size_t>(std::max<std::uint32_t>(1, neighbours), 64);
    jobs::parallelForChunks(count, 256, [&](jobs::IndexRange r) {
        std::uint32_t ids[64];
        float dist2[64];
        for (std::size_t i = r.begin; i != r.end; ++i) {
            const std::size_t found = cache.tree().nearest(positions[i], m, kInfinity, std::span(ids, m), std::span(dist2, m));
            float radius = before[i];
            for (std::size_t k = 0; k < found; ++k)
                if (ids[k] != i) radius = std::min(radius, before[ids[k]] + std::sqrt(dist2[k]));
            radii[i] = radius;
        }
    });
}

}  // namespace fg
