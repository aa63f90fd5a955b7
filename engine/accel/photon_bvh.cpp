// Sphere BVH for the beam radiance estimate (Jarosz, Zwicker & Jensen 2008,
// "The Beam Radiance Estimate for Volumetric Photon Mapping", which finds the
// photons along a ray with a BVH over the photons' kernel spheres).
//
// Build: top-down binned SAH (Wald 2007, "On fast Construction of SAH-based
// Bounding Volume Hierarchies"; MacDonald & Booth 1990 for the cost). At each
// node the sphere centres are binned into `bins` slabs of the centroid bounds
// along each axis; the split plane between two bins that minimises
//   A(left) N(left) + A(right) N(right)
// (surface areas of the children's boxes) is taken, lowest axis and plane on
// ties. Degenerate ranges (all centres equal along every axis) and nodes deeper
// than kMedianDepth are split at the object median under the total order
// (coordinate, input index) instead, which halves the range and bounds the
// depth for the traversal stack.
//
// Determinism and parallelism: every decision depends on the range's content
// only. Ranges of at least parallelThreshold spheres compute their bounds and
// bins over fixed blocks (jobs::deterministicReduce: min, max and counts are
// exact, so the merge order cannot matter) and build their two children as
// parallel tasks; smaller ranges are built serially, each into its own node
// array in depth-first order. A final pass lays the parallel top of the tree
// and the serial subtrees out depth first and copies the subtrees in
// parallel. So the tree is identical for any thread count.
#include "engine/accel/photon_bvh.h"

#include "jobs/parallel.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <limits>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

namespace fg {

namespace {

// Below this depth every split is an object median (see above).
constexpr std::uint32_t kMedianDepth = 48;
constexpr std::size_t kBlock = std::size_t(1) << 15;
constexpr std::uint32_t kMaxBins = 64;

struct Item {
    Vec3 center;
    float radius;
    std::uint32_t id;
};

struct Box {
    Vec3 lo{std::numeric_limits<float>::infinity()};
    Vec3 hi{-std::numeric_limits<float>::infinity()};
    void extend(const Vec3& p) {
        lo = glm::min(lo, p);
        hi = glm::max(hi, p);
    }
    void extend(const Vec3& l, const Vec3& h) {
        lo = glm::min(lo, l);
        hi = glm::max(hi, h);
    }
    void extend(const Box& b) { extend(b.lo, b.hi); }
    bool valid() const { return lo.x <= hi.x; }
    float halfArea() const {
        if (!valid()) return 0.0f;
        const Vec3 e = hi - lo;
        return e.x * e.y + e.y * e.z + e.z * e.x;
    }
};

// The box of a sphere, padded by a few ulps of its coordinates so that the
// slab test, rounded differently from the exact sphere test, never rejects a
// sphere that a segment touches.
void sphereBox(const Item& item, Vec3* lo, Vec3* hi) {
    const Vec3 pad = 4e-7f * (glm::abs(item.center) + Vec3(item.radius)) + Vec3(1e-30f);
    *lo = item.center - Vec3(item.radius) - pad;
    *hi = item.center + Vec3(item.radius) + pad;
}

struct RangeBounds {
    Box box;       // sphere boxes
    Box centroid;  // centres
    void add(const Item& item) {
        Vec3 l, h;
        sphereBox(item, &l, &h);
        box.extend(l, h);
        centroid.extend(item.center);
    }
    void merge(const RangeBounds& o) {
        box.extend(o.box);
        centroid.extend(o.centroid);
    }
};

struct Bins {
    std::array<std::array<Box, kMaxBins>, 3> box;
    std::array<std::array<std::uint32_t, kMaxBins>, 3> count{};
    void merge(const Bins& o, std::uint32_t bins) {
        for (int a = 0; a < 3; ++a)
            for (std::uint32_t b = 0; b < bins; ++b) {
                box[a][b].extend(o.box[a][b]);
                count[a][b] += o.count[a][b];
            }
    }
};

struct BinMapping {
    Vec3 origin;
    Vec3 scale;  // bins / extent, 0 on flat axes
    std::uint32_t bins;
    std::uint32_t bin(const Vec3& c, int axis) const {
        const float x = (c[axis] - origin[axis]) * scale[axis];
        // Non-negative by construction; the clamp catches the upper end.
        return std::min(bins - 1, static_cast<std::uint32_t>(std::max(x, 0.0f)));
    }
};

struct Node {
    Vec3 lo, hi;
    std::uint32_t link;
    std::uint32_t count;
};

// A node of the parallel top of the tree, or the root of a serially built subtree.
struct BuildTree {
    std::vector<Node> serial;  // non-empty: the whole subtree, depth first, inner links relative to its start
    Node self{};
    std::unique_ptr<BuildTree> left, right;
    std::size_t size = 0;  // nodes in the subtree
    std::uint32_t depth = 0;  // levels below and including this node
};

class Builder {
public:
    Builder(std::vector<Item>& items, const PhotonBvhBuildOptions& options) : items_(items), options_(options) {}

    std::unique_ptr<BuildTree> build(std::uint32_t begin, std::uint32_t end, std::uint32_t depth) const {
        auto tree = std::make_unique<BuildTree>();
        if (end - begin < options_.parallelThreshold) {
            tree->depth = buildSerial(tree->serial, begin, end, depth) - depth;
            tree->size = tree->serial.size();
            return tree;
        }
        const RangeBounds bounds = boundsOf(begin, end, true);
        const std::uint32_t mid = split(bounds, begin, end, depth, true);
        tree->self = Node{bounds.box.lo, bounds.box.hi, 0, 0};
        jobs::parallelForChunks(2, 1, [&](jobs::IndexRange r) {
            for (std::size_t child = r.begin; child != r.end; ++child) {
                if (child == 0)
                    tree->left = build(begin, mid, depth + 1);
                else
                    tree->right = build(mid, end, depth + 1);
            }
        });
        tree->size = 1 + tree->left->size + tree->right->size;
        tree->depth = 1 + std::max(tree->left->depth, tree->right->depth);
        return tree;
    }

private:
    // Appends the subtree over [begin, end) to `nodes`; returns the deepest level reached.
    std::uint32_t buildSerial(std::vector<Node>& nodes, std::uint32_t begin, std::uint32_t end,
                              std::uint32_t depth) const {
        const RangeBounds bounds = boundsOf(begin, end, false);
        const std::size_t index = nodes.size();
        nodes.push_back(Node{bounds.box.lo, bounds.box.hi, begin, end - begin});
        if (end - begin <= options_.maxLeafSize) return depth + 1;
        const std::uint32_t mid = split(bounds, begin, end, depth, false);
        nodes[index].count = 0;
        const std::uint32_t leftDepth = buildSerial(nodes, begin, mid, depth + 1);
        nodes[index].link = static_cast<std::uint32_t>(nodes.size());
        const std::uint32_t rightDepth = buildSerial(nodes, mid, end, depth + 1);
        return std::max(leftDepth, rightDepth);
    }

    RangeBounds boundsOf(std::uint32_t begin, std::uint32_t end, bool parallel) const {
        const auto scan = [&](RangeBounds& acc, jobs::IndexRange r) {
            for (std::size_t i = r.begin; i != r.end; ++i) acc.add(items_[begin + i]);
        };
        const std::size_t n = end - begin;
        if (!parallel) {
            RangeBounds acc;
            scan(acc, {0, n});
            return acc;
        }
        return jobs::deterministicReduce<RangeBounds>(
            n, (n + kBlock - 1) / kBlock, [] { return RangeBounds{}; }, scan,
            [](RangeBounds& total, const RangeBounds& part) { total.merge(part); });
    }

    // Partitions [begin, end) and returns the first index of the second child.
    std::uint32_t split(const RangeBounds& bounds, std::uint32_t begin, std::uint32_t end, std::uint32_t depth,
                        bool parallel) const {
        const Vec3 extent = bounds.centroid.hi - bounds.centroid.lo;
        const std::uint32_t bins = std::clamp<std::uint32_t>(options_.bins, 2, kMaxBins);
        BinMapping mapping{bounds.centroid.lo, Vec3(0.0f), bins};
        for (int a = 0; a < 3; ++a)
            mapping.scale[a] = extent[a] > 0.0f ? static_cast<float>(bins) * (1.0f - 1e-6f) / extent[a] : 0.0f;

        int bestAxis = -1;
        std::uint32_t bestBin = 0;
        if (depth < kMedianDepth && (extent.x > 0.0f || extent.y > 0.0f || extent.z > 0.0f)) {
            const Bins binned = binsOf(mapping, begin, end, parallel);
            float bestCost = std::numeric_limits<float>::infinity();
            for (int a = 0; a < 3; ++a) {
                if (!(extent[a] > 0.0f)) continue;
                // Right-to-left sweep: area x count of the right side of each plane.
                std::array<float, kMaxBins> rightCost{};
                Box right;
                std::uint32_t rightCount = 0;
                for (std::uint32_t b = bins - 1; b > 0; --b) {
                    right.extend(binned.box[a][b]);
                    rightCount += binned.count[a][b];
                    rightCost[b] = right.halfArea() * static_cast<float>(rightCount);
                }
                Box left;
                std::uint32_t leftCount = 0;
                for (std::uint32_t b = 1; b < bins; ++b) {
                    left.extend(binned.box[a][b - 1]);
                    leftCount += binned.count[a][b - 1];
                    if (leftCount == 0 || leftCount == end - begin) continue;
                    const float cost = left.halfArea() * static_cast<float>(leftCount) + rightCost[b];
                    if (cost < bestCost) {
                        bestCost = cost;
                        bestAxis = a;
                        bestBin = b;
                    }
                }
            }
        }
        if (bestAxis >= 0) {
            const auto first = items_.begin() + begin;
            const auto middle = std::partition(first, items_.begin() + end, [&](const Item& item) {
                return mapping.bin(item.center, bestAxis) < bestBin;
            });
            return begin + static_cast<std::uint32_t>(middle - first);
        }
        // Object median along the widest centroid extent (any axis when all are flat).
        int axis = 0;
        if (extent.y > extent[axis]) axis = 1;
        if (extent.z > extent[axis]) axis = 2;
        const std::uint32_t mid = begin + (end - begin) / 2;
        std::nth_element(items_.begin() + begin, items_.begin() + mid, items_.begin() + end,
                         [axis](const Item& x, const Item& y) {
                             return x.center[axis] < y.center[axis] ||
                                    (x.center[axis] == y.center[axis] && x.id < y.id);
                         });
        return mid;
    }

    Bins binsOf(const BinMapping& mapping, std::uint32_t begin, std::uint32_t end, bool parallel) const {
        const auto scan = [&](Bins& acc, jobs::IndexRange r) {
            for (std::size_t i = r.begin; i != r.end; ++i) {
                const Item& item = items_[begin + i];
                Vec3 l, h;
                sphereBox(item, &l, &h);
                for (int a = 0; a < 3; ++a) {
                    const std::uint32_t b = mapping.bin(item.center, a);
                    acc.box[a][b].extend(l, h);
                    ++acc.count[a][b];
                }
            }
        };
        const std::size_t n = end - begin;
        if (!parallel) {
            Bins acc;
            scan(acc, {0, n});
            return acc;
        }
        return jobs::deterministicReduce<Bins>(
            n, (n + kBlock - 1) / kBlock, [] { return Bins{}; }, scan,
            [&](Bins& total, const Bins& part) { total.merge(part, mapping.bins); });
    }

    std::vector<Item>& items_;
    const PhotonBvhBuildOptions& options_;
};

// Depth-first placement of the tree: every node gets its final index; the
// serial subtrees are only recorded with their offsets, to be copied in parallel.
struct Placement {
    const BuildTree* tree;
    std::size_t offset;
};

void place(const BuildTree& tree, std::size_t offset, std::vector<Node>& top, std::vector<std::size_t>& topIndex,
           std::vector<Placement>& serial) {
    if (!tree.serial.empty()) {
        serial.push_back({&tree, offset});
        return;
    }
    Node node = tree.self;
    node.link = static_cast<std::uint32_t>(offset + 1 + tree.left->size);
    top.push_back(node);
    topIndex.push_back(offset);
    place(*tree.left, offset + 1, top, topIndex, serial);
    place(*tree.right, offset + 1 + tree.left->size, top, topIndex, serial);
}

}  // namespace

void PhotonBvh::build(std::span<const Vec3> centers, std::span<const float> radii, const BuildOptions& options) {
    if (centers.size() != radii.size())
        throw std::invalid_argument("PhotonBvh: " + std::to_string(centers.size()) + " centres but " +
                                    std::to_string(radii.size()) + " radii");
    if (centers.size() > static_cast<std::size_t>(std::numeric_limits<std::int32_t>::max()))
        throw std::invalid_argument("PhotonBvh: too many spheres");
    const std::size_t n = centers.size();
    std::vector<Item> items(n);
    std::atomic<bool> bad{false};
    jobs::parallelForChunks(n, kBlock, [&](jobs::IndexRange r) {
        for (std::size_t i = r.begin; i != r.end; ++i) {
            const Vec3& c = centers[i];
            const float radius = radii[i];
            if (!std::isfinite(c.x) || !std::isfinite(c.y) || !std::isfinite(c.z) || !std::isfinite(radius) ||
                radius < 0.0f)
                bad = true;
            items[i] = Item{c, radius, static_cast<std::uint32_t>(i)};
        }
    });
    if (bad) throw std::invalid_argument("PhotonBvh: a centre or radius is not finite, or a radius is negative");

    nodes_.clear();
    spheres_.clear();
    depth_ = 0;
    if (n == 0) return;

    PhotonBvhBuildOptions checked = options;
    checked.maxLeafSize = std::clamp<std::uint32_t>(options.maxLeafSize, 1, kMaxLeafSize);
    checked.parallelThreshold = std::max<std::size_t>(checked.parallelThreshold, 2 * std::size_t(checked.maxLeafSize) + 2);
    const Builder builder(items, checked);
    const std::unique_ptr<BuildTree> tree = builder.build(0, static_cast<std::uint32_t>(n), 0);
    depth_ = tree->depth;

    std::vector<Node> top;
    std::vector<std::size_t> topIndex;
    std::vector<Placement> serial;
    place(*tree, 0, top, topIndex, serial);

    nodes_.resize(tree->size);
    const auto lo = nodes_.column<BvhNodeLo>();
    const auto hi = nodes_.column<BvhNodeHi>();
    const auto link = nodes_.column<BvhNodeLink>();
    const auto count = nodes_.column<BvhNodeCount>();
    const auto write = [&](std::size_t at, const Node& node) {
        lo[at] = node.lo;
        hi[at] = node.hi;
        link[at] = node.link;
        count[at] = node.count;
    };
    for (std::size_t i = 0; i < top.size(); ++i) write(topIndex[i], top[i]);
    jobs::parallelForChunks(serial.size(), 1, [&](jobs::IndexRange r) {
        for (std::size_t s = r.begin; s != r.end; ++s) {
            const std::size_t offset = serial[s].offset;
            for (std::size_t k = 0; k < serial[s].tree->serial.size(); ++k) {
                Node node = serial[s].tree->serial[k];
                if (node.count == 0) node.link += static_cast<std::uint32_t>(offset);
                write(offset + k, node);
            }
        }
    });

    spheres_.resize(n);
    const auto x = spheres_.column<BvhSphereX>();
    const auto y = spheres_.column<BvhSphereY>();
    const auto z = spheres_.column<BvhSphereZ>();
    const auto radius = spheres_.column<BvhSphereRadius>();
    const auto id = spheres_.column<BvhSphereId>();
    jobs::parallelForChunks(n, kBlock, [&](jobs::IndexRange r) {
        for (std::size_t i = r.begin; i != r.end; ++i) {
            x[i] = items[i].center.x;
            y[i] = items[i].center.y;
            z[i] = items[i].center.z;
            radius[i] = items[i].radius;
            id[i] = items[i].id;
        }
    });
}

PhotonBvh PhotonBvh::restore(BvhNodeBuffer nodes, BvhSphereBuffer spheres, std::uint32_t depth) {
    const std::size_t nodeCount = nodes.size();
    const std::size_t sphereCount = spheres.size();
    if (sphereCount > static_cast<std::size_t>(std::numeric_limits<std::int32_t>::max()))
        throw std::invalid_argument("PhotonBvh: too many spheres");
    if ((nodeCount == 0) != (sphereCount == 0))
        throw std::invalid_argument("PhotonBvh: " + std::to_string(nodeCount) + " nodes for " +
                                    std::to_string(sphereCount) + " spheres");
    if (nodeCount > 2 * sphereCount)
        throw std::invalid_argument("PhotonBvh: more nodes than a tree over the spheres can have");
    const auto link = nodes.column<BvhNodeLink>();
    const auto count = nodes.column<BvhNodeCount>();
    // Walks the tree as a query would, so that a structure that passes cannot
    // make a query read outside the arrays, loop, or overflow its stack.
    std::uint32_t deepest = 0;
    if (nodeCount > 0) {
        std::vector<bool> reached(nodeCount, false);
        std::size_t reachedCount = 0;
        struct Pending {
            std::size_t node;
            std::uint32_t level;
        };
        std::vector<Pending> pending{{0, 1}};
        while (!pending.empty()) {
            const Pending at = pending.back();
            pending.pop_back();
            if (reached[at.node]) throw std::invalid_argument("PhotonBvh: a node is reached twice");
            reached[at.node] = true;
            ++reachedCount;
            deepest = std::max(deepest, at.level);
            if (at.level > static_cast<std::uint32_t>(kStackSize))
                throw std::invalid_argument("PhotonBvh: deeper than a query's stack");
            const std::uint32_t n = count[at.node];
            if (n > 0) {
                if (n > kMaxLeafSize || link[at.node] > sphereCount || n > sphereCount - link[at.node])
                    throw std::invalid_argument("PhotonBvh: a leaf's spheres are out of range");
                continue;
            }
            const std::size_t first = at.node + 1, second = link[at.node];
            if (first >= nodeCount || second <= first || second >= nodeCount)
                throw std::invalid_argument("PhotonBvh: an inner node's children are out of order or range");
            pending.push_back({second, at.level + 1});
            pending.push_back({first, at.level + 1});
        }
        if (reachedCount != nodeCount) throw std::invalid_argument("PhotonBvh: nodes outside the tree");
    }
    if (depth != deepest)
        throw std::invalid_argument("PhotonBvh: depth " + std::to_string(depth) + ", but the tree has " +
                                    std::to_string(deepest) + " levels");
    PhotonBvh bvh;
    bvh.nodes_ = std::move(nodes);
    bvh.spheres_ = std::move(spheres);
    bvh.depth_ = depth;
    return bvh;
}

}  // namespace fg
