// The uniform grid (and the PointIndex wrapper) against brute-force search.
#include "engine/point_grid.h"
#include "engine/point_index.h"
#include "jobs/parallel.h"
#include "jobs/random.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <limits>
#include <utility>
#include <vector>

namespace fg {
namespace {

using Neighbour = std::pair<float, std::uint32_t>;  // (distance², index): the queries' order

std::vector<Neighbour> bruteRadius(std::span<const Vec3> points, const Vec3& c, float r) {
    std::vector<Neighbour> out;
    for (std::size_t i = 0; i < points.size(); ++i) {
        const float d2 = PointGrid::distance2(c, points[i]);
        if (d2 <= r * r) out.emplace_back(d2, static_cast<std::uint32_t>(i));
    }
    std::sort(out.begin(), out.end());
    return out;
}

std::vector<Neighbour> bruteNearest(std::span<const Vec3> points, const Vec3& c, std::size_t k, float maxRadius) {
    std::vector<Neighbour> all = bruteRadius(points, c, maxRadius);
    if (all.size() > k) all.resize(k);
    return all;
}

std::vector<Neighbour> gridRadius(const PointGrid& grid, const Vec3& c, float r) {
    std::vector<Neighbour> out;
    grid.forEachInRadius(c, r, [&](std::uint32_t i, float d2) { out.emplace_back(d2, i); });
    std::sort(out.begin(), out.end());
    return out;
}

std::vector<Neighbour> gridNearest(const PointGrid& grid, const Vec3& c, std::size_t k, float maxRadius) {
    std::vector<std::uint32_t> ids(k + 3, 12345u);
    std::vector<float> d2(k + 3, -1.0f);
    const std::size_t found = grid.nearest(c, k, maxRadius, std::span(ids).first(k), std::span(d2).first(k));
    std::vector<Neighbour> out;
    for (std::size_t j = 0; j < found; ++j) out.emplace_back(d2[j], ids[j]);
    // Nothing past the k entries it was given is touched.
    for (std::size_t j = k; j < k + 3; ++j) EXPECT_EQ(ids[j], 12345u);
    return out;
}

// Point sets that stress a grid differently: filling a box, lying on a few
// planes (as photons on walls do), flat (one zero extent), with duplicates,
// and tightly clustered far from the rest.
std::vector<std::vector<Vec3>> pointSets() {
    jobs::Rng rng(11, jobs::streamKey("point-grid-test"), 0);
    std::vector<std::vector<Vec3>> sets;
    std::vector<Vec3> box, planes, flat, duplicates, clustered;
    for (int i = 0; i < 3000; ++i) box.push_back(Vec3(rng.uniform(), rng.uniform(), rng.uniform()) * Vec3(4, 2, 1));
    for (int i = 0; i < 3000; ++i) {
        const Vec2 u = rng.uniform2();
        switch (i % 3) {
        case 0: planes.emplace_back(u.x, u.y, 0.0f); break;
        case 1: planes.emplace_back(0.0f, u.x, u.y); break;
        default: planes.emplace_back(u.x, 1.0f, u.y); break;
        }
    }
    for (int i = 0; i < 2000; ++i) flat.emplace_back(rng.uniform() * 10.0f - 5.0f, 3.0f, rng.uniform());
    for (int i = 0; i < 500; ++i) {
        const Vec3 p(std::floor(rng.uniform() * 5.0f), std::floor(rng.uniform() * 5.0f), 0.5f);
        duplicates.push_back(p);
    }
    for (int i = 0; i < 1500; ++i) clustered.push_back(Vec3(rng.uniform(), rng.uniform(), rng.uniform()) * 1e-3f);
    for (int i = 0; i < 20; ++i) clustered.push_back(Vec3(100.0f + rng.uniform(), 50.0f, -20.0f));
    sets = {box, planes, flat, duplicates, clustered, {Vec3(1, 2, 3)}};
    return sets;
}

std::vector<Vec3> queriesFor(std::span<const Vec3> points, jobs::Rng& rng) {
    Vec3 lo(1e30f), hi(-1e30f);
    for (const Vec3& p : points) {
        lo = glm::min(lo, p);
        hi = glm::max(hi, p);
    }
    const Vec3 extent = glm::max(hi - lo, Vec3(1e-3f));
    std::vector<Vec3> queries;
    // Inside and around the bounds, on stored points, and far outside.
    for (int i = 0; i < 60; ++i)
        queries.push_back(lo - 0.2f * extent + Vec3(rng.uniform(), rng.uniform(), rng.uniform()) * 1.4f * extent);
    for (int i = 0; i < 10; ++i) queries.push_back(points[rng.uniformIndex(static_cast<std::uint32_t>(points.size()))]);
    queries.push_back(hi + 5.0f * extent);
    queries.push_back(lo - Vec3(0.0f, 3.0f * extent.y, 0.0f));
    return queries;
}

TEST(PointGrid, RadiusQueriesMatchBruteForce) {
    jobs::Rng rng(3, jobs::streamKey("point-grid-radius"), 0);
    std::size_t nonEmpty = 0;
    for (const std::vector<Vec3>& points : pointSets()) {
        const PointGrid grid(points);
        ASSERT_EQ(grid.size(), points.size());
        for (const Vec3& q : queriesFor(points, rng)) {
            for (float r : {0.0f, 1e-4f, 0.05f, 0.3f, 2.0f, 1000.0f}) {
                const auto expected = bruteRadius(points, q, r);
                EXPECT_EQ(gridRadius(grid, q, r), expected) << "radius " << r;
                nonEmpty += expected.empty() ? 0 : 1;
            }
            EXPECT_TRUE(gridRadius(grid, q, -1.0f).empty());
        }
    }
    EXPECT_GT(nonEmpty, 500u);
}

TEST(PointGrid, NearestQueriesMatchBruteForce) {
    jobs::Rng rng(4, jobs::streamKey("point-grid-nearest"), 0);
    const float unlimited = std::numeric_limits<float>::infinity();
    for (const std::vector<Vec3>& points : pointSets()) {
        const PointGrid grid(points);
        for (const Vec3& q : queriesFor(points, rng)) {
            for (std::size_t k : {1u, 7u, 50u, 400u}) {
                for (float r : {0.02f, 0.4f, unlimited}) {
                    const auto expected = bruteNearest(points, q, k, r);
                    EXPECT_EQ(gridNearest(grid, q, k, r), expected) << "k " << k << " radius " << r;
                }
            }
            // k larger than the set: every point, nearest first.
            EXPECT_EQ(gridNearest(grid, q, points.size() + 5, unlimited),
                      bruteNearest(points, q, points.size() + 5, unlimited));
        }
    }
}

TEST(PointGrid, CellSizeFollowsTheRequestedDensity) {
    jobs::Rng rng(5, jobs::streamKey("point-grid-cells"), 0);
    std::vector<Vec3> points;
    for (int i = 0; i < 8000; ++i) points.push_back(Vec3(rng.uniform(), rng.uniform(), rng.uniform()));
    for (float perCell : {1.0f, 8.0f, 64.0f}) {
        const PointGrid grid(points, {perCell});
        const auto dims = grid.dimensions();
        const double cells = static_cast<double>(dims[0]) * dims[1] * dims[2];
        // Never more cells than asked for, and not far fewer.
        EXPECT_LE(cells, 8000.0 / perCell);
        EXPECT_GE(cells, 0.5 * 8000.0 / perCell);
    }
    // A flat set gets one cell across its flat axis.
    std::vector<Vec3> flat;
    for (int i = 0; i < 1000; ++i) flat.emplace_back(rng.uniform(), 2.0f, rng.uniform());
    EXPECT_EQ(PointGrid(flat).dimensions()[1], 1);
}

TEST(PointGrid, EmptyAndInvalidInput) {
    const PointGrid empty(std::span<const Vec3>{});
    EXPECT_EQ(empty.size(), 0u);
    std::vector<std::uint32_t> ids(4);
    std::vector<float> d2(4);
    EXPECT_EQ(empty.nearest(Vec3(0.0f), 4, 1.0f, ids, d2), 0u);
    int visits = 0;
    empty.forEachInRadius(Vec3(0.0f), 10.0f, [&](std::uint32_t, float) { ++visits; });
    EXPECT_EQ(visits, 0);

    const std::vector<Vec3> bad = {Vec3(0.0f), Vec3(std::numeric_limits<float>::quiet_NaN(), 0.0f, 0.0f)};
    EXPECT_THROW(PointGrid{bad}, std::invalid_argument);
    // k = 0 and a negative radius find nothing.
    const std::vector<Vec3> one = {Vec3(0.0f)};
    const PointGrid single(one);
    EXPECT_EQ(single.nearest(Vec3(0.0f), 0, 1.0f, ids, d2), 0u);
    EXPECT_EQ(single.nearest(Vec3(0.0f), 4, -1.0f, ids, d2), 0u);
    EXPECT_EQ(single.nearest(Vec3(0.0f), 4, 0.0f, ids, d2), 1u);
}

// The stored order, and with it the order of visits, does not depend on the
// number of threads that built the grid.
TEST(PointGrid, BuildIsIndependentOfThreadCount) {
    jobs::Rng rng(6, jobs::streamKey("point-grid-threads"), 0);
    std::vector<Vec3> points;
    for (int i = 0; i < 50000; ++i) points.push_back(Vec3(rng.uniform(), rng.uniform(), 0.1f * rng.uniform()));
    const auto visits = [&](int threads) {
        const jobs::ThreadLimit limit(threads);
        const PointGrid grid(points);
        std::vector<std::uint32_t> order;
        for (int q = 0; q < 20; ++q)
            grid.forEachInRadius(points[static_cast<std::size_t>(q) * 997], 0.05f,
                                 [&](std::uint32_t i, float) { order.push_back(i); });
        return order;
    };
    const auto one = visits(1);
    EXPECT_GT(one.size(), 100u);
    EXPECT_EQ(one, visits(2));
}

TEST(PointIndex, SubsetReportsCallerIndices) {
    jobs::Rng rng(7, jobs::streamKey("point-index-subset"), 0);
    std::vector<Vec3> points;
    std::vector<std::uint32_t> ids;
    std::vector<Vec3> subset;
    for (std::uint32_t i = 0; i < 4000; ++i) {
        points.push_back(Vec3(rng.uniform(), rng.uniform(), rng.uniform()));
        if (i % 3 != 1) {
            ids.push_back(i);
            subset.push_back(points.back());
        }
    }
    PointIndex index;
    index.build(points, ids);
    ASSERT_EQ(index.size(), ids.size());
    std::vector<std::uint32_t> found(30);
    std::vector<float> d2(30);
    for (int q = 0; q < 50; ++q) {
        const Vec3 c(rng.uniform(), rng.uniform(), rng.uniform());
        const auto expected = bruteNearest(subset, c, 30, 0.3f);
        const std::size_t n = index.nearest(c, 30, 0.3f, found, d2);
        ASSERT_EQ(n, expected.size());
        for (std::size_t j = 0; j < n; ++j) {
            EXPECT_EQ(found[j], ids[expected[j].second]);
            EXPECT_EQ(d2[j], expected[j].first);
        }
        std::vector<std::uint32_t> inRadius;
        index.forEachInRadius(c, 0.1f, [&](std::uint32_t id, float) { inRadius.push_back(id); });
        std::sort(inRadius.begin(), inRadius.end());
        std::vector<std::uint32_t> expectedIds;
        for (const auto& [dist2, local] : bruteRadius(subset, c, 0.1f)) expectedIds.push_back(ids[local]);
        std::sort(expectedIds.begin(), expectedIds.end());
        EXPECT_EQ(inRadius, expectedIds);
    }
    EXPECT_THROW(index.build(points, {5, 3}), std::invalid_argument);
    EXPECT_THROW(index.build(points, {4000}), std::invalid_argument);
}

}  // namespace
}  // namespace fg
