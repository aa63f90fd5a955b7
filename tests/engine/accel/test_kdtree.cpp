#include "engine/accel/kdtree.h"

#include "jobs/parallel.h"
#include "jobs/random.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <numeric>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace fg {
namespace {

using Neighbour = std::pair<float, std::uint32_t>;  // (distance², index)

jobs::Rng makeRng(std::uint64_t seed) { return jobs::Rng(seed, jobs::streamKey("kdtree-test"), 0); }

Vec3 uniformPoint(jobs::Rng& rng) {
    const float x = rng.uniform();
    const float y = rng.uniform();
    const float z = rng.uniform();
    return {x, y, z};
}

std::vector<Vec3> uniformPoints(std::size_t n, std::uint64_t seed) {
    jobs::Rng rng = makeRng(seed);
    std::vector<Vec3> points(n);
    for (Vec3& p : points) p = uniformPoint(rng);
    return points;
}

// Tight clusters of very different sizes plus a flat sheet (photons landing on
// a floor): extents differ by orders of magnitude between subtrees.
std::vector<Vec3> clusteredPoints(std::size_t n, std::uint64_t seed) {
    jobs::Rng rng = makeRng(seed);
    const Vec3 centers[] = {{0.1f, 0.2f, 0.3f}, {0.8f, 0.8f, 0.1f}, {0.5f, 0.1f, 0.9f}};
    const float spreads[] = {1e-3f, 2e-2f, 1e-1f};
    std::vector<Vec3> points(n);
    for (std::size_t i = 0; i < n; ++i) {
        const std::uint32_t which = rng.uniformIndex(4);
        if (which == 3) {
            const float x = rng.uniform();
            const float y = rng.uniform();
            points[i] = Vec3(x, y, 0.5f);
        } else {
            const Vec3 offset = uniformPoint(rng) - Vec3(0.5f);
            points[i] = centers[which] + spreads[which] * offset;
        }
    }
    return points;
}

// Many exact copies of a few positions: ties in coordinates and distances.
std::vector<Vec3> duplicatedPoints(std::size_t n, std::size_t distinct, std::uint64_t seed) {
    jobs::Rng rng = makeRng(seed);
    const std::vector<Vec3> sites = uniformPoints(distinct, seed + 1);
    std::vector<Vec3> points(n);
    for (Vec3& p : points) p = sites[rng.uniformIndex(static_cast<std::uint32_t>(distinct))];
    return points;
}

// Integer lattice: distances are small exact integers, so radii land exactly on
// points and split planes pass through many points.
std::vector<Vec3> latticePoints(int side) {
    std::vector<Vec3> points;
    for (int z = 0; z < side; ++z)
        for (int y = 0; y < side; ++y)
            for (int x = 0; x < side; ++x) points.emplace_back(float(x), float(y), float(z));
    return points;
}

std::vector<Neighbour> bruteRange(std::span<const Vec3> points, const Vec3& center, float radius) {
    std::vector<Neighbour> found;
    if (!(radius >= 0.0f)) return found;
    for (std::size_t i = 0; i < points.size(); ++i) {
        const float d2 = KdTree::distance2(center, points[i]);
        if (d2 <= radius * radius) found.emplace_back(d2, static_cast<std::uint32_t>(i));
    }
    std::sort(found.begin(), found.end());
    return found;
}

std::vector<Neighbour> bruteNearest(std::span<const Vec3> points, const Vec3& center, std::size_t k, float maxRadius) {
    std::vector<Neighbour> found = bruteRange(points, center, maxRadius);
    if (found.size() > k) found.resize(k);
    return found;
}

std::vector<Neighbour> treeRange(const KdTree& tree, const Vec3& center, float radius) {
    std::vector<Neighbour> found;
    tree.forEachInRadius(center, radius, [&](std::uint32_t index, float d2) { found.emplace_back(d2, index); });
    std::sort(found.begin(), found.end());
    return found;
}

std::vector<Neighbour> treeNearest(const KdTree& tree, const Vec3& center, std::size_t k, float maxRadius) {
    std::vector<std::uint32_t> indices(k + 3, 0xDEADBEEFu);
    std::vector<float> dist2(k + 3, -1.0f);
    const std::size_t count =
        tree.nearest(center, k, maxRadius, std::span(indices).first(k), std::span(dist2).first(k));
    EXPECT_LE(count, k);
    // Nothing past the k slots handed over may be touched.
    for (std::size_t i = k; i < k + 3; ++i) {
        EXPECT_EQ(indices[i], 0xDEADBEEFu);
        EXPECT_EQ(dist2[i], -1.0f);
    }
    std::vector<Neighbour> found;
    for (std::size_t i = 0; i < std::min(count, k); ++i) found.emplace_back(dist2[i], indices[i]);
    return found;
}

// Every inner node separates its halves at its split value on its axis, the
// permutation is a permutation, and the shape is the documented one.
void expectWellFormed(const KdTree& tree, std::span<const Vec3> points) {
    ASSERT_EQ(tree.size(), points.size());
    const auto order = tree.permutation();
    ASSERT_EQ(order.size(), points.size());
    std::vector<std::uint32_t> sorted(order.begin(), order.end());
    std::sort(sorted.begin(), sorted.end());
    for (std::size_t i = 0; i < sorted.size(); ++i) ASSERT_EQ(sorted[i], i);

    const auto splits = tree.splits();
    struct Node {
        std::size_t node, begin, end;
    };
    std::vector<Node> pending{{0, 0, points.size()}};
    std::size_t inner = 0;
    std::size_t maxInnerSlot = 0;
    while (!pending.empty()) {
        const Node n = pending.back();
        pending.pop_back();
        if (n.end - n.begin <= tree.maxLeafSize()) continue;
        ++inner;
        maxInnerSlot = std::max(maxInnerSlot, n.node);
        ASSERT_LT(n.node, splits.size());
        const KdTree::Split s = splits[n.node];
        ASSERT_LT(s.axis, 3u);
        const std::size_t mid = n.begin + (n.end - n.begin) / 2;
        for (std::size_t i = n.begin; i < mid; ++i) ASSERT_LE(points[order[i]][int(s.axis)], s.value);
        for (std::size_t i = mid; i < n.end; ++i) ASSERT_GE(points[order[i]][int(s.axis)], s.value);
        pending.push_back({2 * n.node + 1, n.begin, mid});
        pending.push_back({2 * n.node + 2, mid, n.end});
    }
    if (inner > 0) {
        EXPECT_EQ(maxInnerSlot + 1, splits.size()) << "heap array longer than its deepest inner node";
        EXPECT_LE(splits.size(), 2 * inner + 1);
    } else {
        EXPECT_TRUE(splits.empty());
    }
}

struct PointSet {
    std::string name;
    std::vector<Vec3> points;
    float scale;  // typical spacing, to pick useful radii
};

std::vector<PointSet> pointSets() {
    return {
        {"uniform", uniformPoints(3000, 11), 0.08f},
        {"clustered", clusteredPoints(3000, 12), 0.02f},
        {"duplicates", duplicatedPoints(2500, 40, 13), 0.15f},
        {"all-equal", std::vector<Vec3>(700, Vec3(0.25f, -3.0f, 7.5f)), 0.1f},
        {"lattice", latticePoints(12), 1.0f},
        {"single", {Vec3(0.5f, 0.5f, 0.5f)}, 0.1f},
        {"tiny", uniformPoints(5, 14), 0.3f},
    };
}

// Query centres: random ones around the set, the points themselves (distance 0
// and exact ties) and midpoints between two points (equidistant pairs).
std::vector<Vec3> queryCenters(std::span<const Vec3> points, std::size_t count, std::uint64_t seed) {
    jobs::Rng rng = makeRng(seed);
    Vec3 lo(std::numeric_limits<float>::max()), hi(-std::numeric_limits<float>::max());
    for (const Vec3& p : points) {
        lo = glm::min(lo, p);
        hi = glm::max(hi, p);
    }
    const Vec3 margin = 0.1f * (hi - lo) + Vec3(0.05f);
    std::vector<Vec3> centers;
    for (std::size_t i = 0; i < count; ++i) {
        const auto n = static_cast<std::uint32_t>(points.size());
        switch (i % 3) {
            case 0: centers.push_back(lo - margin + uniformPoint(rng) * (hi - lo + 2.0f * margin)); break;
            case 1: centers.push_back(points[rng.uniformIndex(n)]); break;
            default: centers.push_back(0.5f * (points[rng.uniformIndex(n)] + points[rng.uniformIndex(n)])); break;
        }
    }
    return centers;
}

const std::uint32_t kLeafSizes[] = {1, 2, 3, 8, 32};

TEST(KdTree, RangeQueriesMatchBruteForce) {
    for (const PointSet& set : pointSets()) {
        const std::vector<Vec3> centers = queryCenters(set.points, 300, 21);
        for (std::uint32_t leaf : kLeafSizes) {
            SCOPED_TRACE(set.name + ", leaf size " + std::to_string(leaf));
            const KdTree tree(set.points, {.maxLeafSize = leaf});
            expectWellFormed(tree, set.points);
            jobs::Rng rng = makeRng(22);
            std::size_t nonEmpty = 0;
            for (std::size_t q = 0; q < centers.size(); ++q) {
                // Radius 0, whole multiples of the spacing (exact on the lattice)
                // and random radii.
                const float radius = q % 5 == 0   ? 0.0f
                                     : q % 5 == 1 ? set.scale * float(q % 4)
                                                  : set.scale * 3.0f * rng.uniform();
                const auto expected = bruteRange(set.points, centers[q], radius);
                const auto actual = treeRange(tree, centers[q], radius);
                ASSERT_EQ(actual, expected) << "query " << q << " radius " << radius;
                nonEmpty += !expected.empty();
            }
            // The comparison above must have been about something.
            EXPECT_GT(nonEmpty, centers.size() / 4);
        }
    }
}

TEST(KdTree, BoxQueriesMatchBruteForce) {
    for (const PointSet& set : pointSets()) {
        const std::vector<Vec3> centers = queryCenters(set.points, 300, 23);
        for (std::uint32_t leaf : kLeafSizes) {
            SCOPED_TRACE(set.name + ", leaf size " + std::to_string(leaf));
            const KdTree tree(set.points, {.maxLeafSize = leaf});
            jobs::Rng rng = makeRng(24);
            std::size_t nonEmpty = 0;
            for (std::size_t q = 0; q < centers.size(); ++q) {
                // Flat, thin, cubic and empty boxes; on the lattice, faces through points.
                Vec3 half(set.scale * 3.0f * rng.uniform(), set.scale * 3.0f * rng.uniform(),
                          set.scale * 3.0f * rng.uniform());
                if (q % 4 == 0) half[static_cast<int>(q % 3)] = 0.0f;
                if (q % 7 == 1) half = Vec3(set.scale * float(q % 3));
                Vec3 lo = centers[q] - half, hi = centers[q] + half;
                if (q % 11 == 2) std::swap(lo.x, hi.x);  // inverted: finds nothing unless flat
                std::vector<std::uint32_t> expected, actual;
                for (std::size_t i = 0; i < set.points.size(); ++i) {
                    const Vec3& p = set.points[i];
                    if (p.x >= lo.x && p.x <= hi.x && p.y >= lo.y && p.y <= hi.y && p.z >= lo.z && p.z <= hi.z)
                        expected.push_back(static_cast<std::uint32_t>(i));
                }
                tree.forEachInBox(lo, hi, [&](std::uint32_t index) { actual.push_back(index); });
                std::sort(actual.begin(), actual.end());
                ASSERT_EQ(actual, expected) << "query " << q;
                nonEmpty += !expected.empty();
            }
            EXPECT_GT(nonEmpty, centers.size() / 4);
        }
    }
}

TEST(KdTree, NearestQueriesMatchBruteForce) {
    const float unlimited = std::numeric_limits<float>::infinity();
    for (const PointSet& set : pointSets()) {
        const std::vector<Vec3> centers = queryCenters(set.points, 240, 31);
        for (std::uint32_t leaf : kLeafSizes) {
            SCOPED_TRACE(set.name + ", leaf size " + std::to_string(leaf));
            const KdTree tree(set.points, {.maxLeafSize = leaf});
            jobs::Rng rng = makeRng(32);
            for (std::size_t q = 0; q < centers.size(); ++q) {
                const std::size_t k = q % 4 == 0 ? 1 : 1 + rng.uniformIndex(60);
                const float maxRadius = q % 3 == 0 ? unlimited : q % 3 == 1 ? 0.0f : set.scale * 4.0f * rng.uniform();
                const auto expected = bruteNearest(set.points, centers[q], k, maxRadius);
                const auto actual = treeNearest(tree, centers[q], k, maxRadius);
                ASSERT_EQ(actual, expected) << "query " << q << " k " << k << " maxRadius " << maxRadius;
            }
        }
    }
}

TEST(KdTree, LatticeRadiusBoundaryIsInclusive) {
    const std::vector<Vec3> points = latticePoints(9);
    const KdTree tree(points, {.maxLeafSize = 4});
    const Vec3 center(4.0f, 4.0f, 4.0f);
    auto countWithin = [&](float radius) {
        std::size_t count = 0;
        tree.forEachInRadius(center, radius, [&](std::uint32_t, float) { ++count; });
        return count;
    };
    EXPECT_EQ(countWithin(0.0f), 1u);
    EXPECT_EQ(countWithin(0.999f), 1u);
    EXPECT_EQ(countWithin(1.0f), 7u);   // centre + 6 face neighbours
    EXPECT_EQ(countWithin(1.5f), 19u);  // + 12 edge neighbours
    EXPECT_EQ(countWithin(2.0f), 33u);  // + 8 corners + 6 at distance 2
    EXPECT_EQ(countWithin(-1.0f), 0u);

    // The 7 nearest: the centre, then its six face neighbours in index order.
    std::uint32_t indices[7];
    float dist2[7];
    ASSERT_EQ(tree.nearest(center, 7, 10.0f, indices, dist2), 7u);
    const auto at = [](int x, int y, int z) { return std::uint32_t(x + 9 * (y + 9 * z)); };
    const std::uint32_t expected[7] = {at(4, 4, 4), at(4, 4, 3), at(4, 3, 4), at(3, 4, 4),
                                       at(5, 4, 4), at(4, 5, 4), at(4, 4, 5)};
    for (int i = 0; i < 7; ++i) {
        EXPECT_EQ(indices[i], expected[i]) << i;
        EXPECT_EQ(dist2[i], i == 0 ? 0.0f : 1.0f) << i;
    }
}

TEST(KdTree, TiesInDistanceGoToTheLowerIndex) {
    // 100 copies of one point and 100 of another equally far from the query.
    std::vector<Vec3> points;
    for (int i = 0; i < 200; ++i) points.push_back(i % 2 ? Vec3(1, 0, 0) : Vec3(-1, 0, 0));
    for (std::uint32_t leaf : kLeafSizes) {
        const KdTree tree(points, {.maxLeafSize = leaf});
        std::vector<std::uint32_t> indices(10);
        std::vector<float> dist2(10);
        ASSERT_EQ(tree.nearest(Vec3(0.0f), 10, 5.0f, indices, dist2), 10u);
        for (std::uint32_t i = 0; i < 10; ++i) {
            EXPECT_EQ(indices[i], i) << "leaf size " << leaf;
            EXPECT_EQ(dist2[i], 1.0f);
        }
    }
}

TEST(KdTree, EmptySetAndDegenerateArguments) {
    const KdTree empty{std::span<const Vec3>()};
    EXPECT_EQ(empty.size(), 0u);
    EXPECT_TRUE(empty.empty());
    EXPECT_EQ(empty.bytes(), 0u);
    bool visited = false;
    empty.forEachInRadius(Vec3(0.0f), 1e6f, [&](std::uint32_t, float) { visited = true; });
    EXPECT_FALSE(visited);
    std::uint32_t indices[4];
    float dist2[4];
    EXPECT_EQ(empty.nearest(Vec3(0.0f), 4, 1e6f, indices, dist2), 0u);

    const std::vector<Vec3> points = uniformPoints(50, 41);
    const KdTree tree(points, {.maxLeafSize = 4});
    EXPECT_EQ(tree.nearest(points[3], 0, 1.0f, indices, dist2), 0u);
    EXPECT_EQ(tree.nearest(points[3], 4, -1.0f, indices, dist2), 0u);
    EXPECT_EQ(tree.nearest(points[3], 4, std::nanf(""), indices, dist2), 0u);
    const Vec3 nanCenter(0.5f, std::nanf(""), 0.5f);
    EXPECT_EQ(tree.nearest(nanCenter, 4, 10.0f, indices, dist2), 0u);
    EXPECT_EQ(tree.nearest(Vec3(0.5f, 0.5f, -std::numeric_limits<float>::infinity()), 4,
                           std::numeric_limits<float>::infinity(), indices, dist2),
              0u);
    tree.forEachInRadius(nanCenter, 10.0f, [&](std::uint32_t, float) { visited = true; });
    EXPECT_FALSE(visited);
    // k is capped by the shorter output span.
    EXPECT_EQ(tree.nearest(points[3], 100, 10.0f, std::span(indices), std::span(dist2).first(2)), 2u);
    EXPECT_EQ(indices[0], 3u);
    EXPECT_EQ(dist2[0], 0.0f);
}

TEST(KdTree, KLargerThanTheSetReturnsEveryPointSorted) {
    const std::vector<Vec3> points = clusteredPoints(37, 42);
    const KdTree tree(points, {.maxLeafSize = 3});
    std::vector<std::uint32_t> indices(100);
    std::vector<float> dist2(100);
    const Vec3 center(0.4f, 0.4f, 0.4f);
    ASSERT_EQ(tree.nearest(center, 100, std::numeric_limits<float>::infinity(), indices, dist2), 37u);
    const auto expected = bruteNearest(points, center, 100, std::numeric_limits<float>::infinity());
    ASSERT_EQ(expected.size(), 37u);
    for (std::size_t i = 0; i < 37; ++i) {
        EXPECT_EQ(indices[i], expected[i].second);
        EXPECT_EQ(dist2[i], expected[i].first);
    }
}

TEST(KdTree, NonFinitePositionsAreRejectedWithTheFirstIndex) {
    std::vector<Vec3> points = uniformPoints(100000, 43);
    points[70000].y = std::numeric_limits<float>::quiet_NaN();
    points[31337].z = std::numeric_limits<float>::infinity();
    try {
        KdTree tree(points);
        FAIL() << "built over a NaN";
    } catch (const std::invalid_argument& e) {
        EXPECT_NE(std::string(e.what()).find("31337"), std::string::npos) << e.what();
    }
}

TEST(KdTree, RebuildReplacesTheTree) {
    const std::vector<Vec3> first = uniformPoints(500, 44);
    const std::vector<Vec3> second = clusteredPoints(80, 45);
    KdTree tree(first, {.maxLeafSize = 2});
    tree.build(second, {.maxLeafSize = 6});
    EXPECT_EQ(tree.size(), 80u);
    EXPECT_EQ(tree.maxLeafSize(), 6u);
    expectWellFormed(tree, second);
    EXPECT_EQ(treeRange(tree, second[5], 0.05f), bruteRange(second, second[5], 0.05f));
}

std::pair<std::vector<std::uint32_t>, std::vector<std::pair<float, std::uint32_t>>> snapshot(const KdTree& tree) {
    std::vector<std::pair<float, std::uint32_t>> splits;
    for (const KdTree::Split& s : tree.splits()) splits.emplace_back(s.value, s.axis);
    return {std::vector<std::uint32_t>(tree.permutation().begin(), tree.permutation().end()), splits};
}

TEST(KdTree, BuildDoesNotDependOnTheThreadCount) {
    // Duplicates make the tie-break on index matter; a low threshold makes
    // hundreds of parallel subtree tasks.
    std::vector<Vec3> points = clusteredPoints(150000, 51);
    const std::vector<Vec3> dups = duplicatedPoints(50000, 300, 52);
    points.insert(points.end(), dups.begin(), dups.end());
    const KdTree::BuildOptions options{.maxLeafSize = 4, .parallelThreshold = 512};
    auto buildWith = [&](int threads) {
        const jobs::ThreadLimit limit(threads);
        return snapshot(KdTree(points, options));
    };
    const auto serial = buildWith(1);
    const auto parallel = buildWith(2);
    const auto parallelAgain = buildWith(2);
    EXPECT_TRUE(serial.first == parallel.first) << "permutations differ";
    EXPECT_TRUE(serial.second == parallel.second) << "split records differ";
    EXPECT_TRUE(parallel == parallelAgain);
    // A serial build (threshold above the size) must agree as well.
    const auto unthreaded = snapshot(KdTree(points, {.maxLeafSize = 4, .parallelThreshold = points.size() + 1}));
    EXPECT_TRUE(unthreaded == serial);
}

TEST(KdTree, QueriesFromManyThreadsAgreeWithSerialOnes) {
    const std::vector<Vec3> points = clusteredPoints(20000, 61);
    const KdTree tree(points);
    const std::vector<Vec3> centers = queryCenters(points, 2000, 62);
    constexpr std::size_t k = 16;
    std::vector<std::uint32_t> parallelIdx(centers.size() * k), serialIdx(centers.size() * k);
    std::vector<float> parallelD2(centers.size() * k), serialD2(centers.size() * k);
    std::vector<std::size_t> parallelCount(centers.size()), serialCount(centers.size());
    auto query = [&](std::size_t q, std::vector<std::uint32_t>& idx, std::vector<float>& d2,
                     std::vector<std::size_t>& count) {
        count[q] =
            tree.nearest(centers[q], k, 0.05f, std::span(idx).subspan(q * k, k), std::span(d2).subspan(q * k, k));
    };
    jobs::parallelFor(centers.size(), 7, [&](std::size_t q) { query(q, parallelIdx, parallelD2, parallelCount); });
    for (std::size_t q = 0; q < centers.size(); ++q) query(q, serialIdx, serialD2, serialCount);
    EXPECT_EQ(parallelCount, serialCount);
    EXPECT_EQ(parallelIdx, serialIdx);
    EXPECT_EQ(parallelD2, serialD2);
}

TEST(KdTree, MillionPointBuildIsBalancedAndAnswersQueries) {
    const std::vector<Vec3> points = uniformPoints(1000000, 71);
    const KdTree tree(points);
    ASSERT_EQ(tree.size(), points.size());
    EXPECT_GE(tree.bytes(), points.size() * sizeof(std::uint32_t));
    // Implicit layout: the array stops at the deepest inner level.
    EXPECT_LE(tree.splits().size(), 2 * points.size() / tree.maxLeafSize() + 1);
    std::vector<std::uint32_t> sorted(tree.permutation().begin(), tree.permutation().end());
    std::sort(sorted.begin(), sorted.end());
    std::vector<std::uint32_t> identity(points.size());
    std::iota(identity.begin(), identity.end(), 0u);
    EXPECT_TRUE(sorted == identity);

    const std::vector<Vec3> centers = queryCenters(points, 12, 72);
    for (const Vec3& c : centers) {
        EXPECT_EQ(treeNearest(tree, c, 50, 0.1f), bruteNearest(points, c, 50, 0.1f));
        EXPECT_EQ(treeRange(tree, c, 0.02f), bruteRange(points, c, 0.02f));
    }
}

}  // namespace
}  // namespace fg
