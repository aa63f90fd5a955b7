// A bounding-volume hierarchy over spheres (photon positions with their kernel
// radii), answering "which spheres does this line segment touch" — the query
// of the beam radiance estimate (Jarosz, Zwicker & Jensen 2008), which sums
// every photon whose kernel sphere a camera ray passes through.
//
//   PhotonBvh bvh;
//   bvh.build(positions, radii);
//   bvh.forEachSphereOnSegment(origin, direction, tNear, tFar,
//       [&](std::uint32_t slot, float tClosest, float dist2) { ... bvh.sphereIds()[slot] ... });
//
// Layout (structure of arrays). Nodes are stored depth first: an inner node's
// first child follows it directly, its second child is at `link`; a leaf has
// `count` > 0 spheres starting at sphere slot `link`. The node columns are
// `lo`, `hi` (box corners), `link` and `count`. The spheres are copied into
// BVH order (columns `x`, `y`, `z`, `radius`, `id` = the caller's index), so
// a leaf reads contiguous runs of memory and is tested with vector code.
// (Interleaving the four node columns into one 32-byte record made queries
// only about 5% faster.)
//
// Traversal: depth first, first child first; both children's boxes are
// tested (slab test) when their parent is reached, so a missed child is
// neither pushed nor fetched again.
//
// The built hierarchy is a function of the input alone, never of the thread
// count. Queries are const and may run concurrently.
#pragma once

#include "engine/core/math.h"
#include "engine/core/pass.h"
#include "engine/core/soa.h"

#include <cstddef>
#include <cstdint>
#include <span>

namespace fg {

struct PhotonBvhBuildOptions {
    // Ranges of at most this many spheres become leaves (at most 64). Leaves
    // are tested branch-free, so larger ones than usual pay: beam queries on
    // 1M volume photons (volumetric-caustic, 128 x 128, 4 spp) took 1.76 s of
    // CPU at 4, 1.33 at 8, 1.26 at 16, 1.18 at 24 and 1.14 at 32, and the
    // build 0.59, 0.47, 0.42, 0.41 and 0.39 s (tools/bre_report.py
    // --leaf-sweep). 24 and 32 are within the noise of each other: 32 was
    // 3-4 % faster in three sweeps, 3 % slower in a fourth.
    std::uint32_t maxLeafSize = 32;
    // Bins per axis of the binned SAH split search (Wald 2007).
    std::uint32_t bins = 16;
    // Ranges with at least this many spheres are binned in parallel blocks and
    // build their two children as parallel tasks; smaller ones are built
    // serially by one task.
    std::size_t parallelThreshold = std::size_t(1) << 14;
};

FG_SOA_COLUMN(BvhNodeLo, Vec3, "lo");
FG_SOA_COLUMN(BvhNodeHi, Vec3, "hi");
FG_SOA_COLUMN(BvhNodeLink, std::uint32_t, "link");    // inner: second child; leaf: first sphere slot
FG_SOA_COLUMN(BvhNodeCount, std::uint32_t, "count");  // leaf: number of spheres (> 0); inner: 0
using BvhNodeBuffer = SoaBuffer<BvhNodeLo, BvhNodeHi, BvhNodeLink, BvhNodeCount>;

FG_SOA_COLUMN(BvhSphereX, float, "x");  // centre coordinates, one column each so that a leaf's
FG_SOA_COLUMN(BvhSphereY, float, "y");  // spheres are tested with vector instructions
FG_SOA_COLUMN(BvhSphereZ, float, "z");
FG_SOA_COLUMN(BvhSphereRadius, float, "radius");
FG_SOA_COLUMN(BvhSphereId, std::uint32_t, "id");  // index of the sphere in the build input
using BvhSphereBuffer = SoaBuffer<BvhSphereX, BvhSphereY, BvhSphereZ, BvhSphereRadius, BvhSphereId>;

// Work done by one query, for the per-pixel cost image.
struct BvhQueryStats {
    std::int64_t nodes = 0;    // node boxes tested
    std::int64_t spheres = 0;  // spheres tested in the leaves reached
};

class PhotonBvh {
public:
    using BuildOptions = PhotonBvhBuildOptions;

    PhotonBvh() = default;

    // Rebuilds over the spheres (centers[i], radii[i]); at most 2^31 - 1 of
    // them. Throws std::invalid_argument if the spans differ in size, or a
    // center or radius is not finite or a radius is negative.
    void build(std::span<const Vec3> centers, std::span<const float> radii, const BuildOptions& options = {});

    std::size_t size() const { return spheres_.size(); }
    bool empty() const { return spheres_.empty(); }
    std::size_t nodeCount() const { return nodes_.size(); }
    std::uint32_t depth() const { return depth_; }
    std::size_t bytes() const { return nodes_.bytes() + spheres_.bytes(); }

    const BvhNodeBuffer& nodes() const { return nodes_; }
    const BvhSphereBuffer& spheres() const { return spheres_; }
    std::span<const std::uint32_t> sphereIds() const { return spheres_.column<BvhSphereId>(); }

    // A hierarchy from what nodes(), spheres() and depth() reported, for
    // loading a saved one without rebuilding it. Throws std::invalid_argument
    // unless the nodes form one tree that a query can walk safely: children
    // after their parent and inside the node array, every node reached once,
    // leaves of 1 to 64 spheres inside the sphere array, and the given depth,
    // which fits the traversal stack.
    static PhotonBvh restore(BvhNodeBuffer nodes, BvhSphereBuffer spheres, std::uint32_t depth);

    // Squared distance from `center` to the segment origin + t direction,
    // t in [tNear, tFar] (direction of unit length), and the unclamped
    // parameter of the point of the line closest to `center`. Exposed so that
    // callers and tests reproduce a query's decisions bit for bit: the query
    // evaluates the same operations in the same order.
    static float segmentDistance2(const Vec3& center, const Vec3& origin, const Vec3& direction, float tNear,
                                  float tFar, float* tClosest) {
        const float vx = center.x - origin.x, vy = center.y - origin.y, vz = center.z - origin.z;
        const float t = vx * direction.x + vy * direction.y + vz * direction.z;
        *tClosest = t;
        const float tc = std::min(std::max(t, tNear), tFar);
        const float qx = vx - tc * direction.x, qy = vy - tc * direction.y, qz = vz - tc * direction.z;
        return qx * qx + qy * qy + qz * qz;
    }
    Vec3 center(std::size_t slot) const {
        return {spheres_.column<BvhSphereX>()[slot], spheres_.column<BvhSphereY>()[slot],
                spheres_.column<BvhSphereZ>()[slot]};
    }

    // Calls visit(slot, tClosest, distance²) for every sphere with
    // segmentDistance2(...) <= radius², i.e. every sphere the segment touches;
    // slot indexes spheres() (sphereIds()[slot] is the caller's index). The
    // order of visits is fixed by the tree (depth first, first child first).
    // tFar may be kInfinity; a segment with tFar < tNear touches nothing.
    template <class F>
    void forEachSphereOnSegment(const Vec3& origin, const Vec3& direction, float tNear, float tFar, F&& visit,
                                BvhQueryStats* stats = nullptr) const;

private:
    // The build bounds the depth (median splits take over below depth 48), so
    // a traversal never holds more pending nodes than this.
    static constexpr int kStackSize = 128;
    static constexpr std::uint32_t kMaxLeafSize = 64;

    BvhNodeBuffer nodes_;
    BvhSphereBuffer spheres_;
    std::uint32_t depth_ = 0;
};

template <>
struct BufferTypeName<PhotonBvh> {
    static constexpr const char* value = "PhotonBvh";
};

template <class F>
void PhotonBvh::forEachSphereOnSegment(const Vec3& origin, const Vec3& direction, float tNear, float tFar,
                                       F&& visit, BvhQueryStats* stats) const {
    if (nodes_.empty() || !(tFar >= tNear)) return;
    // A zero component would give 0 * inf = NaN in the slab test; a huge
    // finite inverse gives the same answer without it.
    const auto inverse = [](float x) {
        return std::abs(x) > 1e-30f ? 1.0f / x : std::copysign(1e30f, x);
    };
    const Vec3 invDir(inverse(direction.x), inverse(direction.y), inverse(direction.z));
    const Vec3* lo = nodes_.column<BvhNodeLo>().data();
    const Vec3* hi = nodes_.column<BvhNodeHi>().data();
    const std::uint32_t* link = nodes_.column<BvhNodeLink>().data();
    const std::uint32_t* count = nodes_.column<BvhNodeCount>().data();
    const float* cx = spheres_.column<BvhSphereX>().data();
    const float* cy = spheres_.column<BvhSphereY>().data();
    const float* cz = spheres_.column<BvhSphereZ>().data();
    const float* radius = spheres_.column<BvhSphereRadius>().data();
    const float ox = origin.x, oy = origin.y, oz = origin.z;
    const float dx = direction.x, dy = direction.y, dz = direction.z;
    float leafT[kMaxLeafSize], leafD2[kMaxLeafSize];
    bool leafHit[kMaxLeafSize];

    const auto hitsBox = [&](std::uint32_t node) {
        const Vec3 t0 = (lo[node] - origin) * invDir;
        const Vec3 t1 = (hi[node] - origin) * invDir;
        const Vec3 tMin = glm::min(t0, t1);
        const Vec3 tMax = glm::max(t0, t1);
        const float enter = std::max(std::max(tNear, tMin.x), std::max(tMin.y, tMin.z));
        const float exit = std::min(std::min(tFar, tMax.x), std::min(tMax.y, tMax.z));
        return enter <= exit;
    };

    std::uint32_t stack[kStackSize];
    int top = 0;
    std::uint32_t node = 0;
    std::int64_t nodesVisited = 1, spheresTested = 0;
    if (!hitsBox(0)) {
        if (stats) ++stats->nodes;
        return;
    }
    // Both children's boxes are tested when their parent is reached, so that
    // a missed child is never fetched again or pushed.
    for (;;) {
        const std::uint32_t n = count[node];
        if (n == 0) {
            const std::uint32_t first = node + 1, second = link[node];
            const bool hitFirst = hitsBox(first), hitSecond = hitsBox(second);
            nodesVisited += 2;
            if (hitFirst) {
                if (hitSecond) stack[top++] = second;
                node = first;
                continue;
            }
            if (hitSecond) {
                node = second;
                continue;
            }
        } else {
            const std::uint32_t first = link[node];
            spheresTested += n;
            // Branch-free over the leaf (vectorisable), then the visits.
            for (std::uint32_t k = 0; k < n; ++k) {
                const std::uint32_t s = first + k;
                const float vx = cx[s] - ox, vy = cy[s] - oy, vz = cz[s] - oz;
                const float t = vx * dx + vy * dy + vz * dz;
                const float tc = std::min(std::max(t, tNear), tFar);
                const float qx = vx - tc * dx, qy = vy - tc * dy, qz = vz - tc * dz;
                const float d2 = qx * qx + qy * qy + qz * qz;
                leafT[k] = t;
                leafD2[k] = d2;
                leafHit[k] = d2 <= radius[s] * radius[s];
            }
            for (std::uint32_t k = 0; k < n; ++k)
                if (leafHit[k]) visit(first + k, leafT[k], leafD2[k]);
        }
        if (top == 0) break;
        node = stack[--top];
    }
    if (stats) {
        stats->nodes += nodesVisited;
        stats->spheres += spheresTested;
    }
}

}  // namespace fg
