// The neighbour structure the density-estimation passes share, as a pipeline
// buffer: built once from photon or eye-vertex positions by an index pass and
// read by the gather and splat passes. It owns a copy of the positions it
// indexes (the kd-tree's, in tree order), so it outlives the buffer it was built from, and may index a subset
// of them (e.g. photons of some classes only), reporting the caller's indices.
//
// The search itself is delegated to the balanced kd-tree (engine/accel/kdtree.h);
// any structure with the same build and the same two queries can replace it
// without touching the passes.
#pragma once

#include "engine/core/math.h"
#include "engine/core/pass.h"
#include "engine/accel/kdtree.h"

#include <cstdint>
#include <span>
#include <stdexcept>
#include <string>
#include <vector>

namespace fg {

class PointIndex {
public:
    PointIndex() = default;
    PointIndex(const PointIndex&) = delete;
    PointIndex& operator=(const PointIndex&) = delete;
    PointIndex(PointIndex&&) = default;
    PointIndex& operator=(PointIndex&&) = default;

    // Indexes every point; queries report positions in `points`.
    void build(std::span<const Vec3> points) {
        ids_.clear();
        search_.build(points);
    }
    // Indexes points[ids[j]] for increasing ids; queries report those ids.
    void build(std::span<const Vec3> points, std::vector<std::uint32_t> ids) {
        for (std::size_t j = 0; j < ids.size(); ++j) {
            if (ids[j] >= points.size() || (j > 0 && ids[j] <= ids[j - 1]))
                throw std::invalid_argument("PointIndex: ids must be increasing indices into the points");
        }
        std::vector<Vec3> subset(ids.size());
        for (std::size_t j = 0; j < ids.size(); ++j) subset[j] = points[ids[j]];
        ids_ = std::move(ids);
        search_.build(subset);
    }

    // What a saved index holds: the caller's ids (empty: the identity) and the tree.
    std::span<const std::uint32_t> ids() const { return ids_; }
    const KdTree& tree() const { return search_; }
    // An index from what ids() and tree() reported. Throws
    // std::invalid_argument unless ids is empty or holds one increasing id per
    // indexed point.
    static PointIndex restore(KdTree tree, std::vector<std::uint32_t> ids) {
        if (!ids.empty() && ids.size() != tree.size())
            throw std::invalid_argument("PointIndex: " + std::to_string(ids.size()) + " ids for " +
                                        std::to_string(tree.size()) + " points");
        for (std::size_t j = 1; j < ids.size(); ++j)
            if (ids[j] <= ids[j - 1]) throw std::invalid_argument("PointIndex: ids must be increasing");
        PointIndex index;
        index.ids_ = std::move(ids);
        index.search_ = std::move(tree);
        return index;
    }

    std::size_t size() const { return search_.size(); }
    bool empty() const { return search_.empty(); }
    std::size_t bytes() const { return ids_.capacity() * sizeof(std::uint32_t) + search_.bytes(); }

    // Slots: the points in the index's own (tree) order, 0 .. size() - 1. A pass
    // that reads per-point data for every point a query finds can copy it into
    // slot order once and then read it leaf by leaf instead of at random.
    std::uint32_t slotId(std::uint32_t slot) const { return id(search_.permutation()[slot]); }
    const Vec3& slotPosition(std::uint32_t slot) const { return search_.slotPosition(slot); }
    // visit(slot) for every indexed point inside the box [lo, hi] (bounds inclusive).
    template <class F>
    void forEachSlotInBox(const Vec3& lo, const Vec3& hi, F&& visit) const {
        search_.forEachSlotInBox(lo, hi, visit);
    }

    // visit(id, distance²) for every indexed point with distance² <= radius².
    template <class F>
    void forEachInRadius(const Vec3& center, float radius, F&& visit) const {
        search_.forEachInRadius(center, radius, [&](std::uint32_t local, float d2) { visit(id(local), d2); });
    }

    // visit(id) for every indexed point inside the box [lo, hi] (bounds inclusive).
    template <class F>
    void forEachInBox(const Vec3& lo, const Vec3& hi, F&& visit) const {
        search_.forEachInBox(lo, hi, [&](std::uint32_t local) { visit(id(local)); });
    }

    // The up to k nearest indexed points with distance² <= maxRadius² (which
    // may be infinite), ordered by (distance², id); returns how many.
    std::size_t nearest(const Vec3& center, std::size_t k, float maxRadius, std::span<std::uint32_t> outIds,
                        std::span<float> outDist2) const {
        const std::size_t found = search_.nearest(center, k, maxRadius, outIds, outDist2);
        // Ids increase with the local index, so the order survives the mapping.
        if (!ids_.empty())
            for (std::size_t j = 0; j < found; ++j) outIds[j] = ids_[outIds[j]];
        return found;
    }

private:
    std::uint32_t id(std::uint32_t local) const { return ids_.empty() ? local : ids_[local]; }

    std::vector<std::uint32_t> ids_;  // empty: the identity
    KdTree search_;
};

template <>
struct BufferTypeName<PointIndex> {
    static constexpr const char* value = "PointIndex";
};

}  // namespace fg
