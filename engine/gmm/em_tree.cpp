// The statistics kd-tree of accelerated EM (Jakob et al. 2011 §5.1-5.2); see em_tree.h.
#include "engine/gmm/em_tree.h"

#include "jobs/parallel.h"

#include <algorithm>
#include <numeric>
#include <queue>
#include <stdexcept>

namespace fg {

namespace {

constexpr std::size_t kBinGrain = 4096;

EmStatistics statisticsOf(std::span<const std::uint32_t> members, std::span<const Vec3> positions,
                          std::span<const Rgb> power, double powerScale) {
    EmStatistics s;
    s.count = members.size();
    if (members.empty()) return s;
    // Two passes: mean first, then the scatter about it.
    glm::dvec3 sum(0.0), powerSum(0.0);
    for (const std::uint32_t i : members) {
        sum += glm::dvec3(positions[i]);
        powerSum += glm::dvec3(power[i]);
    }
    s.mean = sum / static_cast<double>(members.size());
    s.power = powerSum * powerScale;
    for (const std::uint32_t i : members) s.scatter += gmm::Sym3::outer(glm::dvec3(positions[i]) - s.mean);
    return s;
}

}  // namespace

void EmStatistics::merge(const EmStatistics& other) {
    if (other.count == 0) return;
    if (count == 0) {
        *this = other;
        return;
    }
    const double na = static_cast<double>(count), nb = static_cast<double>(other.count);
    const double n = na + nb;
    const glm::dvec3 delta = other.mean - mean;
    mean += delta * (nb / n);
    scatter += other.scatter;
    scatter += gmm::Sym3::outer(delta) * (na * nb / n);
    power += other.power;
    count += other.count;
}

EmStatistics EmTree::statistics(std::uint32_t node) const {
    EmStatistics s;
    s.count = nodes.column<EmNodeCount>()[node];
    s.mean = nodes.column<EmNodeMean>()[node];
    s.scatter = nodes.column<EmNodeScatter>()[node];
    s.power = nodes.column<EmNodePower>()[node];
    return s;
}

void EmTree::build(std::span<const Vec3> positions, std::span<const Rgb> power, std::uint32_t maxLeafSize) {
    if (positions.size() != power.size()) throw std::invalid_argument("EmTree: positions and powers differ in count");
    if (positions.size() >= std::numeric_limits<std::uint32_t>::max())
        throw std::invalid_argument("EmTree: too many photons");
    leafSize = std::max<std::uint32_t>(1, maxLeafSize);
    batches = 0;
    nodes.clear();
    std::vector<std::uint32_t> order(positions.size());
    std::iota(order.begin(), order.end(), 0u);
    if (positions.empty()) return;
    // At most 2 n / leafSize + 1 nodes for median splits.
    std::vector<EmTreeBuffer::Record> records;
    records.reserve(2 * positions.size() / leafSize + 2);

    // Iterative depth-first build with an explicit stack: (node, begin, end).
    struct Pending {
        std::uint32_t parent;  // whose `right` this node is, or kNoParent for the root / a left child
        std::size_t begin, end;
    };
    constexpr std::uint32_t kNoParent = std::numeric_limits<std::uint32_t>::max();
    std::vector<Pending> stack{{kNoParent, 0, positions.size()}};
    std::vector<std::uint32_t> postOrderInner;
    while (!stack.empty()) {
        const Pending p = stack.back();
        stack.pop_back();
        const auto index = static_cast<std::uint32_t>(records.size());
        if (p.parent != kNoParent) records[p.parent].get<EmNodeRight>() = index;
        EmTreeBuffer::Record record;
        Vec3 lo(std::numeric_limits<float>::max()), hi(-std::numeric_limits<float>::max());
        for (std::size_t i = p.begin; i < p.end; ++i) {
            lo = glm::min(lo, positions[order[i]]);
            hi = glm::max(hi, positions[order[i]]);
        }
        record.get<EmNodeLo>() = lo;
        record.get<EmNodeHi>() = hi;
        record.get<EmNodeRight>() = kNoParent;
        const std::size_t count = p.end - p.begin;
        const Vec3 extent = hi - lo;
        const int axis = extent.x >= extent.y && extent.x >= extent.z ? 0 : (extent.y >= extent.z ? 1 : 2);
        if (count <= leafSize || !(extent[axis] > 0.0f)) {
            const EmStatistics s =
                statisticsOf(std::span(order).subspan(p.begin, count), positions, power, 1.0);
            record.get<EmNodeCount>() = s.count;
            record.get<EmNodeMean>() = s.mean;
            record.get<EmNodeScatter>() = s.scatter;
            record.get<EmNodePower>() = s.power;
            record.get<EmNodeSplit>() = EmSplit{};
            records.push_back(record);
            continue;
        }
        const std::size_t mid = p.begin + count / 2;
        const auto less = [&](std::uint32_t a, std::uint32_t b) {
            const float xa = positions[a][axis], xb = positions[b][axis];
            return xa < xb || (xa == xb && a < b);
        };
        std::nth_element(order.begin() + static_cast<std::ptrdiff_t>(p.begin),
                         order.begin() + static_cast<std::ptrdiff_t>(mid),
                         order.begin() + static_cast<std::ptrdiff_t>(p.end), less);
        const float value = positions[order[mid]][axis];
        // Photons equal to the split value may lie on both sides of the median;
        // later photons equal to it go right. Either way each node's statistics
        // are exact for the photons it was given.
        record.get<EmNodeSplit>() = EmSplit{value, static_cast<std::uint8_t>(axis)};
        records.push_back(record);
        postOrderInner.push_back(index);
        stack.push_back({index, mid, p.end});          // right, popped after the left subtree
        stack.push_back({kNoParent, p.begin, mid});    // left child: index + 1
    }
    // Inner statistics from the children, deepest first (children have larger indices).
    for (auto it = postOrderInner.rbegin(); it != postOrderInner.rend(); ++it) {
        const std::uint32_t node = *it;
        const auto fromRecord = [&](std::uint32_t i) {
            EmStatistics s;
            s.count = records[i].get<EmNodeCount>();
            s.mean = records[i].get<EmNodeMean>();
            s.scatter = records[i].get<EmNodeScatter>();
            s.power = records[i].get<EmNodePower>();
            return s;
        };
        EmStatistics s = fromRecord(node + 1);
        s.merge(fromRecord(records[node].get<EmNodeRight>()));
        records[node].get<EmNodeCount>() = s.count;
        records[node].get<EmNodeMean>() = s.mean;
        records[node].get<EmNodeScatter>() = s.scatter;
        records[node].get<EmNodePower>() = s.power;
    }
    nodes.append(records);
}

std::uint32_t EmTree::leafOf(const Vec3& x) const {
    const auto splits = nodes.column<EmNodeSplit>();
    const auto rights = nodes.column<EmNodeRight>();
    std::uint32_t node = 0;
    while (splits[node].axis != kEmLeaf) node = x[splits[node].axis] < splits[node].value ? node + 1 : rights[node];
    return node;
}

void EmTree::update(std::span<const Vec3> positions, std::span<const Rgb> power, double powerScale) {
    if (positions.size() != power.size()) throw std::invalid_argument("EmTree: positions and powers differ in count");
    if (nodes.empty() || positions.empty()) return;
    const std::size_t n = positions.size();
    std::vector<std::uint32_t> leaf(n);
    jobs::parallelFor(n, kBinGrain, [&](std::size_t i) { leaf[i] = leafOf(positions[i]); });
    // Counting sort by leaf, stable: each leaf's photons in batch order.
    const std::size_t nodeCount = nodes.size();
    std::vector<std::uint32_t> start(nodeCount + 1, 0);
    for (const std::uint32_t l : leaf) ++start[l + 1];
    std::partial_sum(start.begin(), start.end(), start.begin());
    std::vector<std::uint32_t> members(n);
    {
        std::vector<std::uint32_t> cursor(start.begin(), start.end() - 1);
        for (std::size_t i = 0; i < n; ++i) members[cursor[leaf[i]]++] = static_cast<std::uint32_t>(i);
    }
    std::vector<EmStatistics> batch(nodeCount);
    const auto splits = nodes.column<EmNodeSplit>();
    jobs::parallelFor(nodeCount, 256, [&](std::size_t node) {
        if (splits[node].axis != kEmLeaf) return;
        batch[node] = statisticsOf(std::span(members).subspan(start[node], start[node + 1] - start[node]),
                                   positions, power, powerScale);
    });
    const auto rights = nodes.column<EmNodeRight>();
    for (std::size_t node = nodeCount; node-- > 0;) {
        if (splits[node].axis == kEmLeaf) continue;
        batch[node] = batch[node + 1];
        batch[node].merge(batch[rights[node]]);
    }
    // Boxes grow to hold the new photons.
    std::vector<Vec3> leafLo(nodeCount, Vec3(std::numeric_limits<float>::max())),
        leafHi(nodeCount, Vec3(-std::numeric_limits<float>::max()));
    for (std::size_t i = 0; i < n; ++i) {
        leafLo[leaf[i]] = glm::min(leafLo[leaf[i]], positions[i]);
        leafHi[leaf[i]] = glm::max(leafHi[leaf[i]], positions[i]);
    }
    auto lo = nodes.column<EmNodeLo>();
    auto hi = nodes.column<EmNodeHi>();
    for (std::size_t node = nodeCount; node-- > 0;) {
        if (splits[node].axis != kEmLeaf) {
            leafLo[node] = glm::min(leafLo[node + 1], leafLo[rights[node]]);
            leafHi[node] = glm::max(leafHi[node + 1], leafHi[rights[node]]);
        }
        lo[node] = glm::min(lo[node], leafLo[node]);
        hi[node] = glm::max(hi[node], leafHi[node]);
    }
    auto count = nodes.column<EmNodeCount>();
    auto mean = nodes.column<EmNodeMean>();
    auto scatter = nodes.column<EmNodeScatter>();
    auto powerSum = nodes.column<EmNodePower>();
    jobs::parallelFor(nodeCount, 1024, [&](std::size_t node) {
        EmStatistics s = statistics(static_cast<std::uint32_t>(node));
        s.merge(batch[node]);
        count[node] = s.count;
        mean[node] = s.mean;
        scatter[node] = s.scatter;
        powerSum[node] = s.power;
    });
    ++batches;
}

std::vector<std::uint32_t> EmTree::cut(std::size_t cells) const {
    if (nodes.empty()) return {};
    const auto count = nodes.column<EmNodeCount>();
    // Max-heap on (count, -index): the fullest node first, the smaller index on ties.
    const auto lower = [&](std::uint32_t a, std::uint32_t b) {
        return count[a] < count[b] || (count[a] == count[b] && a > b);
    };
    std::priority_queue<std::uint32_t, std::vector<std::uint32_t>, decltype(lower)> open(lower);
    std::vector<std::uint32_t> leaves;
    open.push(0);
    while (!open.empty() && open.size() + leaves.size() < cells) {
        const std::uint32_t node = open.top();
        open.pop();
        if (isLeaf(node)) {
            leaves.push_back(node);
            continue;
        }
        open.push(left(node));
        open.push(right(node));
    }
    while (!open.empty()) {
        leaves.push_back(open.top());
        open.pop();
    }
    std::sort(leaves.begin(), leaves.end());
    return leaves;
}

gmm::EmCells cellsOf(const EmTree& tree, std::span<const std::uint32_t> cut) {
    gmm::EmCells cells;
    for (const std::uint32_t node : cut) {
        const EmStatistics s = tree.statistics(node);
        if (s.count == 0) continue;
        const double n = static_cast<double>(s.count);
        cells.count.push_back(n);
        cells.mean.push_back(s.mean);
        cells.covariance.push_back(s.scatter * (1.0 / n));
        cells.power.push_back(s.power);
    }
    return cells;
}

}  // namespace fg
