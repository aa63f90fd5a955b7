// Gaussian pyramid pass (`gmm_pyramid`): Jakob et al. 2011 §6, Alg. 3 — the
// level-of-detail tree over a fitted mixture. Each level pairs the current
// nodes greedily by the dissimilarity of Eq. 11,
//   d(j1, j2) = w_j1 w_j2 min(D_KL(j1 || j2), D_KL(j2 || j1))
// (closed-form KL of Gaussians), smallest first from a heap (Walter et al.
// 2008's agglomeration), and merges each pair by Eqs. 12-14 (moment matching
// on the weights w, so every level keeps the mixture's weight, mean and second
// moment sum w (Sigma + mu mu^T)); powers and n_eff are added. An odd node is
// carried up unmerged. Nearest partners are found by brute force over the
// level (parallel, each node's search independent of the others); ties go to
// the smaller index. Nodes are stored depth first from the root (gmm_buffers.h).
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
        while (current.size() > 1) {
            ++level;
            const std::size_t m = current.size();
            std::vector<bool> merged(m, false);
            // Nearest unmerged partner of position i within the level.
            const auto nearest = [&](std::size_t i) {
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
            std::vector<std::pair<double, std::size_t>> first(m);
            jobs::parallelFor(m, 16, [&](std::size_t i) { first[i] = nearest(i); });
            evaluations += static_cast<std::int64_t>(m * (m - 1));
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
                    const auto [best, partner] = nearest(i);
                    evaluations += static_cast<std::int64_t>(m);
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
    return {spec, [] { return std::make_unique<GmmPyramidPass>(); }};
}

}  // namespace fg
