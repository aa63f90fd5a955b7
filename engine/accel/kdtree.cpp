// Balanced kd-tree for photon and eye-vertex lookups (Bentley 1975; Friedman,
// Bentley & Finkel 1977 for the k-nearest-neighbour search; Jensen 2001,
// "Realistic Image Synthesis Using Photon Mapping", ch. 6, for its use as a
// photon map).
//
// Layout. Every node covers a contiguous range of a permutation of the point
// indices, and an inner node splits its range exactly in the middle, so the
// range of any node follows from its parent's and need not be stored: the
// tree shape is implicit in (size, leaf size). Inner nodes are addressed in
// heap order (children of i at 2i+1, 2i+2) and hold only a split value and an
// axis, 8 bytes; there are no child links, no per-node ranges and no per-node
// allocations, and the top levels that every query visits share a few cache
// lines. Leaves are ranges of at most maxLeafSize points scanned linearly.
// Because range sizes at depth d are floor(n/2^d) or ceil(n/2^d), all leaves
// lie on at most two adjacent levels and the heap array is at most about
// twice the number of inner nodes.
//
// Build. The split axis is the widest extent of the node's own bounding box
// (not the parent's box cut at the plane, which drifts from the points on
// clustered data such as photons on surfaces), and the split is the median
// found by nth_element under the total order (coordinate, index). Under that
// order the median, and so the set of points on each side, is unique even
// with equal coordinates or all-equal point sets. Subtrees above
// a size threshold build their two halves as parallel tasks; each subtree is
// built serially by whichever thread runs it, so the result does not depend
// on scheduling. Points are copied with their index into a 16-byte build
// record so that the selection passes stream through memory instead of
// gathering positions through the permutation.
#include "engine/accel/kdtree.h"

#include "jobs/parallel.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>
#include <utility>

namespace fg {

namespace {

struct BuildItem {
    Vec3 position;
    std::uint32_t index;
};

struct Bounds {
    Vec3 lo{std::numeric_limits<float>::infinity()};
    Vec3 hi{-std::numeric_limits<float>::infinity()};

    void extend(const Vec3& p) {
        lo = glm::min(lo, p);
        hi = glm::max(hi, p);
    }
    void extend(const Bounds& b) {
        lo = glm::min(lo, b.lo);
        hi = glm::max(hi, b.hi);
    }
    // Ties go to the lower axis so that the choice is reproducible.
    std::uint32_t widestAxis() const {
        const Vec3 extent = hi - lo;
        std::uint32_t axis = 0;
        if (extent.y > extent[static_cast<int>(axis)]) axis = 1;
        if (extent.z > extent[static_cast<int>(axis)]) axis = 2;
        return axis;
    }
};

// Bounding boxes of large ranges are reduced in parallel; min and max are exact,
// so the block order cannot change the result.
constexpr std::size_t kParallelBoundsGrain = std::size_t(1) << 16;

Bounds boundsOf(std::span<const BuildItem> items) {
    Bounds bounds;
    for (const BuildItem& item : items) bounds.extend(item.position);
    return bounds;
}

Bounds parallelBoundsOf(std::span<const BuildItem> items) {
    if (items.size() < 2 * kParallelBoundsGrain) return boundsOf(items);
    const std::size_t blocks = (items.size() + kParallelBoundsGrain - 1) / kParallelBoundsGrain;
    return jobs::deterministicReduce<Bounds>(
        items.size(), blocks, [] { return Bounds{}; },
        [&](Bounds& acc, jobs::IndexRange r) { acc.extend(boundsOf(items.subspan(r.begin, r.size()))); },
        [](Bounds& total, const Bounds& part) { total.extend(part); });
}

class Builder {
public:
    Builder(std::vector<BuildItem>& items, std::vector<KdTree::Split>& splits, std::uint32_t leafSize,
            std::size_t parallelThreshold)
        : items_(items), splits_(splits), leafSize_(leafSize), parallelThreshold_(parallelThreshold) {}

    void buildNode(std::uint32_t node, std::uint32_t begin, std::uint32_t end) const {
        const std::uint32_t count = end - begin;
        if (count <= leafSize_) return;
        const std::span<BuildItem> range(items_.data() + begin, count);
        const bool parallel = count >= parallelThreshold_;
        const Bounds bounds = parallel ? parallelBoundsOf(range) : boundsOf(range);
        const std::uint32_t axis = bounds.widestAxis();
        const int a = static_cast<int>(axis);
        const std::uint32_t mid = begin + count / 2;
        std::nth_element(range.begin(), range.begin() + (mid - begin), range.end(),
                         [a](const BuildItem& x, const BuildItem& y) {
                             return x.position[a] < y.position[a] ||
                                    (x.position[a] == y.position[a] && x.index < y.index);
                         });
        splits_[node] = KdTree::Split{items_[mid].position[a], axis};
        if (parallel) {
            jobs::parallelForChunks(2, 1, [&](jobs::IndexRange r) {
                for (std::size_t child = r.begin; child != r.end; ++child) buildChild(node, begin, mid, end, child);
            });
        } else {
            buildNode(2 * node + 1, begin, mid);
            buildNode(2 * node + 2, mid, end);
        }
    }

private:
    void buildChild(std::uint32_t node, std::uint32_t begin, std::uint32_t mid, std::uint32_t end,
                    std::size_t child) const {
        if (child == 0)
            buildNode(2 * node + 1, begin, mid);
        else
            buildNode(2 * node + 2, mid, end);
    }

    std::vector<BuildItem>& items_;
    std::vector<KdTree::Split>& splits_;
    std::uint32_t leafSize_;
    std::size_t parallelThreshold_;
};

// Heap slots needed for the inner nodes: ranges at depth d hold at most
// ceil(n / 2^d) points, so the deepest inner level is the last one where that
// exceeds the leaf size.
std::size_t innerNodeSlots(std::size_t n, std::size_t leafSize) {
    std::size_t slots = 0;
    std::size_t levelWidth = 1;
    for (std::size_t largest = n; largest > leafSize; largest = (largest + 1) / 2) {
        slots += levelWidth;
        levelWidth *= 2;
    }
    return slots;
}

constexpr std::size_t kFillGrain = std::size_t(1) << 14;

// Lower bound of KdTree::distance2() to any point whose per-axis offsets from
// the query are at least `offsets` in magnitude. It is written exactly as
// distance2() is: every rounded operation is monotonic, so the bound stays a
// bound in floating point and ties at the radius are decided identically.
float boxDistance2(const Vec3& offsets) {
    return offsets.x * offsets.x + offsets.y * offsets.y + offsets.z * offsets.z;
}


// A bounded max-heap under the order (distance², index), kept directly in the
// caller's output arrays so that a query allocates nothing; heap-sorted in
// place at the end.
class NeighbourHeap {
public:
    NeighbourHeap(std::uint32_t* indices, float* dist2, std::size_t capacity)
        : indices_(indices), dist2_(dist2), capacity_(capacity) {}

    std::size_t size() const { return size_; }
    bool full() const { return size_ == capacity_; }
    float worstDist2() const { return dist2_[0]; }
    bool beatsWorst(float d2, std::uint32_t index) const {
        return d2 < dist2_[0] || (d2 == dist2_[0] && index < indices_[0]);
    }

    void push(std::uint32_t index, float d2) {
        std::size_t hole = size_++;
        while (hole > 0) {
            const std::size_t parent = (hole - 1) / 2;
            if (!less(dist2_[parent], indices_[parent], d2, index)) break;
            move(parent, hole);
            hole = parent;
        }
        indices_[hole] = index;
        dist2_[hole] = d2;
    }

    void replaceWorst(std::uint32_t index, float d2) { siftDown(0, size_, index, d2); }

    // Ascending order of (distance², index).
    void sort() {
        for (std::size_t last = size_; last > 1; --last) {
            const std::uint32_t index = indices_[last - 1];
            const float d2 = dist2_[last - 1];
            indices_[last - 1] = indices_[0];
            dist2_[last - 1] = dist2_[0];
            siftDown(0, last - 1, index, d2);
        }
    }

private:
    static bool less(float d2a, std::uint32_t ia, float d2b, std::uint32_t ib) {
        return d2a < d2b || (d2a == d2b && ia < ib);
    }
    void move(std::size_t from, std::size_t to) {
        indices_[to] = indices_[from];
        dist2_[to] = dist2_[from];
    }
    // Places (index, d2) into the hole at `hole` of a heap of `count` items.
    void siftDown(std::size_t hole, std::size_t count, std::uint32_t index, float d2) {
        for (;;) {
            std::size_t child = 2 * hole + 1;
            if (child >= count) break;
            if (child + 1 < count && less(dist2_[child], indices_[child], dist2_[child + 1], indices_[child + 1]))
                ++child;
            if (!less(d2, index, dist2_[child], indices_[child])) break;
            move(child, hole);
            hole = child;
        }
        indices_[hole] = index;
        dist2_[hole] = d2;
    }

    std::uint32_t* indices_;
    float* dist2_;
    std::size_t capacity_;
    std::size_t size_ = 0;
};

}  // namespace

void KdTree::build(std::span<const Vec3> positions, const BuildOptions& options) {
    if (positions.size() > static_cast<std::size_t>(std::numeric_limits<std::int32_t>::max()))
        throw std::length_error("KdTree: more than 2^31 - 1 points");
    leafSize_ = std::max<std::uint32_t>(1, options.maxLeafSize);
    sorted_.clear();
    order_.clear();
    splits_.clear();
    const std::size_t n = positions.size();
    if (n == 0) return;

    std::vector<BuildItem> items(n);
    std::atomic<std::size_t> firstNonFinite{n};
    jobs::parallelForChunks(n, kFillGrain, [&](jobs::IndexRange r) {
        for (std::size_t i = r.begin; i != r.end; ++i) {
            const Vec3& p = positions[i];
            if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z)) {
                std::size_t seen = firstNonFinite.load(std::memory_order_relaxed);
                while (i < seen && !firstNonFinite.compare_exchange_weak(seen, i, std::memory_order_relaxed)) {
                }
            }
            items[i] = BuildItem{p, static_cast<std::uint32_t>(i)};
        }
    });
    if (firstNonFinite.load() < n)
        throw std::invalid_argument("KdTree: point " + std::to_string(firstNonFinite.load()) +
                                    " has a non-finite position");

    std::vector<Split> splits(innerNodeSlots(n, leafSize_));
    Builder(items, splits, leafSize_, std::max<std::size_t>(2, options.parallelThreshold))
        .buildNode(0, 0, static_cast<std::uint32_t>(n));

    std::vector<std::uint32_t> order(n);
    std::vector<Vec3> sorted(n);
    jobs::parallelFor(n, kFillGrain, [&](std::size_t i) {
        order[i] = items[i].index;
        sorted[i] = items[i].position;
    });

    sorted_ = std::move(sorted);
    order_ = std::move(order);
    splits_ = std::move(splits);
}

KdTree KdTree::restore(std::vector<Vec3> sortedPositions, std::vector<std::uint32_t> permutation,
                       std::vector<Split> splits, std::uint32_t maxLeafSize) {
    const std::size_t n = sortedPositions.size();
    if (n > static_cast<std::size_t>(std::numeric_limits<std::int32_t>::max()))
        throw std::invalid_argument("KdTree: more than 2^31 - 1 points");
    if (maxLeafSize == 0) throw std::invalid_argument("KdTree: leaf size 0");
    if (permutation.size() != n)
        throw std::invalid_argument("KdTree: " + std::to_string(n) + " positions but " +
                                    std::to_string(permutation.size()) + " permutation entries");
    // The heap layout is implied by (n, leaf size), so the split count is too.
    const std::size_t expectedSplits = n == 0 ? 0 : innerNodeSlots(n, maxLeafSize);
    if (splits.size() != expectedSplits)
        throw std::invalid_argument("KdTree: " + std::to_string(splits.size()) + " splits, expected " +
                                    std::to_string(expectedSplits));
    for (const Split& split : splits)
        if (split.axis > 2) throw std::invalid_argument("KdTree: split axis " + std::to_string(split.axis));
    std::vector<bool> seen(n, false);
    for (const std::uint32_t index : permutation) {
        if (index >= n || seen[index]) throw std::invalid_argument("KdTree: the order is not a permutation");
        seen[index] = true;
    }
    KdTree tree;
    tree.sorted_ = std::move(sortedPositions);
    tree.order_ = std::move(permutation);
    tree.splits_ = std::move(splits);
    tree.leafSize_ = maxLeafSize;
    return tree;
}

std::size_t KdTree::bytes() const {
    return order_.capacity() * sizeof(std::uint32_t) + splits_.capacity() * sizeof(Split) +
           sorted_.capacity() * sizeof(Vec3);
}

std::size_t KdTree::nearest(const Vec3& center, std::size_t k, float maxRadius, std::span<std::uint32_t> outIndices,
                            std::span<float> outDist2) const {
    k = std::min({k, outIndices.size(), outDist2.size()});
    if (k == 0 || sorted_.empty() || !(maxRadius >= 0.0f)) return 0;
    // A NaN distance would pass every "too far?" test and poison the heap.
    if (!std::isfinite(center.x) || !std::isfinite(center.y) || !std::isfinite(center.z)) return 0;
    NeighbourHeap heap(outIndices.data(), outDist2.data(), k);
    // Until k candidates are held, anything within maxRadius qualifies; then only
    // what beats the worst held one. Equal distances must still be examined
    // since a lower index wins the tie.
    float bound2 = maxRadius * maxRadius;

    // A deferred subtree with the query's offsets to the planes bounding its
    // cell along each axis (Arya & Mount 1993, incremental distance):
    // boxDistance2(offsets) is a lower bound on the distance to any point in it,
    // which prunes about a quarter of the points a plane-only test would scan.
    struct Pending {
        Range range;
        Vec3 offsets;
    };
    Pending stack[kMaxDepth];
    int top = 0;
    stack[top++] = Pending{Range{0, 0, static_cast<std::uint32_t>(order_.size())}, Vec3(0.0f)};
    while (top > 0) {
        const Pending pending = stack[--top];
        if (boxDistance2(pending.offsets) > bound2) continue;
        Range range = pending.range;
        const Vec3& offsets = pending.offsets;
        // Descend to the leaf on the query's side, deferring the far children.
        while (range.end - range.begin > leafSize_) {
            const Split split = splits_[range.node];
            const int axis = static_cast<int>(split.axis);
            const std::uint32_t mid = range.begin + (range.end - range.begin) / 2;
            const float offset = center[axis] - split.value;
            Vec3 farOffsets = offsets;
            farOffsets[axis] = offset;
            const bool reachesAcross = boxDistance2(farOffsets) <= bound2;
            const Range left{2 * range.node + 1, range.begin, mid};
            const Range right{2 * range.node + 2, mid, range.end};
            if (offset <= 0.0f) {
                if (reachesAcross) stack[top++] = Pending{right, farOffsets};
                range = left;
            } else {
                if (reachesAcross) stack[top++] = Pending{left, farOffsets};
                range = right;
            }
        }
        for (std::uint32_t i = range.begin; i != range.end; ++i) {
            const float d2 = distance2(center, sorted_[i]);
            if (d2 > bound2) continue;
            const std::uint32_t index = order_[i];
            if (!heap.full()) {
                heap.push(index, d2);
                if (heap.full()) bound2 = heap.worstDist2();
            } else if (heap.beatsWorst(d2, index)) {
                heap.replaceWorst(index, d2);
                bound2 = heap.worstDist2();
            }
        }
    }
    heap.sort();
    return heap.size();
}

}  // namespace fg
