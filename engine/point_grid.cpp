// Uniform-grid neighbour search for density estimation (the fixed-radius and
// k-nearest-neighbour queries of photon mapping, Jensen 1996, and of photon
// splatting over an eye-vertex map, Frisvad et al. 2014 §3.3).
//
// Build: the cell size is chosen so that the grid has about n / pointsPerCell
// cells over the points' bounding box (bisection on the edge length, so flat
// or elongated point sets still get a sensible grid), then the points are
// counting-sorted by cell: atomic counts, a prefix sum, an atomic scatter and
// a sort of each cell's indices. The sort makes the stored order a function
// of the point set alone, whatever the number of threads.
//
// k nearest: cells are visited in rings of growing Chebyshev distance around
// the query's cell; a bounded max-heap keeps the best k by (distance², index),
// and the search stops once no unvisited ring can hold a point closer than
// the heap's worst entry (or within maxRadius).
#include "engine/point_grid.h"

#include "jobs/parallel.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <stdexcept>

namespace fg {

namespace {

constexpr std::size_t kGrain = 4096;

// A max-heap of (distance², index) over caller-provided storage.
class CandidateHeap {
public:
    CandidateHeap(std::uint32_t* indices, float* dist2, std::size_t capacity)
        : indices_(indices), dist2_(dist2), capacity_(capacity) {}

    bool full() const { return size_ == capacity_; }
    float worstDistance2() const { return dist2_[0]; }
    std::size_t size() const { return size_; }

    void offer(std::uint32_t index, float d2) {
        if (size_ < capacity_) {
            std::size_t i = size_++;
            indices_[i] = index;
            dist2_[i] = d2;
            while (i > 0) {
                const std::size_t parent = (i - 1) / 2;
                if (!before(parent, i)) break;
                swap(parent, i);
                i = parent;
            }
            return;
        }
        if (!(d2 < dist2_[0] || (d2 == dist2_[0] && index < indices_[0]))) return;
        indices_[0] = index;
        dist2_[0] = d2;
        siftDown(0, size_);
    }

    // Heap sort in place: ascending (distance², index).
    void sortAscending() {
        for (std::size_t end = size_; end > 1; --end) {
            swap(0, end - 1);
            siftDown(0, end - 1);
        }
    }

private:
    // True if entry a orders before entry b, i.e. is nearer.
    bool before(std::size_t a, std::size_t b) const {
        return dist2_[a] < dist2_[b] || (dist2_[a] == dist2_[b] && indices_[a] < indices_[b]);
    }
    void swap(std::size_t a, std::size_t b) {
        std::swap(indices_[a], indices_[b]);
        std::swap(dist2_[a], dist2_[b]);
    }
    void siftDown(std::size_t i, std::size_t end) {
        for (;;) {
            const std::size_t left = 2 * i + 1, right = left + 1;
            std::size_t largest = i;
            if (left < end && before(largest, left)) largest = left;
            if (right < end && before(largest, right)) largest = right;
            if (largest == i) return;
            swap(i, largest);
            i = largest;
        }
    }

    std::uint32_t* indices_;
    float* dist2_;
    std::size_t capacity_;
    std::size_t size_ = 0;
};

struct Bounds {
    Vec3 lo{std::numeric_limits<float>::infinity()};
    Vec3 hi{-std::numeric_limits<float>::infinity()};
    std::size_t nonFinite = 0;
};

double cellCount(const Vec3& extent, double edge) {
    double cells = 1.0;
    for (int a = 0; a < 3; ++a) cells *= std::max(1.0, std::ceil(static_cast<double>(extent[a]) / edge));
    return cells;
}

}  // namespace

void PointGrid::build(std::span<const Vec3> positions, const BuildOptions& options) {
    const std::size_t n = positions.size();
    if (n >= std::numeric_limits<std::uint32_t>::max())
        throw std::length_error("PointGrid: at most 2^32 - 2 points can be indexed");
    if (!(options.pointsPerCell > 0.0f)) throw std::invalid_argument("PointGrid: pointsPerCell must be positive");
    sortedPoints_.clear();
    sortedIndex_.clear();
    cellStart_.assign(1, 0);
    dims_ = {0, 0, 0};
    if (n == 0) return;

    const Bounds bounds = jobs::deterministicReduce<Bounds>(
        n, 64, [] { return Bounds{}; },
        [&](Bounds& b, jobs::IndexRange r) {
            for (std::size_t i = r.begin; i != r.end; ++i) {
                const Vec3& p = positions[i];
                if (!(std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z))) {
                    ++b.nonFinite;
                    continue;
                }
                b.lo = glm::min(b.lo, p);
                b.hi = glm::max(b.hi, p);
            }
        },
        [](Bounds& total, const Bounds& part) {
            total.lo = glm::min(total.lo, part.lo);
            total.hi = glm::max(total.hi, part.hi);
            total.nonFinite += part.nonFinite;
        });
    if (bounds.nonFinite > 0) throw std::invalid_argument("PointGrid: a point has a non-finite coordinate");

    origin_ = bounds.lo;
    const Vec3 extent = bounds.hi - bounds.lo;
    const double maxExtent = std::max<double>(extent.x, std::max<double>(extent.y, extent.z));
    const double targetCells = std::max(1.0, static_cast<double>(n) / static_cast<double>(options.pointsPerCell));
    double edge = 1.0;
    if (maxExtent > 0.0) {
        // cellCount falls as the edge grows; find the smallest edge within the target.
        double small = maxExtent * 0x1p-20, large = maxExtent;
        for (int iteration = 0; iteration < 64; ++iteration) {
            const double mid = std::sqrt(small * large);
            (cellCount(extent, mid) <= targetCells ? large : small) = mid;
        }
        edge = large;
    }
    cellSize_ = static_cast<float>(edge);
    inverseCellSize_ = 1.0f / cellSize_;
    for (int a = 0; a < 3; ++a)
        dims_[a] = static_cast<int>(std::max(1.0, std::ceil(static_cast<double>(extent[a]) / edge)));
    const std::size_t cells = static_cast<std::size_t>(dims_[0]) * dims_[1] * dims_[2];

    std::vector<std::uint32_t> cellOf(n);
    jobs::parallelFor(n, kGrain, [&](std::size_t i) {
        std::array<int, 3> c{};
        for (int a = 0; a < 3; ++a) {
            const float g = std::floor((positions[i][a] - origin_[a]) * inverseCellSize_);
            c[a] = g <= 0.0f ? 0 : std::min(dims_[a] - 1, static_cast<int>(std::min(g, 2e9f)));
        }
        cellOf[i] = static_cast<std::uint32_t>(cellIndex(c[0], c[1], c[2]));
    });

    std::vector<std::atomic<std::uint32_t>> counts(cells);
    jobs::parallelFor(n, kGrain, [&](std::size_t i) { counts[cellOf[i]].fetch_add(1, std::memory_order_relaxed); });
    cellStart_.assign(cells + 1, 0);
    for (std::size_t c = 0; c < cells; ++c) cellStart_[c + 1] = cellStart_[c] + counts[c].load(std::memory_order_relaxed);

    // The counters become scatter cursors.
    jobs::parallelFor(cells, kGrain, [&](std::size_t c) { counts[c].store(cellStart_[c], std::memory_order_relaxed); });
    sortedIndex_.resize(n);
    jobs::parallelFor(n, kGrain, [&](std::size_t i) {
        sortedIndex_[counts[cellOf[i]].fetch_add(1, std::memory_order_relaxed)] = static_cast<std::uint32_t>(i);
    });
    jobs::parallelFor(cells, kGrain, [&](std::size_t c) {
        std::sort(sortedIndex_.begin() + cellStart_[c], sortedIndex_.begin() + cellStart_[c + 1]);
    });
    sortedPoints_.resize(n);
    jobs::parallelFor(n, kGrain, [&](std::size_t s) { sortedPoints_[s] = positions[sortedIndex_[s]]; });
}

std::size_t PointGrid::bytes() const {
    return cellStart_.capacity() * sizeof(std::uint32_t) + sortedPoints_.capacity() * sizeof(Vec3) +
           sortedIndex_.capacity() * sizeof(std::uint32_t);
}

std::size_t PointGrid::nearest(const Vec3& center, std::size_t k, float maxRadius,
                               std::span<std::uint32_t> outIndices, std::span<float> outDist2) const {
    k = std::min({k, outIndices.size(), outDist2.size()});
    if (k == 0 || sortedPoints_.empty() || !(maxRadius >= 0.0f)) return 0;
    const float maxRadius2 = maxRadius * maxRadius;
    CandidateHeap heap(outIndices.data(), outDist2.data(), k);

    // The query's cell, unclamped (it may lie outside the grid), and how far the
    // query sits from its cell's nearest face, in cells.
    constexpr float kCoordinateLimit = 0x1p30f;
    std::array<long long, 3> centre{};
    float margin = 0.5f;
    for (int a = 0; a < 3; ++a) {
        const float g = std::clamp((center[a] - origin_[a]) * inverseCellSize_, -kCoordinateLimit, kCoordinateLimit);
        const float cell = std::floor(g);
        centre[a] = static_cast<long long>(cell);
        const float fraction = g - cell;
        margin = std::min(margin, std::min(fraction, 1.0f - fraction));
    }
    margin = std::max(0.0f, margin);

    // Rings that can hold grid cells: from the grid's Chebyshev distance to its farthest corner.
    long long firstRing = 0, lastRing = 0;
    for (int a = 0; a < 3; ++a) {
        const long long top = dims_[a] - 1;
        firstRing = std::max(firstRing, std::max(-centre[a], centre[a] - top));
        lastRing = std::max(lastRing, std::max(centre[a], top - centre[a]));
    }

    const auto visitRun = [&](std::size_t beginCell, std::size_t endCell) {
        for (std::size_t i = cellStart_[beginCell]; i < cellStart_[endCell]; ++i) {
            const float d2 = distance2(center, sortedPoints_[i]);
            if (d2 <= maxRadius2) heap.offer(sortedIndex_[i], d2);
        }
    };

    for (long long d = firstRing; d <= lastRing; ++d) {
        if (d > 0) {
            // Nothing in ring d or beyond is nearer than this (shrunk against rounding).
            const float bound = (static_cast<float>(d - 1) + margin) * cellSize_ * (1.0f - 1e-4f);
            const float bound2 = bound * bound;
            if (bound2 > maxRadius2) break;
            if (heap.full() && heap.worstDistance2() < bound2) break;
        }
        const long long zBegin = std::max(0LL, centre[2] - d), zEnd = std::min<long long>(dims_[2] - 1, centre[2] + d);
        const long long yBegin = std::max(0LL, centre[1] - d), yEnd = std::min<long long>(dims_[1] - 1, centre[1] + d);
        const long long xBegin = std::max(0LL, centre[0] - d), xEnd = std::min<long long>(dims_[0] - 1, centre[0] + d);
        if (xBegin > xEnd) continue;
        for (long long z = zBegin; z <= zEnd; ++z) {
            const bool zFace = z == centre[2] - d || z == centre[2] + d;
            for (long long y = yBegin; y <= yEnd; ++y) {
                const auto yi = static_cast<int>(y), zi = static_cast<int>(z);
                if (zFace || y == centre[1] - d || y == centre[1] + d) {
                    visitRun(cellIndex(static_cast<int>(xBegin), yi, zi), cellIndex(static_cast<int>(xEnd), yi, zi) + 1);
                    continue;
                }
                // Inside the ring's cross-section only the two x ends belong to ring d.
                const long long left = centre[0] - d, right = centre[0] + d;
                if (left >= 0 && left < dims_[0])
                    visitRun(cellIndex(static_cast<int>(left), yi, zi), cellIndex(static_cast<int>(left), yi, zi) + 1);
                if (d > 0 && right >= 0 && right < dims_[0])
                    visitRun(cellIndex(static_cast<int>(right), yi, zi), cellIndex(static_cast<int>(right), yi, zi) + 1);
            }
        }
    }
    heap.sortAscending();
    return heap.size();
}

}  // namespace fg
