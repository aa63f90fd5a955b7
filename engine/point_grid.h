// A uniform grid over a fixed set of points, answering the two neighbour
// queries of density estimation: every point within a radius (photon
// splatting) and the k nearest points within a radius (photon gathering).
//
//   PointGrid grid;
//   grid.build(positions);
//   grid.forEachInRadius(x, r, [&](std::uint32_t point, float dist2) { ... });
//   std::size_t found = grid.nearest(x, k, maxRadius, indices, dist2);
//
// Points are stored cell by cell (a counting sort), in increasing index order
// inside each cell, so every query visits points in an order fixed by the
// point set alone, never by the thread count that built it.
#pragma once

#include "engine/math.h"

#include <array>
#include <cstdint>
#include <span>
#include <vector>

namespace fg {

struct PointGridOptions {
    // Average points per cell if the points filled the bounding box;
    // points on surfaces crowd fewer cells more densely.
    float pointsPerCell = 1.0f;
};

class PointGrid {
public:
    using BuildOptions = PointGridOptions;

    PointGrid() = default;
    explicit PointGrid(std::span<const Vec3> positions, const BuildOptions& options = {}) { build(positions, options); }

    // Rebuilds over a copy of `positions` (at most 2^32 - 2 points), in parallel through jobs/.
    void build(std::span<const Vec3> positions, const BuildOptions& options = {});

    std::size_t size() const { return sortedPoints_.size(); }
    float cellSize() const { return cellSize_; }
    std::array<int, 3> dimensions() const { return dims_; }
    std::size_t bytes() const;

    // The squared distance every query compares against radius².
    static float distance2(const Vec3& a, const Vec3& b) {
        const float dx = a.x - b.x, dy = a.y - b.y, dz = a.z - b.z;
        return dx * dx + dy * dy + dz * dz;
    }

    // Calls visit(index, distance²) for every point with distance2 <= radius².
    // A negative radius visits nothing.
    template <class F>
    void forEachInRadius(const Vec3& center, float radius, F&& visit) const;

    // The up to k points nearest to `center` with distance² <= maxRadius²,
    // ordered by (distance², index), written to the front of outIndices and
    // outDist2; returns how many. k is capped by the sizes of both spans.
    // maxRadius may be infinite.
    std::size_t nearest(const Vec3& center, std::size_t k, float maxRadius, std::span<std::uint32_t> outIndices,
                        std::span<float> outDist2) const;

private:
    std::size_t cellIndex(int x, int y, int z) const {
        return (static_cast<std::size_t>(z) * static_cast<std::size_t>(dims_[1]) + static_cast<std::size_t>(y)) *
                   static_cast<std::size_t>(dims_[0]) +
               static_cast<std::size_t>(x);
    }

    Vec3 origin_{0.0f};
    float cellSize_ = 1.0f;
    float inverseCellSize_ = 1.0f;
    std::array<int, 3> dims_{0, 0, 0};
    std::vector<std::uint32_t> cellStart_;  // cells + 1 offsets into the sorted arrays
    std::vector<Vec3> sortedPoints_;
    std::vector<std::uint32_t> sortedIndex_;  // original index of each sorted point
};

template <class F>
void PointGrid::forEachInRadius(const Vec3& center, float radius, F&& visit) const {
    if (sortedPoints_.empty() || !(radius >= 0.0f)) return;
    const float radius2 = radius * radius;
    // The cell range is widened slightly so that rounding in it can never drop a
    // point the exact distance test below would accept.
    const float reach = radius * 1.0001f + cellSize_ * 1e-4f;
    std::array<int, 3> lo{}, hi{};
    for (int a = 0; a < 3; ++a) {
        const float first = std::floor((center[a] - reach - origin_[a]) * inverseCellSize_);
        const float last = std::floor((center[a] + reach - origin_[a]) * inverseCellSize_);
        if (!(last >= 0.0f) || !(first <= static_cast<float>(dims_[a] - 1))) return;
        lo[a] = first <= 0.0f ? 0 : static_cast<int>(first);
        hi[a] = last >= static_cast<float>(dims_[a] - 1) ? dims_[a] - 1 : static_cast<int>(last);
    }
    for (int z = lo[2]; z <= hi[2]; ++z) {
        for (int y = lo[1]; y <= hi[1]; ++y) {
            const std::size_t rowBegin = cellStart_[cellIndex(lo[0], y, z)];
            const std::size_t rowEnd = cellStart_[cellIndex(hi[0], y, z) + 1];
            // Cells of one row are contiguous, so the row is one run of points.
            for (std::size_t i = rowBegin; i < rowEnd; ++i) {
                const float d2 = distance2(center, sortedPoints_[i]);
                if (d2 <= radius2) visit(sortedIndex_[i], d2);
            }
        }
    }
}

}  // namespace fg
