// A balanced 3D kd-tree over a point set held elsewhere (the position column of
// an SoA buffer: photons, eye vertices), answering fixed-radius range queries
// and bounded k-nearest-neighbour queries.
//
//   KdTree tree(buffer.column<PhotonPosition>());
//   tree.forEachInRadius(x, r, [&](std::uint32_t photon, float dist2) { ... });
//   std::size_t found = tree.nearest(x, k, maxRadius, indices, dist2);
//
// The tree keeps a copy of the positions in tree order (so a leaf is scanned
// from contiguous memory and the caller's positions need not outlive it), the
// permutation from tree order to point indices and one split record per inner
// node. Positions must be finite.
//
// Queries are const and may run concurrently from any number of threads. The
// built tree is a function of the point set alone, never of the thread count.
#pragma once

#include "engine/core/math.h"

#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

namespace fg {

// Declared outside KdTree so that `= {}` can be a default argument inside it.
struct KdTreeBuildOptions {
    // Ranges of at most this many points become leaves scanned linearly. On
    // 1M points, leaves of up to 16 answered k = 50 queries 1.6-2.4x faster
    // than one-point leaves and built 28% faster in 36% of the memory; 8 and
    // 32 were within noise of 16 for k from 5 to 50 and for ~50-point ranges
    // (tools/bench/bench_kdtree.cpp).
    std::uint32_t maxLeafSize = 16;
    // Subtrees with at least this many points build their two children as
    // parallel tasks; smaller ones are built serially by one task.
    std::size_t parallelThreshold = std::size_t(1) << 15;
};

class KdTree {
public:
    using BuildOptions = KdTreeBuildOptions;

    // Split record of an inner node: points left of it have
    // position[axis] <= value, points right of it have position[axis] >= value.
    struct Split {
        float value = 0.0f;
        std::uint32_t axis = 0;
    };

    KdTree() = default;
    explicit KdTree(std::span<const Vec3> positions, const BuildOptions& options = {}) { build(positions, options); }

    // Rebuilds over `positions` (at most 2^31 - 1 points). Throws
    // std::invalid_argument if a position is not finite.
    void build(std::span<const Vec3> positions, const BuildOptions& options = {});

    std::size_t size() const { return sorted_.size(); }
    bool empty() const { return sorted_.empty(); }
    std::uint32_t maxLeafSize() const { return leafSize_; }
    // Bytes held by the tree itself (not the positions it views), for profiling.
    std::size_t bytes() const;

    // Point indices in tree order: the points of the node covering the range
    // [begin, end) are permutation()[begin..end). The root covers [0, size());
    // an inner node splits its range at mid = begin + (end - begin) / 2 into
    // [begin, mid) and [mid, end). A range no longer than maxLeafSize() is a leaf.
    std::span<const std::uint32_t> permutation() const { return order_; }
    // Inner-node split records in heap order: the children of node i are
    // 2i + 1 (left) and 2i + 2 (right). Slots of leaves are unused.
    std::span<const Split> splits() const { return splits_; }

    // The positions in tree order: slotPosition(slot) for every slot.
    std::span<const Vec3> sortedPositions() const { return sorted_; }

    // A tree from the arrays a built tree reports (sortedPositions(),
    // permutation(), splits(), maxLeafSize()), for loading a saved one without
    // rebuilding it. Throws std::invalid_argument unless they describe a tree
    // that queries can walk safely: equal sizes, a permutation of 0 .. n - 1,
    // one split per heap slot build() would use, axes below 3, leaf size >= 1.
    static KdTree restore(std::vector<Vec3> sortedPositions, std::vector<std::uint32_t> permutation,
                          std::vector<Split> splits, std::uint32_t maxLeafSize);

    // The squared distance every query compares against radius², exposed so
    // that callers (and tests) can reproduce a query's decisions bit for bit.
    static float distance2(const Vec3& a, const Vec3& b) {
        const float dx = a.x - b.x, dy = a.y - b.y, dz = a.z - b.z;
        return dx * dx + dy * dy + dz * dz;
    }

    // Calls visit(index, distance²) for every point with
    // distance2(center, point) <= radius * radius. Order of visits is
    // unspecified. A negative radius visits nothing.
    template <class F>
    void forEachInRadius(const Vec3& center, float radius, F&& visit) const;

    // Calls visit(index) for every point with lo <= point <= hi on all three
    // axes (an axis-aligned box, bounds inclusive). Order of visits is unspecified.
    template <class F>
    void forEachInBox(const Vec3& lo, const Vec3& hi, F&& visit) const {
        forEachSlotInBox(lo, hi, [&](std::uint32_t slot) { visit(order_[slot]); });
    }
    // As forEachInBox, but reports tree slots: the point is permutation()[slot],
    // at slotPosition(slot). Callers that keep their own per-point data in tree
    // order read it sequentially, leaf by leaf.
    template <class F>
    void forEachSlotInBox(const Vec3& lo, const Vec3& hi, F&& visit) const;
    const Vec3& slotPosition(std::uint32_t slot) const { return sorted_[slot]; }

    // The up to k points nearest to `center` with distance² <= maxRadius²,
    // ordered by (distance², index), written to the front of outIndices and
    // outDist2; returns how many. k is capped by the sizes of both spans. A
    // non-finite center finds nothing.
    std::size_t nearest(const Vec3& center, std::size_t k, float maxRadius, std::span<std::uint32_t> outIndices,
                        std::span<float> outDist2) const;

private:
    struct Range {
        std::uint32_t node;
        std::uint32_t begin;
        std::uint32_t end;
    };
    // Deep enough for any tree over at most 2^31 points: a traversal keeps at
    // most one pending sibling per level.
    static constexpr int kMaxDepth = 64;

    std::vector<Vec3> sorted_;  // positions in tree order
    std::vector<std::uint32_t> order_;
    std::vector<Split> splits_;
    std::uint32_t leafSize_ = KdTreeBuildOptions{}.maxLeafSize;
};

template <class F>
void KdTree::forEachInRadius(const Vec3& center, float radius, F&& visit) const {
    if (sorted_.empty() || !(radius >= 0.0f)) return;
    const float radius2 = radius * radius;
    // Only the plane of each node is tested here, not the box distance that
    // nearest() tracks: with a fixed radius the extra pruning did not pay for
    // the larger stack entries (measured: slower at leaf size 1, no faster at 8).
    Range stack[kMaxDepth];
    int top = 0;
    stack[top++] = Range{0, 0, static_cast<std::uint32_t>(order_.size())};
    while (top > 0) {
        Range range = stack[--top];
        while (range.end - range.begin > leafSize_) {
            const Split split = splits_[range.node];
            const std::uint32_t mid = range.begin + (range.end - range.begin) / 2;
            const float offset = center[static_cast<int>(split.axis)] - split.value;
            // The child across the plane holds no point nearer than the plane;
            // comparing squares keeps this test consistent with distance2().
            const bool reachesAcross = offset * offset <= radius2;
            const Range left{2 * range.node + 1, range.begin, mid};
            const Range right{2 * range.node + 2, mid, range.end};
            if (offset <= 0.0f) {
                if (reachesAcross) stack[top++] = right;
                range = left;
            } else {
                if (reachesAcross) stack[top++] = left;
                range = right;
            }
        }
        for (std::uint32_t i = range.begin; i != range.end; ++i) {
            const float d2 = distance2(center, sorted_[i]);
            if (d2 <= radius2) visit(order_[i], d2);
        }
    }
}

template <class F>
void KdTree::forEachSlotInBox(const Vec3& lo, const Vec3& hi, F&& visit) const {
    if (sorted_.empty() || !(lo.x <= hi.x && lo.y <= hi.y && lo.z <= hi.z)) return;
    Range stack[kMaxDepth];
    int top = 0;
    stack[top++] = Range{0, 0, static_cast<std::uint32_t>(order_.size())};
    while (top > 0) {
        Range range = stack[--top];
        while (range.end - range.begin > leafSize_) {
            const Split split = splits_[range.node];
            const int axis = static_cast<int>(split.axis);
            const std::uint32_t mid = range.begin + (range.end - range.begin) / 2;
            const bool goLeft = lo[axis] <= split.value, goRight = hi[axis] >= split.value;
            const Range left{2 * range.node + 1, range.begin, mid};
            const Range right{2 * range.node + 2, mid, range.end};
            if (goLeft && goRight) {
                stack[top++] = right;
                range = left;
            } else {
                range = goLeft ? left : right;
            }
        }
        for (std::uint32_t i = range.begin; i != range.end; ++i) {
            const Vec3& p = sorted_[i];
            if (p.x >= lo.x && p.x <= hi.x && p.y >= lo.y && p.y <= hi.y && p.z >= lo.z && p.z <= hi.z) visit(i);
        }
    }
}

}  // namespace fg
