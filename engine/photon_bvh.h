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
// BVH order (columns `center`, `radius`, `id` = the caller's index), so a leaf
// reads a contiguous run of memory.
//
// The built hierarchy is a function of the input alone, never of the thread
// count. Queries are const and may run concurrently.
#pragma once

#include "engine/math.h"
#include "engine/pass.h"
#include "engine/soa.h"

#include <cstddef>
#include <cstdint>
#include <span>

namespace fg {

struct PhotonBvhBuildOptions {
    // Ranges of at most this many spheres become leaves.
    std::uint32_t maxLeafSize = 4;
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

FG_SOA_COLUMN(BvhSphereCenter, Vec3, "center");
FG_SOA_COLUMN(BvhSphereRadius, float, "radius");
FG_SOA_COLUMN(BvhSphereId, std::uint32_t, "id");  // index of the sphere in the build input
using BvhSphereBuffer = SoaBuffer<BvhSphereCenter, BvhSphereRadius, BvhSphereId>;

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

    // Squared distance from `center` to the segment origin + t direction,
    // t in [tNear, tFar] (direction of unit length), and the unclamped
    // parameter of the point of the line closest to `center`. Exposed so that
    // callers and tests reproduce a query's decisions bit for bit.
    static float segmentDistance2(const Vec3& center, const Vec3& origin, const Vec3& direction, float tNear,
                                  float tFar, float* tClosest) {
        const Vec3 v = center - origin;
        const float t = glm::dot(v, direction);
        *tClosest = t;
        const Vec3 q = v - std::clamp(t, tNear, tFar) * direction;
        return glm::dot(q, q);
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
    const Vec3* center = spheres_.column<BvhSphereCenter>().data();
    const float* radius = spheres_.column<BvhSphereRadius>().data();

    std::uint32_t stack[kStackSize];
    int top = 0;
    std::uint32_t node = 0;
    std::int64_t nodesVisited = 0, spheresTested = 0;
    for (;;) {
        ++nodesVisited;
        const Vec3 t0 = (lo[node] - origin) * invDir;
        const Vec3 t1 = (hi[node] - origin) * invDir;
        const Vec3 tMin = glm::min(t0, t1);
        const Vec3 tMax = glm::max(t0, t1);
        const float enter = std::max(std::max(tNear, tMin.x), std::max(tMin.y, tMin.z));
        const float exit = std::min(std::min(tFar, tMax.x), std::min(tMax.y, tMax.z));
        if (enter <= exit) {
            const std::uint32_t n = count[node];
            if (n == 0) {
                stack[top++] = link[node];
                ++node;
                continue;
            }
            const std::uint32_t first = link[node];
            spheresTested += n;
            for (std::uint32_t s = first; s != first + n; ++s) {
                float tClosest;
                const float d2 = segmentDistance2(center[s], origin, direction, tNear, tFar, &tClosest);
                if (d2 <= radius[s] * radius[s]) visit(s, tClosest, d2);
            }
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
