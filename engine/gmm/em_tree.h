// The partition family of accelerated EM (Jakob et al. 2011 §5.1, after
// Verbeek, Nunnink & Vlassis 2006): a balanced kd-tree over photon positions
// whose every node keeps the sufficient statistics of the photons inside it —
// count n_A, mean m_A, centred scatter S_A = sum (x - m_A)(x - m_A)^T (so the
// cell covariance is C_A = S_A / n_A), summed RGB power and bounding box. Any
// cut through the tree is a partition P. Nodes are stored depth first: a
// node's left child follows it, `right` names the other.
//
// Later photons (§5.2) are binned down the frozen splits and their statistics
// blended into every node on their path with Chan, Golub & LeVeque's pairwise
// update (n = n_a + n_b, delta = m_b - m_a, m = m_a + delta n_b / n,
// S = S_a + S_b + delta delta^T n_a n_b / n), which needs no raw moments and so
// loses no precision however many photons stream through.
#pragma once

#include "engine/core/math.h"
#include "engine/core/pass.h"
#include "engine/core/soa.h"
#include "engine/gmm/em.h"
#include "engine/gmm/gaussian.h"

#include <cstdint>
#include <limits>
#include <span>
#include <vector>

namespace fg {

inline constexpr std::uint8_t kEmLeaf = 3;  // split axis of a leaf

struct EmSplit {
    float value = 0.0f;          // x[axis] < value: left child; otherwise right
    std::uint8_t axis = kEmLeaf;
};

FG_SOA_COLUMN(EmNodeCount, std::uint64_t, "count");
FG_SOA_COLUMN(EmNodeMean, glm::dvec3, "mean");
FG_SOA_COLUMN(EmNodeScatter, gmm::Sym3, "scatter");
FG_SOA_COLUMN(EmNodePower, glm::dvec3, "power");
FG_SOA_COLUMN(EmNodeLo, Vec3, "lo");
FG_SOA_COLUMN(EmNodeHi, Vec3, "hi");
FG_SOA_COLUMN(EmNodeSplit, EmSplit, "split");
FG_SOA_COLUMN(EmNodeRight, std::uint32_t, "right");

using EmTreeBuffer =
    SoaBuffer<EmNodeCount, EmNodeMean, EmNodeScatter, EmNodePower, EmNodeLo, EmNodeHi, EmNodeSplit, EmNodeRight>;

// Statistics of a set of points: what a node holds and what Chan's update merges.
struct EmStatistics {
    std::uint64_t count = 0;
    glm::dvec3 mean{0.0};
    gmm::Sym3 scatter;
    glm::dvec3 power{0.0};
    void merge(const EmStatistics& other);
};

struct EmTree {
    EmTreeBuffer nodes;
    std::uint32_t leafSize = 4;
    std::uint64_t batches = 0;  // batches blended in after the build

    // Builds the tree over `positions` (power per photon alongside): a node of
    // more than leafSize photons splits at the median of its box's longest
    // axis (ties by photon index).
    void build(std::span<const Vec3> positions, std::span<const Rgb> power, std::uint32_t maxLeafSize = 4);
    // Bins a batch down the frozen splits and blends it into every node on the
    // photons' paths (powers multiplied by powerScale).
    void update(std::span<const Vec3> positions, std::span<const Rgb> power, double powerScale = 1.0);

    std::size_t size() const { return nodes.size(); }
    bool isLeaf(std::uint32_t node) const { return nodes.column<EmNodeSplit>()[node].axis == kEmLeaf; }
    std::uint32_t left(std::uint32_t node) const { return node + 1; }
    std::uint32_t right(std::uint32_t node) const { return nodes.column<EmNodeRight>()[node]; }
    EmStatistics statistics(std::uint32_t node) const;
    // The leaf a point falls into.
    std::uint32_t leafOf(const Vec3& x) const;
    // A cut of `cells` nodes (or all leaves, if fewer): starting from the root,
    // the node with the most photons is replaced by its children (ties by
    // index) until there are enough; in a balanced tree, a level of it.
    std::vector<std::uint32_t> cut(std::size_t cells) const;
    std::size_t bytes() const { return nodes.bytes(); }
};
template <>
struct BufferTypeName<EmTree> {
    static constexpr const char* value = "EmTree";
};

// The statistics of the cells of a cut, as accelerated EM reads them (empty cells skipped).
gmm::EmCells cellsOf(const EmTree& tree, std::span<const std::uint32_t> cut);

}  // namespace fg
