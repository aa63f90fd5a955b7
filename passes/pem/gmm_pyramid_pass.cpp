// Gaussian pyramid pass (`gmm_pyramid`): Jakob et al. 2011 §6, Alg. 3 — the
// level-of-detail tree over a fitted mixture. Each level pairs the current
// nodes greedily by the dissimilarity of Eq. 11,
//   d(j1, j2) = w_j1 w_j2 min(D_KL(j1 || j2), D_KL(j2 || j1))
// (closed-form KL of Gaussians), smallest first from a heap (Walter et al.
// 2008's agglomeration), and merges each pair by Eqs. 12-14 (moment matching
// on the weights w, so every level keeps the mixture's weight, mean and second
// moment sum w (Sigma + mu mu^T)); powers and n_eff are added. An odd node is
// carried up unmerged. Nearest partners are found through a kd-tree over the
// level's means (parallel, each node's search independent of the others),
// pruned by a lower bound on Eq. 11: with Δμ the mean difference,
//   D_KL(a || b) = 1/2 [tr(Σ_b^-1 Σ_a) - 3 + log(|Σ_b| / |Σ_a|)] + 1/2 Δμ^T Σ_b^-1 Δμ >= |Δμ|^2 / (2 λ_max(Σ_b))
// (the bracket is the KL of the zero-mean Gaussians, >= 0), so
//   d(i, j) >= w_i min_j w_j dist(μ_i, box)^2 / (2 max(λ_max(Σ_i), max_j λ_max(Σ_j)))
// over a subtree. A subtree is skipped only when its bound exceeds the best d
// found, and equal d go to the smaller index, so the partners are those of
// the brute-force search (pairing = "brute", tested equal). Nodes are stored
// depth first from the root (gmm_buffers.h).
#include "passes/passes.h"

#include "passes/pem/pem_common.h"
#include "jobs/parallel.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <queue>
#include <tuple>

namespace fg {

namespace {

struct Node {
    double weight = 0.0;
    glm::dvec3 power{0.0};
    gmm::Gaussian gaussian;
    double effectiveCount = 0.0;
    std::uint32_t left = kNoGmmNode, right = kNoGmmNode, level = 0;
};

double dissimilarity(const Node& a, const Node& b) {
    return a.weight * b.weight * std::min(gmm::klDivergence(a.gaussian, b.gaussian), gmm::klDivergence(b.gaussian, a.gaussian));
}

constexpr std::size_t kMeanLeafSize = 8;

// A kd-tree over the means of one level's nodes (positions 0..m-1 of the level).
class MeanTree {
public:
    MeanTree(const std::vector<Node>& nodes, const std::vector<std::uint32_t>& current) : nodes_(nodes), current_(current) {
        const std::size_t m = current.size();
        order_.resize(m);
        for (std::size_t i = 0; i < m; ++i) order_[i] = static_cast<std::uint32_t>(i);
        lambda_.resize(m);
        for (std::size_t i = 0; i < m; ++i) lambda_[i] = nodes[current[i]].gaussian.covariance.largestEigenvalue();
        if (m > 0) build(0, m);
    }

    // Nearest unmerged partner of position i (d, partner), partner = m if none.
    std::pair<double, std::size_t> nearest(std::size_t i, const std::vector<bool>& merged, std::int64_t& evaluations) const {
        Search search{i, merged, std::numeric_limits<double>::infinity(), current_.size(), evaluations};
        if (!tree_.empty()) visit(0, search);
        return {search.best, search.partner};
    }

private:
    struct TreeNode {
        glm::dvec3 lo, hi;
        double minWeight = 0.0, maxLambda = 0.0;
        std::uint32_t begin = 0, end = 0, left = 0, right = 0;
        bool leaf = true;
    };
    struct Search {
        std::size_t i;
        const std::vector<bool>& merged;
        double best;
        std::size_t partner;
        std::int64_t& evaluations;
    };

    std::uint32_t build(std::size_t begin, std::size_t end) {
        const auto index = static_cast<std::uint32_t>(tree_.size());
        tree_.emplace_back();
        TreeNode t;
        t.begin = static_cast<std::uint32_t>(begin);
        t.end = static_cast<std::uint32_t>(end);
        t.lo = glm::dvec3(std::numeric_limits<double>::max());
        t.hi = glm::dvec3(-std::numeric_limits<double>::max());
        t.minWeight = std::numeric_limits<double>::infinity();
        for (std::size_t k = begin; k < end; ++k) {
            const Node& n = nodes_[current_[order_[k]]];
            t.lo = glm::min(t.lo, n.gaussian.mean);
            t.hi = glm::max(t.hi, n.gaussian.mean);
            t.minWeight = std::min(t.minWeight, n.weight);
            t.maxLambda = std::max(t.maxLambda, lambda_[order_[k]]);
        }
        if (end - begin > kMeanLeafSize) {
            const glm::dvec3 extent = t.hi - t.lo;
            const int axis = extent.x >= extent.y && extent.x >= extent.z ? 0 : (extent.y >= extent.z ? 1 : 2);
            const std::size_t mid = begin + (end - begin) / 2;
            std::nth_element(order_.begin() + static_cast<std::ptrdiff_t>(begin),
                             order_.begin() + static_cast<std::ptrdiff_t>(mid),
                             order_.begin() + static_cast<std::ptrdiff_t>(end), [&](std::uint32_t a, std::uint32_t b) {
                                 const double xa = nodes_[current_[a]].gaussian.mean[axis];
                                 const double xb = nodes_[current_[b]].gaussian.mean[axis];
                                 return xa < xb || (xa == xb && a < b);
                             });
            t.leaf = false;
            t.left = build(begin, mid);
            t.right = build(mid, end);
        }
        tree_[index] = t;
        return index;
    }

    double lowerBound(std::uint32_t t, const Node& query, double queryLambda) const {
        const TreeNode& node = tree_[t];
        const glm::dvec3& m = query.gaussian.mean;
        const glm::dvec3 gap = glm::max(glm::dvec3(0.0), glm::max(node.lo - m, m - node.hi));
        return query.weight * node.minWeight * glm::dot(gap, gap) / (2.0 * std::max(queryLambda, node.maxLambda));
    }

    void visit(std::uint32_t t, Search& search) const {
        const TreeNode& node = tree_[t];
        if (node.leaf) {
            const Node& query = nodes_[current_[search.i]];
            for (std::uint32_t k = node.begin; k < node.end; ++k) {
                const std::size_t j = order_[k];
                if (j == search.i || search.merged[j]) continue;
                const double d = dissimilarity(query, nodes_[current_[j]]);
                ++search.evaluations;
                if (d < search.best || (d == search.best && j < search.partner)) {
                    search.best = d;
                    search.partner = j;
                }
            }
            return;
        }
        const Node& query = nodes_[current_[search.i]];
        const double lambda = lambda_[search.i];
        const double boundLeft = lowerBound(node.left, query, lambda);
        const double boundRight = lowerBound(node.right, query, lambda);
        const bool leftFirst = boundLeft <= boundRight;
        const std::uint32_t near = leftFirst ? node.left : node.right, far = leftFirst ? node.right : node.left;
        const double nearBound = leftFirst ? boundLeft : boundRight, farBound = leftFirst ? boundRight : boundLeft;
        // Strictly greater: a subtree that could hold an equal d with a smaller index is still searched.
        if (!(nearBound > search.best)) visit(near, search);
        if (!(farBound > search.best)) visit(far, search);
    }

    const std::vector<Node>& nodes_;
    const std::vector<std::uint32_t>& current_;
    std::vector<std::uint32_t> order_;
    std::vector<double> lambda_;
    std::vector<TreeNode> tree_;
};

class GmmPyramidPass final : public Pass {
public:
    void run(PassContext& ctx) override {
        const GaussianMixture& mixture = ctx.input<GaussianMixture>("gmm");
        const GmmBuffer& components = mixture.components;
        std::vector<Node> nodes(components.size());
        for (std::size_t s = 0; s < nodes.size(); ++s) {
            nodes[s].weight = components.column<GmmWeight>()[s];
            nodes[s].power = components.column<GmmPower>()[s];
            nodes[s].effectiveCount = components.column<GmmEffectiveCount>()[s];
            nodes[s].gaussian = gaussianAt(components, s);
        }
        std::vector<std::uint32_t> current(nodes.size());
        for (std::uint32_t s = 0; s < current.size(); ++s) current[s] = s;
        std::uint32_t level = 0;
        std::int64_t evaluations = 0;
        const bool brute = ctx.params().getString("pairing") == "brute";
        while (current.size() > 1) {
            ++level;
            const std::size_t m = current.size();
            std::vector<bool> merged(m, false);
            // Nearest unmerged partner of position i within the level, by brute force.
            const auto nearestBrute = [&](std::size_t i) {
                double best = std::numeric_limits<double>::infinity();
                std::size_t partner = m;
                for (std::size_t j = 0; j < m; ++j) {
                    if (j == i || merged[j]) continue;
                    const double d = dissimilarity(nodes[current[i]], nodes[current[j]]);
                    if (d < best) {
                        best = d;
                        partner = j;
                    }
                }
                return std::pair(best, partner);
            };
            const MeanTree tree(nodes, current);
            std::vector<std::int64_t> searched(m, 0);
            const auto nearest = [&](std::size_t i, std::int64_t& count) {
                if (brute) {
                    count += static_cast<std::int64_t>(m - 1);
                    return nearestBrute(i);
                }
                return tree.nearest(i, merged, count);
            };
            std::vector<std::pair<double, std::size_t>> first(m);
            jobs::parallelFor(m, 16, [&](std::size_t i) { first[i] = nearest(i, searched[i]); });
            for (const std::int64_t count : searched) evaluations += count;
            using Edge = std::tuple<double, std::size_t, std::size_t>;  // (d, i, partner): smallest first, then index
            std::priority_queue<Edge, std::vector<Edge>, std::greater<Edge>> heap;
            for (std::size_t i = 0; i < m; ++i)
                if (first[i].second < m) heap.push({first[i].first, i, first[i].second});
            std::vector<std::uint32_t> next;
            std::size_t unmerged = m;
            while (!heap.empty() && unmerged > 1) {
                const auto [d, i, j] = heap.top();
                heap.pop();
                if (merged[i]) continue;
                if (merged[j]) {
                    // The partner was taken: find the next nearest and try again later.
                    const auto [best, partner] = nearest(i, evaluations);
                    if (partner < m) heap.push({best, i, partner});
                    continue;
                }
                merged[i] = merged[j] = true;
                unmerged -= 2;
                const Node& a = nodes[current[std::min(i, j)]];
                const Node& b = nodes[current[std::max(i, j)]];
                const gmm::WeightedMoments moments =
                    gmm::merge({a.weight, a.gaussian.mean, a.gaussian.covariance}, {b.weight, b.gaussian.mean, b.gaussian.covariance});
                Node parent;
                parent.weight = moments.weight;
                parent.power = a.power + b.power;
                parent.effectiveCount = a.effectiveCount + b.effectiveCount;
                parent.gaussian = gmm::Gaussian(moments.mean, moments.covariance);
                parent.left = current[std::min(i, j)];
                parent.right = current[std::max(i, j)];
                parent.level = level;
                nodes.push_back(parent);
                next.push_back(static_cast<std::uint32_t>(nodes.size() - 1));
            }
            for (std::size_t i = 0; i < m; ++i)
                if (!merged[i]) next.push_back(current[i]);  // the odd one is carried up
            current = std::move(next);
        }

        GmmPyramid& pyramid = ctx.createOutput<GmmPyramid>("pyramid");
        pyramid.levels = level;
        if (nodes.empty()) return;
        // Depth first from the root: left child next, right child recorded.
        pyramid.nodes.resize(nodes.size());
        std::vector<std::pair<std::uint32_t, std::uint32_t>> stack{{current.front(), kNoGmmNode}};
        std::uint32_t slot = 0;
        while (!stack.empty()) {
            const auto [node, parentSlot] = stack.back();
            stack.pop_back();
            if (parentSlot != kNoGmmNode) pyramid.nodes.column<GmmRight>()[parentSlot] = slot;
            const Node& n = nodes[node];
            pyramid.nodes.column<GmmWeight>()[slot] = n.weight;
            pyramid.nodes.column<GmmPower>()[slot] = n.power;
            pyramid.nodes.column<GmmEffectiveCount>()[slot] = n.effectiveCount;
            pyramid.nodes.column<GmmLevel>()[slot] = n.level;
            pyramid.nodes.column<GmmRight>()[slot] = kNoGmmNode;
            setGaussianAt(pyramid.nodes, slot, n.gaussian);
            if (n.left != kNoGmmNode) {
                stack.push_back({n.right, slot});
                stack.push_back({n.left, kNoGmmNode});
            }
            ++slot;
        }
        ctx.addItems(static_cast<std::int64_t>(components.size()));
        ctx.addCounter("nodes", static_cast<std::int64_t>(nodes.size()));
        ctx.addCounter("levels", level);
        ctx.addCounter("kl_evaluations", evaluations);
    }
};

}  // namespace

PassRegistration gmmPyramidPass() {
    PassSpec spec;
    spec.name = "gmm_pyramid";
    spec.doc = "Level-of-detail pyramid of a Gaussian mixture (Jakob et al. 2011 Alg. 3): greedy pairing by Eq. 11, "
               "moment-matching merges (Eqs. 12-14), powers added";
    spec.inputs = {{"gmm", "GaussianMixture", "the fitted mixture (em_fit, pem_fit)"}};
    spec.outputs = {{"pyramid", "GmmPyramid", "2k - 1 nodes depth first; leaves are the components"}};
    spec.params = {
        {"pairing", ParamType::String, std::string("kdtree"), 0, 0, {"kdtree", "brute"},
         "nearest-partner search: kd-tree over the means with a lower bound on Eq. 11, or all pairs (same pyramid)"},
    };
    return {spec, [] { return std::make_unique<GmmPyramidPass>(); }};
}

}  // namespace fg
