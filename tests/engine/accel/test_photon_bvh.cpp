// The sphere BVH of the beam query against brute force: the same spheres for
// random segments (finite, infinite, axis-aligned), on scattered, clustered
// and degenerate sphere sets; structural invariants; identical trees for any
// thread count.
#include "engine/accel/photon_bvh.h"
#include "jobs/parallel.h"
#include "jobs/random.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cstring>
#include <vector>

namespace fg {
namespace {

struct Spheres {
    std::vector<Vec3> centers;
    std::vector<float> radii;
};

Spheres randomSpheres(std::size_t n, std::uint64_t seed, bool clustered) {
    Spheres s;
    for (std::size_t i = 0; i < n; ++i) {
        jobs::Rng rng(seed, jobs::streamKey("bvh-spheres"), i);
        Vec3 c(rng.uniform(), rng.uniform(), rng.uniform());
        if (clustered) {
            // Most spheres on a plane (photons on a floor), a dense blob, a sparse rest.
            const float which = rng.uniform();
            if (which < 0.5f) c.y = 0.0f;
            else if (which < 0.8f) c = Vec3(0.3f) + 0.02f * c;
        }
        s.centers.push_back(4.0f * c - Vec3(2.0f));
        // Radii over two orders of magnitude, a few of them zero.
        const float u = rng.uniform();
        s.radii.push_back(u < 0.02f ? 0.0f : 0.01f * std::pow(100.0f, rng.uniform()));
    }
    return s;
}

struct Segment {
    Vec3 origin, direction;
    float tNear, tFar;
};

Segment randomSegment(std::uint64_t i) {
    jobs::Rng rng(7, jobs::streamKey("bvh-segments"), i);
    Segment seg;
    seg.origin = 6.0f * Vec3(rng.uniform(), rng.uniform(), rng.uniform()) - Vec3(3.0f);
    const Vec2 u = rng.uniform2();
    const float z = 1.0f - 2.0f * u.x, r = std::sqrt(std::max(0.0f, 1.0f - z * z)), phi = 2.0f * kPi * u.y;
    seg.direction = Vec3(r * std::cos(phi), r * std::sin(phi), z);
    switch (i % 4) {
    case 0:  // axis-aligned: zero direction components
        seg.direction = Vec3(0.0f);
        seg.direction[static_cast<int>(i / 4 % 3)] = (i / 12) % 2 ? 1.0f : -1.0f;
        seg.tNear = 0.0f;
        seg.tFar = 6.0f;
        break;
    case 1:  // escaping
        seg.tNear = 0.0f;
        seg.tFar = kInfinity;
        break;
    default:  // a stretch of the line
        seg.tNear = 4.0f * rng.uniform() - 1.0f;
        seg.tFar = seg.tNear + 3.0f * rng.uniform();
    }
    return seg;
}

// Compares the query with brute force; spheres the segment only grazes (within
// rounding of the tangent) may go either way and are counted.
void expectSameSpheres(const Spheres& s, const PhotonBvh& bvh, int segments, std::size_t* hitsOut = nullptr) {
    std::size_t hits = 0, grazing = 0;
    for (int q = 0; q < segments; ++q) {
        const Segment seg = randomSegment(static_cast<std::uint64_t>(q));
        std::vector<std::uint32_t> found;
        std::vector<float> foundT;
        bvh.forEachSphereOnSegment(seg.origin, seg.direction, seg.tNear, seg.tFar,
                                   [&](std::uint32_t slot, float t, float d2) {
                                       found.push_back(bvh.sphereIds()[slot]);
                                       foundT.push_back(t);
                                       (void)d2;
                                   });
        std::vector<std::uint32_t> expected;
        for (std::size_t i = 0; i < s.centers.size(); ++i) {
            float t;
            const float d2 = PhotonBvh::segmentDistance2(s.centers[i], seg.origin, seg.direction, seg.tNear,
                                                         seg.tFar, &t);
            const float r2 = s.radii[i] * s.radii[i];
            if (std::abs(d2 - r2) <= 1e-5f * r2 + 1e-12f) {
                ++grazing;
                continue;
            }
            if (d2 <= r2) expected.push_back(static_cast<std::uint32_t>(i));
        }
        std::vector<std::uint32_t> sorted = found;
        std::sort(sorted.begin(), sorted.end());
        ASSERT_TRUE(std::adjacent_find(sorted.begin(), sorted.end()) == sorted.end()) << "a sphere reported twice";
        // Drop grazing spheres from the query's answer too.
        std::vector<std::uint32_t> clear;
        for (std::uint32_t id : sorted) {
            float t;
            const float d2 =
                PhotonBvh::segmentDistance2(s.centers[id], seg.origin, seg.direction, seg.tNear, seg.tFar, &t);
            const float r2 = s.radii[id] * s.radii[id];
            if (!(std::abs(d2 - r2) <= 1e-5f * r2 + 1e-12f)) clear.push_back(id);
        }
        ASSERT_EQ(clear, expected) << "segment " << q;
        hits += expected.size();
    }
    EXPECT_LE(grazing, 2u);
    if (hitsOut) *hitsOut = hits;
}

TEST(PhotonBvh, FindsTheSameSpheresAsBruteForce) {
    for (const bool clustered : {false, true}) {
        const Spheres s = randomSpheres(20000, clustered ? 2 : 1, clustered);
        PhotonBvh bvh;
        PhotonBvh::BuildOptions options;
        options.parallelThreshold = 512;  // exercise the parallel top of the tree
        bvh.build(s.centers, s.radii, options);
        ASSERT_EQ(bvh.size(), s.centers.size());
        std::size_t hits = 0;
        expectSameSpheres(s, bvh, 400, &hits);
        EXPECT_GT(hits, 2000u) << "the segments must actually meet spheres";
    }
}

TEST(PhotonBvh, LeavesPartitionTheSpheresAndBoxesNest) {
    const Spheres s = randomSpheres(5000, 3, true);
    PhotonBvh bvh;
    PhotonBvh::BuildOptions options;
    options.maxLeafSize = 3;
    options.parallelThreshold = 256;
    bvh.build(s.centers, s.radii, options);
    const auto lo = bvh.nodes().column<BvhNodeLo>();
    const auto hi = bvh.nodes().column<BvhNodeHi>();
    const auto link = bvh.nodes().column<BvhNodeLink>();
    const auto count = bvh.nodes().column<BvhNodeCount>();
    const auto radius = bvh.spheres().column<BvhSphereRadius>();
    std::vector<int> seen(s.centers.size(), 0);
    std::vector<std::uint32_t> ids(bvh.sphereIds().begin(), bvh.sphereIds().end());
    std::sort(ids.begin(), ids.end());
    for (std::size_t i = 0; i < ids.size(); ++i) ASSERT_EQ(ids[i], i) << "ids are a permutation";
    // Walk the tree: children inside parents, spheres inside leaves, every slot in one leaf.
    std::vector<std::uint32_t> stack{0};
    std::size_t visited = 0;
    while (!stack.empty()) {
        const std::uint32_t node = stack.back();
        stack.pop_back();
        ++visited;
        if (count[node] == 0) {
            for (const std::uint32_t child : {node + 1, link[node]}) {
                ASSERT_LT(child, bvh.nodeCount());
                EXPECT_TRUE(glm::all(glm::lessThanEqual(lo[node], lo[child])));
                EXPECT_TRUE(glm::all(glm::greaterThanEqual(hi[node], hi[child])));
                stack.push_back(child);
            }
        } else {
            EXPECT_LE(count[node], 3u);
            for (std::uint32_t k = link[node]; k < link[node] + count[node]; ++k) {
                ++seen[k];
                EXPECT_TRUE(glm::all(glm::lessThanEqual(lo[node], bvh.center(k) - Vec3(radius[k]))));
                EXPECT_TRUE(glm::all(glm::greaterThanEqual(hi[node], bvh.center(k) + Vec3(radius[k]))));
                EXPECT_EQ(bvh.center(k), s.centers[bvh.sphereIds()[k]]);
            }
        }
    }
    EXPECT_EQ(visited, bvh.nodeCount()) << "every node reachable once";
    for (int c : seen) ASSERT_EQ(c, 1);
    EXPECT_GT(bvh.depth(), 5u);
}

template <class Buffer>
bool sameBytes(const Buffer& a, const Buffer& b) {
    return a.size() == b.size() && std::memcmp(a.data(), b.data(), a.size_bytes()) == 0;
}

TEST(PhotonBvh, IdenticalForAnyThreadCount) {
    const Spheres s = randomSpheres(60000, 4, true);
    PhotonBvh::BuildOptions options;
    options.parallelThreshold = 1024;
    PhotonBvh one, two;
    {
        const jobs::ThreadLimit limit(1);
        one.build(s.centers, s.radii, options);
    }
    {
        const jobs::ThreadLimit limit(2);
        two.build(s.centers, s.radii, options);
    }
    EXPECT_TRUE(sameBytes(one.nodes().column<BvhNodeLo>(), two.nodes().column<BvhNodeLo>()));
    EXPECT_TRUE(sameBytes(one.nodes().column<BvhNodeHi>(), two.nodes().column<BvhNodeHi>()));
    EXPECT_TRUE(sameBytes(one.nodes().column<BvhNodeLink>(), two.nodes().column<BvhNodeLink>()));
    EXPECT_TRUE(sameBytes(one.nodes().column<BvhNodeCount>(), two.nodes().column<BvhNodeCount>()));
    EXPECT_TRUE(sameBytes(one.sphereIds(), two.sphereIds()));
    // A serial build (no parallel top) finds the same spheres, in its own order.
    options.parallelThreshold = std::size_t(1) << 30;
    PhotonBvh serial;
    serial.build(s.centers, s.radii, options);
    expectSameSpheres(s, serial, 50);
}

TEST(PhotonBvh, DegenerateAndInvalidInput) {
    PhotonBvh bvh;
    bvh.build({}, {});
    int visits = 0;
    bvh.forEachSphereOnSegment(Vec3(0.0f), Vec3(1, 0, 0), 0.0f, kInfinity, [&](auto...) { ++visits; });
    EXPECT_EQ(visits, 0);

    // All spheres at one point: object-median splits; a segment through it finds all.
    Spheres same;
    same.centers.assign(1000, Vec3(0.5f, -0.25f, 1.0f));
    same.radii.assign(1000, 0.1f);
    bvh.build(same.centers, same.radii);
    EXPECT_LE(bvh.depth(), 20u);
    std::vector<int> found(1000, 0);
    BvhQueryStats stats;
    bvh.forEachSphereOnSegment(Vec3(0.5f, -0.25f, -1.0f), Vec3(0, 0, 1), 0.0f, 5.0f,
                               [&](std::uint32_t slot, float t, float d2) {
                                   ++found[bvh.sphereIds()[slot]];
                                   EXPECT_FLOAT_EQ(t, 2.0f);
                                   EXPECT_EQ(d2, 0.0f);
                               },
                               &stats);
    for (int f : found) ASSERT_EQ(f, 1);
    EXPECT_EQ(stats.spheres, 1000);
    EXPECT_GE(stats.nodes, static_cast<std::int64_t>(bvh.nodeCount()));
    // A segment that stops short, or an empty one, finds nothing.
    visits = 0;
    bvh.forEachSphereOnSegment(Vec3(0.5f, -0.25f, -1.0f), Vec3(0, 0, 1), 0.0f, 1.8f, [&](auto...) { ++visits; });
    bvh.forEachSphereOnSegment(Vec3(0.5f, -0.25f, -1.0f), Vec3(0, 0, 1), 3.0f, 2.5f, [&](auto...) { ++visits; });
    EXPECT_EQ(visits, 0);

    const std::vector<Vec3> centers{Vec3(0.0f), Vec3(1.0f)};
    EXPECT_THROW(bvh.build(centers, std::vector<float>{1.0f}), std::invalid_argument);
    EXPECT_THROW(bvh.build(centers, std::vector<float>{1.0f, -1.0f}), std::invalid_argument);
    EXPECT_THROW(bvh.build(std::vector<Vec3>{Vec3(0.0f), Vec3(NAN)}, std::vector<float>{1.0f, 1.0f}),
                 std::invalid_argument);
}

}  // namespace
}  // namespace fg
