// Guiding cache of Vorba et al. 2014, §4.3: record selection (Eq. 11) and
// validity radii.
#include "engine/guiding/guiding_cache.h"

#include "jobs/parallel.h"

#include <algorithm>
#include <array>
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

namespace {
// Cells per axis at most: 64³ cells of 4 bytes is 1 MiB of offsets.
constexpr int kMaxCoverResolution = 64;
// A grid whose lists would exceed this many entries is not built (lookups
// fall back to lookup()).
constexpr std::size_t kMaxCoverEntries = std::size_t{1} << 26;
// Covering candidates compared per lookup; more (in record order) are ignored.
constexpr std::size_t kMaxCovering = 64;
}  // namespace

void GuidingCache::buildCoverGrid() {
    coverOffsets_.clear();
    cellGuides_.clear();
    coverRecords_.clear();
    cover_.clear();
    const std::size_t count = records.size();
    if (count == 0) return;
    const auto positions = records.column<GuidePosition>();
    const auto radii = records.column<GuideValidityRadius>();
    Vec3 lo(kInfinity), hi(-kInfinity);
    std::vector<float> sorted(radii.begin(), radii.end());
    for (std::size_t i = 0; i < count; ++i) {
        lo = glm::min(lo, positions[i] - Vec3(radii[i]));
        hi = glm::max(hi, positions[i] + Vec3(radii[i]));
    }
    std::nth_element(sorted.begin(), sorted.begin() + static_cast<std::ptrdiff_t>(count / 2), sorted.end());
    const Vec3 extent = hi - lo;
    const float widest = std::max({extent.x, extent.y, extent.z});
    // Cells about as wide as a typical record's cover: a cell then lists few
    // records, and a record few cells, except the large ones.
    const float cell = std::max({sorted[count / 2], widest / kMaxCoverResolution, 1e-6f});
    std::size_t cells = 1;
    for (int a = 0; a < 3; ++a) {
        resolution_[a] = std::clamp(static_cast<int>(std::ceil(extent[a] / cell)), 1, kMaxCoverResolution);
        cells *= static_cast<std::size_t>(resolution_[a]);
    }
    gridLo_ = lo;
    cellInverse_ = 1.0f / cell;
    const auto cellRange = [&](std::size_t i, int a) {
        const float c = positions[i][a], r = radii[i];
        return std::pair<int, int>(std::clamp(static_cast<int>(std::floor((c - r - lo[a]) * cellInverse_)), 0, resolution_[a] - 1),
                                   std::clamp(static_cast<int>(std::floor((c + r - lo[a]) * cellInverse_)), 0, resolution_[a] - 1));
    };
    // Whether record i's sphere reaches cell (x, y, z): distance from its
    // centre to the cell's box at most its radius.
    const auto reaches = [&](std::size_t i, int x, int y, int z) {
        const int cellIndex[3] = {x, y, z};
        float d2 = 0.0f;
        for (int a = 0; a < 3; ++a) {
            const float boxLo = lo[a] + static_cast<float>(cellIndex[a]) * cell, boxHi = boxLo + cell;
            const float c = positions[i][a];
            const float d = c < boxLo ? boxLo - c : (c > boxHi ? c - boxHi : 0.0f);
            d2 += d * d;
        }
        return d2 <= radii[i] * radii[i];
    };
    const auto forCells = [&](std::size_t i, auto&& f) {
        const auto [x0, x1] = cellRange(i, 0);
        const auto [y0, y1] = cellRange(i, 1);
        const auto [z0, z1] = cellRange(i, 2);
        for (int z = z0; z <= z1; ++z)
            for (int y = y0; y <= y1; ++y)
                for (int x = x0; x <= x1; ++x)
                    if (reaches(i, x, y, z))
                        f((static_cast<std::size_t>(z) * resolution_[1] + y) * resolution_[0] + x);
    };
    std::vector<std::uint32_t> offsets(cells + 1, 0);
    std::size_t entries = 0;
    for (std::size_t i = 0; i < count; ++i)
        forCells(i, [&](std::size_t c) {
            ++offsets[c + 1];
            ++entries;
        });
    if (entries > kMaxCoverEntries) return;
    for (std::size_t c = 0; c < cells; ++c) offsets[c + 1] += offsets[c];
    std::vector<std::uint32_t> cursor(offsets.begin(), offsets.end() - 1);
    coverRecords_.resize(entries);
    for (std::size_t i = 0; i < count; ++i)
        forCells(i, [&](std::size_t c) { coverRecords_[cursor[c]++] = static_cast<std::uint32_t>(i); });
    coverOffsets_ = std::move(offsets);
    const auto normals = records.column<GuideNormal>();
    const auto gmms = records.column<GuideMixture>();
    const auto bsdfOnly = records.column<GuideBsdfOnly>();
    cover_.resize(count);
    for (std::size_t i = 0; i < count; ++i)
        cover_[i] = {positions[i], radii[i] * radii[i], normals[i], bsdfOnly[i] == 0 && gmms[i].usable() ? 1u : 0u};
    cellGuides_.assign(cells, 0);
    for (std::size_t c = 0; c < cells; ++c)
        for (std::uint32_t k = coverOffsets_[c]; k != coverOffsets_[c + 1]; ++k)
            if (cover_[coverRecords_[k]].usable) {
                cellGuides_[c] = 1;
                break;
            }
}

bool GuidingCache::anyGuides() const {
    for (std::uint32_t i = 0; i < records.size(); ++i)
        if (guides(i)) return true;
    return false;
}

std::optional<std::uint32_t> GuidingCache::lookupGuiding(const Vec3& x, const Vec3& n) const {
    const std::optional<std::size_t> cell = coverCell(x);
    if (!cell || !cellGuides_[*cell]) return std::nullopt;
    const std::optional<std::uint32_t> record = scanCell(*cell, x, n);
    if (!record || !usable(*record)) return std::nullopt;
    return record;
}

std::optional<std::size_t> GuidingCache::coverCell(const Vec3& x) const {
    if (!hasCoverGrid()) return std::nullopt;
    int cellIndex[3];
    for (int a = 0; a < 3; ++a) {
        const float f = std::floor((x[a] - gridLo_[a]) * cellInverse_);
        if (!(f >= 0.0f && f < static_cast<float>(resolution_[a]))) return std::nullopt;  // no record reaches x
        cellIndex[a] = static_cast<int>(f);
    }
    return (static_cast<std::size_t>(cellIndex[2]) * resolution_[1] + cellIndex[1]) * resolution_[0] + cellIndex[0];
}

std::optional<std::uint32_t> GuidingCache::lookupCovering(const Vec3& x, const Vec3& n) const {
    const std::optional<std::size_t> cell = coverCell(x);
    if (!cell) return std::nullopt;
    return scanCell(*cell, x, n);
}

std::optional<std::uint32_t> GuidingCache::scanCell(std::size_t cell, const Vec3& x, const Vec3& n) const {
    std::uint32_t ids[kMaxCovering];
    float dist2[kMaxCovering], angular[kMaxCovering];
    std::size_t found = 0;
    float h2 = 0.0f;
    for (std::uint32_t k = coverOffsets_[cell]; k != coverOffsets_[cell + 1] && found < kMaxCovering; ++k) {
        const std::uint32_t i = coverRecords_[k];
        const CoverRecord& record = cover_[i];
        const float d2 = KdTree::distance2(x, record.position);
        if (d2 > record.radius2) continue;
        const float cosine = glm::dot(n, record.normal);
        if (!(cosine > 0.0f)) continue;
        ids[found] = i;
        dist2[found] = d2;
        angular[found] = 2.0f * std::sqrt(std::max(0.0f, 1.0f - cosine));
        h2 = std::max(h2, d2);
        ++found;
    }
    if (found == 0) return std::nullopt;
    const float h = std::max(std::sqrt(h2), 1e-12f);
    // Lists are in record order, so a strict comparison keeps the lower index on ties.
    std::size_t best = 0;
    float bestScore = kInfinity;
    for (std::size_t k = 0; k < found; ++k) {
        const float score = dist2[k] / h + angular[k];
        if (score < bestScore) {
            bestScore = score;
            best = k;
        }
    }
    return ids[best];
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

// The particles are a weighted sample of the density q on the square that is
// proportional to L_i cos (the flux a surface receives per solid angle; the
// map's Jacobian is constant). For a strategy of density p_s on the square
// (p_s = 2π p_ω), the estimate g / p of I = ∫ g dω, g = L_i cos, has the
// relative second moment ∫ g² / p dω / I² = ∫ q² / p_s ds = E_q[q / p_s],
// which the particles estimate as Σ w_j q(s_j) / p_s(s_j) / Σ w_j. q is not
// known at the particles; the fitted mixture stands in for it (the model of
// q that §4.1 trains). That favours guiding: on its own training particles a
// mixture looks closer to q than it is (against quadrature of the true
// radiance, the guided moment comes out at about a third, the BSDF's, for
// broad light, up to 3.5x, as the mixture does not vanish at the horizon as
// q does), which cache_update's threshold (guide_moment_ratio 0.3) allows
// for. An estimate from a histogram of the particles instead (8 x 8 cells,
// q² from pairs of distinct particles) erred the other way, its cells wider
// than a gap's lobe, and left more of veach-ajar's useful records unguided.
// BSDF sampling of a diffuse surface has p_s = 2π cos/π = 2 cos; the cosine
// is clamped at 1/64 (a degree from the horizon).
OneBounceVariance oneBounceVariance(const DirectionalGmm& gmm, std::span<const WeightedPoint> points,
                                    float bsdfProbability) {
    double total = 0.0, bsdfMoment = 0.0, mixtureMoment = 0.0;
    const double alpha = bsdfProbability;
    for (const WeightedPoint& point : points) {
        const double a = 2.0 * point.s.x - 1.0, b = 2.0 * point.s.y - 1.0;
        const double r = std::max(std::abs(a), std::abs(b));
        const double bsdfPdf = 2.0 * std::max(1.0 - r * r, 1.0 / 64.0);
        const double q = gmm.pdfSquare(point.s);
        total += point.weight;
        bsdfMoment += point.weight * q / bsdfPdf;
        mixtureMoment += point.weight * q / (alpha * bsdfPdf + (1.0 - alpha) * q);
    }
    if (!(total > 0.0)) return {};
    return {bsdfMoment / total - 1.0, mixtureMoment / total - 1.0};
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
