// The splat kd-tree (Herzog et al. 2007, §7): structural invariants, and the
// frustum traversal against brute force: for 10^4 random cones (axis-parallel,
// grazing, dh = 0 and degenerate among them) the tree must report every
// feasible eye vertex, with and without backface-culling nodes, by
// Algorithm 1's cells and by the tight-box cone search.
#include "engine/accel/splat_kdtree.h"
#include "passes/prs/ray_splat.h"
#include "jobs/random.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cstring>
#include <set>
#include <vector>

namespace fg {
namespace {

// Vertices on three faces of a box (coherent normals, as eye vertices on walls)
// and a cloud with random normals.
void makeVertices(std::vector<Vec3>& p, std::vector<Vec3>& n, std::size_t count) {
    for (std::size_t i = 0; i < count; ++i) {
        jobs::Rng rng(5, 1, i);
        const Vec2 u = rng.uniform2();
        const float kind = rng.uniform();
        if (kind < 0.25f) {
            p.emplace_back(u.x, u.y, 0.0f);
            n.emplace_back(0, 0, 1);
        } else if (kind < 0.5f) {
            p.emplace_back(0.0f, u.x, u.y);
            n.emplace_back(1, 0, 0);
        } else if (kind < 0.75f) {
            p.emplace_back(u.x, 1.0f, u.y);
            n.emplace_back(0, -1, 0);
        } else {
            p.emplace_back(u.x, u.y, rng.uniform());
            const Vec2 w = rng.uniform2();
            const float z = 1.0f - 2.0f * w.x, r = std::sqrt(std::max(0.0f, 1.0f - z * z));
            n.emplace_back(r * std::cos(2.0f * kPi * w.y), r * std::sin(2.0f * kPi * w.y), z);
        }
    }
}

SplatRay randomRay(std::uint64_t i) {
    jobs::Rng rng(9, 2, i);
    SplatRay ray;
    ray.origin = Vec3(-0.3f) + 1.6f * Vec3(rng.uniform(), rng.uniform(), rng.uniform());
    const Vec2 w = rng.uniform2();
    const float z = 1.0f - 2.0f * w.x, r = std::sqrt(std::max(0.0f, 1.0f - z * z));
    ray.direction = Vec3(r * std::cos(2.0f * kPi * w.y), r * std::sin(2.0f * kPi * w.y), z);
    const int kind = static_cast<int>(i % 5);
    if (kind == 1) {  // axis-parallel
        ray.direction = Vec3(0.0f);
        ray.direction[static_cast<int>(i / 5 % 3)] = (i / 15) % 2 ? 1.0f : -1.0f;
    } else if (kind == 2) {  // grazing the z = 0 face
        ray.direction = glm::normalize(Vec3(ray.direction.x, ray.direction.y, 0.01f * ray.direction.z));
        ray.origin.z = 0.02f * rng.uniform();
    }
    ray.length = 1.5f * rng.uniform();
    ray.h0 = 0.1f * rng.uniform();
    ray.dh = kind == 3 ? 0.0f : 0.1f * rng.uniform();  // dh = 0: a cylinder
    if (kind == 4 && i % 2) ray.length = 0.0f, ray.h0 = 0.0f;  // degenerate: no footprint
    if (rng.uniform() < 0.5f) ray.originNormal = glm::normalize(ray.direction + Vec3(0.1f, 0.0f, 0.0f));
    if (rng.uniform() < 0.8f) {
        const Vec3 tilt(rng.uniform() - 0.5f, rng.uniform() - 0.5f, rng.uniform() - 0.5f);
        ray.endNormal = glm::normalize(-ray.direction + tilt);
    }
    return ray;
}

TEST(SplatKdTree, Invariants) {
    std::vector<Vec3> p, n;
    makeVertices(p, n, 20000);
    const SplatKdTree tree(p, n, {16, 0.0f, 45.0f});
    ASSERT_EQ(tree.size(), p.size());
    std::vector<int> seen(p.size(), 0);
    for (std::uint32_t s = 0; s < tree.size(); ++s) {
        ++seen[tree.vertexOf(s)];
        EXPECT_EQ(tree.slotPosition(s), p[tree.vertexOf(s)]);
    }
    for (int count : seen) ASSERT_EQ(count, 1);
    // Walk the tree: leaves partition the slots, vertices lie in their cells,
    // leaves hold fewer than 16, cull nodes bound their subtree's normals.
    struct Item {
        std::uint32_t node;
        Vec3 lo, hi;
        Vec3 cullNormal;
        float cullSin;
    };
    std::vector<Item> stack{{0, tree.boundsMin(), tree.boundsMax(), Vec3(0.0f), 2.0f}};
    std::size_t covered = 0;
    int cullNodes = 0, sinesAboveCullSin = 0;
    while (!stack.empty()) {
        const Item item = stack.back();
        stack.pop_back();
        const SplatKdNode node = tree.nodes()[item.node];
        if (node.kind() == SplatKdNode::Leaf) {
            const std::uint32_t count = node.b >> 2;
            EXPECT_LT(count, 16u);
            for (std::uint32_t s = node.a; s < node.a + count; ++s) {
                const Vec3 x = tree.slotPosition(s);
                for (int a = 0; a < 3; ++a) {
                    EXPECT_GE(x[a], item.lo[a]);
                    EXPECT_LE(x[a], item.hi[a]);
                }
                if (item.cullSin <= 1.0f) {
                    const float c = glm::dot(tree.slotNormal(s), item.cullNormal);
                    EXPECT_GE(std::sqrt(std::max(0.0f, 1.0f - item.cullSin * item.cullSin)), 0.0f);
                    EXPECT_GE(c, std::sqrt(std::max(0.0f, 1.0f - item.cullSin * item.cullSin)) - 1e-4f);
                    // sin of the angle itself, which a cosine near 1 cannot resolve.
                    if (glm::length(glm::cross(item.cullNormal, glm::normalize(tree.slotNormal(s)))) > item.cullSin)
                        ++sinesAboveCullSin;
                }
            }
            covered += count;
        } else if (node.kind() == SplatKdNode::Cull) {
            ++cullNodes;
            stack.push_back({item.node + 1, item.lo, item.hi, SplatKdTree::decodeNormal(node.a),
                             SplatKdTree::decodeFloat(node.b & ~3u)});
        } else if (node.kind() == SplatKdNode::Interior) {
            const int axis = static_cast<int>((node.b >> 2) & 3u);
            const float plane = SplatKdTree::decodeFloat(node.a);
            Item left = item, right = item;
            left.node = item.node + 1;
            right.node = item.node + (node.b >> 4);
            left.hi[axis] = plane;
            right.lo[axis] = plane;
            stack.push_back(left);
            stack.push_back(right);
        }
    }
    EXPECT_EQ(covered, p.size());
    EXPECT_GT(cullNodes, 2);  // the three walls at least
    EXPECT_EQ(sinesAboveCullSin, 0);
}

class SplatKdTreeTraversal : public ::testing::TestWithParam<float> {};

TEST_P(SplatKdTreeTraversal, FindsEveryFeasibleVertex) {
    std::vector<Vec3> p, n;
    makeVertices(p, n, 6000);
    const SplatKdTree tree(p, n, {16, 0.0f, GetParam()});
    std::int64_t feasibleTotal = 0, visitedTotal = 0;
    for (const SplatEndCap cap : {SplatEndCap::Hemisphere, SplatEndCap::TangentPlane}) {
        for (std::uint64_t i = 0; i < 5000; ++i) {
            const SplatRay ray = randomRay(i);
            std::set<std::uint32_t> expected, found;
            for (std::uint32_t v = 0; v < p.size(); ++v)
                if (splatWeight(ray, cap, p[v], n[v]) > 0.0f) expected.insert(v);
            tree.forEachCandidate(splatCone(ray, cap), [&](std::uint32_t slot) {
                ++visitedTotal;
                const std::uint32_t v = tree.vertexOf(slot);
                if (splatWeight(ray, cap, p[v], n[v]) > 0.0f) found.insert(v);
            });
            ASSERT_EQ(found, expected) << "ray " << i;
            feasibleTotal += static_cast<std::int64_t>(expected.size());
        }
    }
    EXPECT_GT(feasibleTotal, 10000);
    // The traversal prunes: far fewer candidates than a scan of all vertices.
    EXPECT_LT(visitedTotal, 10000 * static_cast<std::int64_t>(p.size()) / 10);
}

// Slices "hit_plane" read the radius at t*, which may lie up to R(t_hit)
// tan theta beyond a vertex's foot t_p: the cone splatCone gives them must
// still hold every vertex the frustum weighs, by cells and by tight boxes.
TEST_P(SplatKdTreeTraversal, HitPlaneSlicesConeHoldsEveryFeasibleVertex) {
    std::vector<Vec3> p, n;
    makeVertices(p, n, 6000);
    const SplatKdTree tree(p, n, {16, 0.0f, GetParam()});
    const SplatEndCap cap = SplatEndCap::TangentPlane;
    const SplatSlices slices = SplatSlices::HitPlane;
    std::int64_t feasibleTotal = 0, widened = 0;
    for (std::uint64_t i = 0; i < 5000; ++i) {
        const SplatRay ray = randomRay(i);
        std::set<std::uint32_t> expected, byCells, byBoxes;
        for (std::uint32_t v = 0; v < p.size(); ++v) {
            if (splatWeight(ray, cap, p[v], n[v], slices) > 0.0f) expected.insert(v);
            if (splatWeight(ray, cap, p[v], n[v], slices) > 0.0f && !(splatWeight(ray, cap, p[v], n[v]) > 0.0f))
                ++widened;
        }
        const SplatCone cone = splatCone(ray, cap, slices);
        tree.forEachCandidate(cone, [&](std::uint32_t slot) {
            const std::uint32_t v = tree.vertexOf(slot);
            if (splatWeight(ray, cap, p[v], n[v], slices) > 0.0f) byCells.insert(v);
        });
        tree.forEachLeafNearCone(cone, [&](std::uint32_t first, std::uint32_t count) {
            for (std::uint32_t slot = first; slot < first + count; ++slot) {
                const std::uint32_t v = tree.vertexOf(slot);
                if (splatWeight(ray, cap, p[v], n[v], slices) > 0.0f) byBoxes.insert(v);
            }
        });
        ASSERT_EQ(byCells, expected) << "ray " << i;
        ASSERT_EQ(byBoxes, expected) << "ray " << i;
        feasibleTotal += static_cast<std::int64_t>(expected.size());
    }
    EXPECT_GT(feasibleTotal, 5000);
    EXPECT_GT(widened, 100);  // vertices outside the paper's frustum that the sliced one weighs
}

// forEachVertexInCone searches by tight boxes and tests the leaves' vertices
// against the cone; ray_splat's image stays the same bit for bit only if
// every feasible vertex is still visited, in Algorithm 1's order.
TEST_P(SplatKdTreeTraversal, ConeSearchVisitsTheFeasibleVerticesInAlgorithmOnesOrder) {
    std::vector<Vec3> p, n;
    makeVertices(p, n, 6000);
    const SplatKdTree tree(p, n, {16, 0.0f, GetParam()});
    std::int64_t feasibleTotal = 0, cellCandidates = 0, coneCandidates = 0;
    std::uint64_t tested = 0;
    for (const SplatEndCap cap : {SplatEndCap::Hemisphere, SplatEndCap::TangentPlane}) {
        for (std::uint64_t i = 0; i < 5000; ++i) {
            const SplatRay ray = randomRay(i);
            std::vector<std::uint32_t> expected, found;
            std::vector<int> seen(p.size(), 0);
            tree.forEachCandidate(splatCone(ray, cap), [&](std::uint32_t slot) {
                ++cellCandidates;
                const std::uint32_t v = tree.vertexOf(slot);
                if (splatWeight(ray, cap, p[v], n[v]) > 0.0f) expected.push_back(v);
            });
            tested += tree.forEachVertexInCone(splatCone(ray, cap), [&](std::uint32_t slot) {
                ++coneCandidates;
                const std::uint32_t v = tree.vertexOf(slot);
                ++seen[v];
                if (splatWeight(ray, cap, p[v], n[v]) > 0.0f) found.push_back(v);
            });
            ASSERT_EQ(found, expected) << "ray " << i;
            ASSERT_LE(*std::max_element(seen.begin(), seen.end()), 1) << "ray " << i << ": a vertex twice";
            std::size_t bruteForce = 0;
            for (std::uint32_t v = 0; v < p.size(); ++v)
                if (splatWeight(ray, cap, p[v], n[v]) > 0.0f) ++bruteForce;
            ASSERT_EQ(found.size(), bruteForce) << "ray " << i;
            feasibleTotal += static_cast<std::int64_t>(found.size());
        }
    }
    EXPECT_GT(feasibleTotal, 10000);
    // Fewer leaf vertices than Algorithm 1 hands out, and of those only the
    // ones in the cone (plus rounding slack) reach the caller.
    EXPECT_LT(tested, static_cast<std::uint64_t>(cellCandidates));
    EXPECT_LT(coneCandidates, 2 * feasibleTotal);
}

INSTANTIATE_TEST_SUITE_P(CullNodes, SplatKdTreeTraversal, ::testing::Values(0.0f, 45.0f, 89.0f));

// A flat wall's culling node: its 16-bit octahedral reference normal is off
// the wall's normal by about 2e-5 rad, so C_max must be at least that. A ray
// descending onto the wall at a few 1e-6 rad still reaches its vertices
// (dir·n_x < 0) while dir·n_ref > 0; a C_max taken from √(1 − cos²δ) in
// float (cos δ rounds to 1) culled it. On the Cornell box at 128², 2 spp,
// such rays were the deposits the 16-vertex tree lost.
TEST(SplatKdTree, GrazingRaysAreNotCulledOffFlatWalls) {
    int cases = 0;
    for (const Vec3 wall : {Vec3(0, 0, 1), Vec3(0, -1, 0), glm::normalize(Vec3(0.3f, 0.2f, 0.93f))}) {
        const Vec3 t1 = glm::normalize(std::abs(wall.x) < 0.9f ? glm::cross(wall, Vec3(1, 0, 0)) : glm::cross(wall, Vec3(0, 1, 0)));
        const Vec3 t2 = glm::cross(wall, t1);
        std::vector<Vec3> p, n;
        for (std::uint64_t i = 0; i < 3000; ++i) {
            jobs::Rng rng(7, 3, i);
            const Vec2 u = rng.uniform2() - Vec2(0.5f);
            p.push_back(u.x * t1 + u.y * t2);
            n.push_back(wall);
        }
        const SplatKdTree tree(p, n, {16, 0.0f, 45.0f});
        ASSERT_EQ(tree.nodes()[0].kind(), SplatKdNode::Cull);
        const Vec3 reference = SplatKdTree::decodeNormal(tree.nodes()[0].a);
        // The reference's tilt off the wall, in double: in float the
        // cancellation leaves g off the wall's plane by more than the tilt.
        const glm::dvec3 w = glm::normalize(glm::dvec3(wall)), along = glm::dvec3(reference) - glm::dot(glm::dvec3(reference), w) * w;
        const double tilt = glm::length(along);
        ASSERT_GT(tilt, 5e-6) << "the quantised reference must differ from the wall's normal for this test";
        const glm::dvec3 g = along / tilt, side = glm::cross(w, g);
        for (const double slope : {0.125, 0.25, 0.5})
            for (const double yaw : {-0.3, 0.0, 0.3}) {
                const glm::dvec3 heading = std::cos(yaw) * g + std::sin(yaw) * side;
                SplatRay ray;
                ray.direction = Vec3(glm::normalize(heading - slope * tilt * w));
                ray.origin = Vec3(-0.7 * heading + 0.002 * w);
                ray.length = 1.4f;
                ray.h0 = 0.05f;
                ray.dh = 0.0f;
                ASSERT_LT(glm::dot(ray.direction, wall), 0.0f);
                ASSERT_GT(glm::dot(ray.direction, reference), 1e-6f);  // the old C_max would cull it
                std::set<std::uint32_t> expected, found;
                for (std::uint32_t v = 0; v < p.size(); ++v)
                    if (splatWeight(ray, SplatEndCap::TangentPlane, p[v], n[v]) > 0.0f) expected.insert(v);
                tree.forEachCandidate(splatCone(ray, SplatEndCap::TangentPlane), [&](std::uint32_t slot) {
                    const std::uint32_t v = tree.vertexOf(slot);
                    if (splatWeight(ray, SplatEndCap::TangentPlane, p[v], n[v]) > 0.0f) found.insert(v);
                });
                EXPECT_GT(expected.size(), 50u);
                EXPECT_EQ(found, expected) << "wall " << wall.x << "," << wall.y << "," << wall.z << " slope " << slope
                                           << " yaw " << yaw;
                std::set<std::uint32_t> inCone;
                tree.forEachVertexInCone(splatCone(ray, SplatEndCap::TangentPlane), [&](std::uint32_t slot) {
                    const std::uint32_t v = tree.vertexOf(slot);
                    if (splatWeight(ray, SplatEndCap::TangentPlane, p[v], n[v]) > 0.0f) inCone.insert(v);
                });
                EXPECT_EQ(inCone, expected) << "cone search, wall " << wall.x << "," << wall.y << "," << wall.z
                                            << " slope " << slope << " yaw " << yaw;
                ++cases;
            }
    }
    EXPECT_EQ(cases, 27);
}

// The cone search runs on four-wide nodes collapsed from the binary tree; its
// leaves must come in Algorithm 1's order whatever the shape: leaves of one
// vertex (deep trees, many interior nodes collapsed) to leaves of up to 96
// (shallow ones, wide nodes with unexpanded leaf slots).
TEST(SplatKdTree, ConeSearchKeepsAlgorithmOnesOrderForAnyLeafSize) {
    std::vector<Vec3> p, n;
    makeVertices(p, n, 4000);
    for (const std::uint32_t leafSize : {2u, 5u, 96u}) {
        const SplatKdTree tree(p, n, {leafSize, 0.0f, 45.0f});
        std::int64_t feasibleTotal = 0;
        for (std::uint64_t i = 0; i < 2000; ++i) {
            const SplatRay ray = randomRay(i);
            const SplatEndCap cap = i % 2 ? SplatEndCap::Hemisphere : SplatEndCap::TangentPlane;
            std::vector<std::uint32_t> expected, found;
            tree.forEachCandidate(splatCone(ray, cap), [&](std::uint32_t slot) {
                const std::uint32_t v = tree.vertexOf(slot);
                if (splatWeight(ray, cap, p[v], n[v]) > 0.0f) expected.push_back(v);
            });
            std::vector<int> seen(tree.size(), 0);
            tree.forEachLeafNearCone(splatCone(ray, cap), [&](std::uint32_t first, std::uint32_t count) {
                for (std::uint32_t slot = first; slot < first + count; ++slot) {
                    ++seen[slot];
                    const std::uint32_t v = tree.vertexOf(slot);
                    if (splatWeight(ray, cap, p[v], n[v]) > 0.0f) found.push_back(v);
                }
            });
            ASSERT_EQ(found, expected) << "leaf size " << leafSize << ", ray " << i;
            ASSERT_LE(*std::max_element(seen.begin(), seen.end()), 1) << "leaf size " << leafSize << ", ray " << i;
            feasibleTotal += static_cast<std::int64_t>(found.size());
        }
        EXPECT_GT(feasibleTotal, 2000) << "leaf size " << leafSize;
    }
}

// A saved tree may hold a culling node right under another (the builder
// places none so, restore() accepts it): the cone search must honour both.
// Vertices on z = 0 facing +z; rays running up through them reach none.
// Whichever of the two nodes culls rays with dir . (0, 0, 1) > 0.5 (the other
// never culls: C_max 1.5), no leaf may be visited.
TEST(SplatKdTree, ConeSearchHonoursNestedCullingNodes) {
    std::vector<Vec3> p, n;
    for (std::uint64_t i = 0; i < 500; ++i) {
        jobs::Rng rng(3, 4, i);
        const Vec2 u = rng.uniform2();
        p.emplace_back(u.x, u.y, 0.0f);
        n.emplace_back(0.0f, 0.0f, 1.0f);
    }
    const SplatKdTree plain(p, n, {16, 0.0f, 0.0f});
    ASSERT_EQ(plain.nodes()[0].kind(), SplatKdNode::Interior);
    const auto cullNode = [](std::uint32_t packedNormal, float cMax) {
        std::uint32_t bits;
        std::memcpy(&bits, &cMax, sizeof bits);
        return SplatKdNode{packedNormal, (bits & ~3u) | SplatKdNode::Cull};
    };
    const std::uint32_t up = 32768u | (32768u << 16), down = 65535u | (65535u << 16);
    ASSERT_GT(SplatKdTree::decodeNormal(up).z, 0.9999f);
    ASSERT_LT(SplatKdTree::decodeNormal(down).z, -0.9999f);
    SplatRay ray;
    ray.origin = Vec3(0.5f, 0.5f, -0.5f);
    ray.direction = glm::normalize(Vec3(0.1f, 0.05f, 1.0f));
    ray.h0 = 0.2f;
    ray.length = 1.0f;
    const SplatCone cone = splatCone(ray, SplatEndCap::TangentPlane);
    for (const bool innerCulls : {false, true}) {
        std::vector<SplatKdNode> nodes{innerCulls ? cullNode(down, 1.5f) : cullNode(up, 0.5f),
                                       innerCulls ? cullNode(up, 0.5f) : cullNode(down, 1.5f)};
        nodes.insert(nodes.end(), plain.nodes().begin(), plain.nodes().end());
        const SplatKdTree tree = SplatKdTree::restore(
            plain.options(), plain.boundsMin(), plain.boundsMax(), nodes,
            std::vector<std::uint32_t>(plain.ids().begin(), plain.ids().end()),
            std::vector<Vec3>(plain.slotPositions().begin(), plain.slotPositions().end()),
            std::vector<Vec3>(plain.slotNormals().begin(), plain.slotNormals().end()));
        int leaves = 0, leavesUnculled = 0;
        tree.forEachLeafNearCone(cone, [&](std::uint32_t, std::uint32_t) { ++leaves; });
        tree.forEachLeafNearCone(cone, [&](std::uint32_t, std::uint32_t) { ++leavesUnculled; }, false);
        EXPECT_EQ(leaves, 0) << (innerCulls ? "inner" : "outer") << " node culls";
        EXPECT_GT(leavesUnculled, 3) << (innerCulls ? "inner" : "outer") << " node culls";
    }
}

}  // namespace
}  // namespace fg
