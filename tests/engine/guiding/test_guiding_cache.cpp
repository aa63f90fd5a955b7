// Guiding cache (Vorba et al. 2014 §4.3): Eq. 11 selection against brute force,
// validity-radius clamps and neighbour clamping.
#include "engine/guiding/guiding_cache.h"

#include "jobs/random.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <vector>

namespace fg {
namespace {

Vec3 randomUnit(jobs::Rng& rng) {
    const Vec2 u = rng.uniform2();
    return sampleUniformSphere(u);
}

GuidingCache randomCache(std::size_t count, std::uint64_t key) {
    jobs::Rng rng(5, jobs::streamKey("cache-records"), key);
    GuidingCache cache;
    cache.records.resize(count);
    auto positions = cache.records.column<GuidePosition>();
    auto normals = cache.records.column<GuideNormal>();
    auto radii = cache.records.column<GuideValidityRadius>();
    for (std::size_t i = 0; i < count; ++i) {
        positions[i] = Vec3(rng.uniform(), rng.uniform(), rng.uniform());
        normals[i] = randomUnit(rng);
        radii[i] = 0.02f + 0.1f * rng.uniform();
    }
    cache.rebuildIndex();
    return cache;
}

std::optional<std::uint32_t> bruteForceSelect(const GuidingCache& cache, const Vec3& x, const Vec3& n, std::size_t m) {
    const auto positions = cache.records.column<GuidePosition>();
    const auto normals = cache.records.column<GuideNormal>();
    std::vector<std::pair<float, std::uint32_t>> byDistance;
    for (std::uint32_t i = 0; i < positions.size(); ++i) byDistance.push_back({KdTree::distance2(x, positions[i]), i});
    std::sort(byDistance.begin(), byDistance.end());
    byDistance.resize(std::min(m, byDistance.size()));
    const float h = std::max(std::sqrt(byDistance.back().first), 1e-12f);
    std::optional<std::uint32_t> best;
    float bestScore = kInfinity;
    for (const auto& [d2, i] : byDistance) {
        const float cosine = glm::dot(n, normals[i]);
        if (!(cosine > 0.0f)) continue;
        const float score = d2 / h + 2.0f * std::sqrt(std::max(0.0f, 1.0f - cosine));
        if (score < bestScore || (score == bestScore && best && i < *best)) {
            bestScore = score;
            best = i;
        }
    }
    return best;
}

TEST(GuidingCache, Eq11SelectionMatchesBruteForce) {
    const GuidingCache cache = randomCache(2000, 1);
    jobs::Rng rng(5, jobs::streamKey("cache-queries"), 0);
    int found = 0, reused = 0;
    for (int q = 0; q < 3000; ++q) {
        const Vec3 x(rng.uniform(), rng.uniform(), rng.uniform());
        const Vec3 n = randomUnit(rng);
        const auto expected = bruteForceSelect(cache, x, n, 16);
        const auto selected = cache.select(x, n);
        ASSERT_EQ(selected, expected) << q;
        if (selected) {
            ++found;
            const auto reuse = cache.lookup(x, n);
            const float r = cache.records.column<GuideValidityRadius>()[*selected];
            const bool inside = KdTree::distance2(x, cache.records.column<GuidePosition>()[*selected]) <= r * r;
            EXPECT_EQ(reuse.has_value(), inside);
            reused += inside ? 1 : 0;
        }
    }
    EXPECT_GT(found, 2500);
    EXPECT_GT(reused, 100);
    EXPECT_FALSE(GuidingCache{}.select(Vec3(0.0f), Vec3(0, 0, 1)).has_value());
}

// The records covering x that face n, best by Eq. 11 with h the distance to
// the furthest of them, ties to the lower index.
std::optional<std::uint32_t> bruteForceCovering(const GuidingCache& cache, const Vec3& x, const Vec3& n) {
    const auto positions = cache.records.column<GuidePosition>();
    const auto normals = cache.records.column<GuideNormal>();
    const auto radii = cache.records.column<GuideValidityRadius>();
    std::vector<std::uint32_t> covering;
    float h2 = 0.0f;
    for (std::uint32_t i = 0; i < positions.size(); ++i) {
        const float d2 = KdTree::distance2(x, positions[i]);
        if (d2 <= radii[i] * radii[i] && glm::dot(n, normals[i]) > 0.0f) {
            covering.push_back(i);
            h2 = std::max(h2, d2);
        }
    }
    const float h = std::max(std::sqrt(h2), 1e-12f);
    std::optional<std::uint32_t> best;
    float bestScore = kInfinity;
    for (std::uint32_t i : covering) {
        const float score = KdTree::distance2(x, positions[i]) / h +
                            2.0f * std::sqrt(std::max(0.0f, 1.0f - glm::dot(n, normals[i])));
        if (score < bestScore) {
            bestScore = score;
            best = i;
        }
    }
    return best;
}

// The cover grid finds what a scan of all records finds, for radii from far
// below to far above its cell size (a few large records among small ones).
TEST(GuidingCache, CoverGridLookupMatchesBruteForce) {
    GuidingCache cache = randomCache(2000, 2);
    auto radii = cache.records.column<GuideValidityRadius>();
    for (std::size_t i = 0; i < radii.size(); i += 97) radii[i] = 0.4f;
    EXPECT_FALSE(cache.lookupCovering(Vec3(0.5f), Vec3(0, 0, 1)).has_value());  // no grid yet
    cache.buildCoverGrid();
    ASSERT_TRUE(cache.hasCoverGrid());
    jobs::Rng rng(5, jobs::streamKey("cover-queries"), 0);
    int found = 0;
    for (int q = 0; q < 3000; ++q) {
        const Vec3 x(-0.2f + 1.4f * rng.uniform(), -0.2f + 1.4f * rng.uniform(), -0.2f + 1.4f * rng.uniform());
        const Vec3 n = randomUnit(rng);
        const auto expected = bruteForceCovering(cache, x, n);
        ASSERT_EQ(cache.lookupCovering(x, n), expected) << q;
        found += expected ? 1 : 0;
    }
    EXPECT_GT(found, 1000);
    EXPECT_LT(found, 3000);
}

TEST(GuidingCache, ValidityRadiusStaysWithinClamps) {
    jobs::Rng rng(5, jobs::streamKey("cache-radius"), 0);
    int atLower = 0, atUpper = 0, between = 0;
    for (int k = 0; k < 500; ++k) {
        DirectionalGmm gmm;
        const float scale = std::pow(10.0f, -5.0f + 5.0f * rng.uniform());
        for (GmmComponent& c : gmm.components) {
            c.weight = 0.05f + rng.uniform();
            c.mean = rng.uniform2();
            c.covXX = scale * (0.1f + rng.uniform());
            c.covYY = scale * (0.1f + rng.uniform());
            c.covXY = 0.5f * std::sqrt(c.covXX * c.covYY) * (2.0f * rng.uniform() - 1.0f);
        }
        ASSERT_TRUE(gmm.finalize());
        const float training = 0.01f + rng.uniform();
        const float r = validityRadius(gmm, training, 0.5f);
        EXPECT_GE(r, 0.5f * training);
        EXPECT_LE(r, training);
        atLower += r == 0.5f * training;
        atUpper += r == training;
        between += r > 0.5f * training && r < training;
    }
    // Narrow lobes reach the lower clamp, wide ones the upper, and some fall between.
    EXPECT_GT(atLower, 0);
    EXPECT_GT(atUpper, 0);
    EXPECT_GT(between, 0);
}

TEST(GuidingCache, NeighbourClampingBoundsRadii) {
    GuidingCache cache = randomCache(500, 2);
    const std::vector<float> before(cache.records.column<GuideValidityRadius>().begin(),
                                    cache.records.column<GuideValidityRadius>().end());
    clampNeighbourRadii(cache, 16);
    const auto positions = cache.records.column<GuidePosition>();
    const auto radii = cache.records.column<GuideValidityRadius>();
    int lowered = 0;
    for (std::uint32_t i = 0; i < positions.size(); ++i) {
        EXPECT_LE(radii[i], before[i]);
        lowered += radii[i] < before[i];
        std::uint32_t ids[16];
        float dist2[16];
        const std::size_t found = cache.tree().nearest(positions[i], 16, kInfinity, ids, dist2);
        for (std::size_t k = 0; k < found; ++k)
            EXPECT_LE(radii[i], before[ids[k]] + std::sqrt(dist2[k]) * (1.0f + 1e-6f));
    }
    EXPECT_GT(lowered, 0);
}

}  // namespace
}  // namespace fg
