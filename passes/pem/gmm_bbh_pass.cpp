// Gaussian bounding-box hierarchy pass (`gmm_bbh`): Jakob et al. 2011 §7.1.
// Each pyramid node's Gaussian is truncated to the ellipsoid of Mahalanobis
// radius r_j outside which its energy is at most delta W / k (W: the total
// power, k: the leaves; the paper leaves delta unstated, 1e-3 by default):
// Phi_j P(chi_3 > r_j) = delta W / k, with P(chi_3 > r) = erfc(r / sqrt 2) +
// sqrt(2 / pi) r e^{-r^2 / 2}, powers compared by their channel sums. The
// ellipsoid's box has half extents r_j sqrt(Sigma_ii). A first sweep sets
// every node's own box, a second (leaves up) unites each with its children's,
// so a node's box holds its whole subtree; the bounding sphere is the box's.
// r_j is kept per node, so that a renderer can test a ray against the
// ellipsoid itself.
#include "passes/passes.h"

#include "passes/pem/pem_common.h"
#include "jobs/parallel.h"

#include <cmath>

namespace fg {

namespace {

class GmmBbhPass final : public Pass {
public:
    void run(PassContext& ctx) override {
        const GmmPyramid& pyramid = ctx.input<GmmPyramid>("pyramid");
        const GmmPyramidBuffer& nodes = pyramid.nodes;
        const double delta = ctx.params().getFloat("delta");
        const std::size_t n = nodes.size();
        GmmBbh& bbh = ctx.createOutput<GmmBbh>("bbh");
        bbh.truncation = delta;
        bbh.nodes.resize(n);
        if (n == 0) return;
        const double total = energy(nodes.column<GmmPower>()[0]);
        const std::size_t leaves = (n + 1) / 2;
        const double allowed = delta * total / static_cast<double>(leaves);
        auto lo = bbh.nodes.column<BbhLo>();
        auto hi = bbh.nodes.column<BbhHi>();
        auto radius = bbh.nodes.column<BbhRadius>();
        jobs::parallelFor(n, 256, [&](std::size_t j) {
            const double e = energy(nodes.column<GmmPower>()[j]);
            const double r = e > 0.0 ? gmm::truncationRadius(allowed / e) : 0.0;
            radius[j] = r;
            const glm::dvec3 mean = nodes.column<GmmMean>()[j];
            const gmm::Sym3& sigma = nodes.column<GmmCovariance>()[j];
            const glm::dvec3 half(r * std::sqrt(sigma.v[0]), r * std::sqrt(sigma.v[3]), r * std::sqrt(sigma.v[5]));
            lo[j] = Vec3(mean - half);
            hi[j] = Vec3(mean + half);
        });
        // Children follow their parents depth first: leaves-up is reverse order.
        const auto right = nodes.column<GmmRight>();
        for (std::size_t j = n; j-- > 0;) {
            if (right[j] == kNoGmmNode) continue;
            lo[j] = glm::min(lo[j], glm::min(lo[j + 1], lo[right[j]]));
            hi[j] = glm::max(hi[j], glm::max(hi[j + 1], hi[right[j]]));
        }
        auto sphere = bbh.nodes.column<BbhSphere>();
        for (std::size_t j = 0; j < n; ++j) sphere[j] = Vec4(0.5f * (lo[j] + hi[j]), 0.5f * glm::length(hi[j] - lo[j]));
        ctx.addItems(static_cast<std::int64_t>(n));
    }
};

}  // namespace

PassRegistration gmmBbhPass() {
    PassSpec spec;
    spec.name = "gmm_bbh";
    spec.doc = "Bounding boxes of a Gaussian pyramid's truncated ellipsoids, united up the tree, with bounding spheres "
               "(Jakob et al. 2011 §7.1)";
    spec.inputs = {{"pyramid", "GmmPyramid", "the Gaussian pyramid (gmm_pyramid)"}};
    spec.outputs = {{"bbh", "GmmBbh", "per node box and sphere, same order as the pyramid"}};
    spec.params = {
        {"delta", ParamType::Float, 1e-3, 0.0, 1.0, {},
         "truncation: energy outside each node's ellipsoid <= delta W / k (W total power, k leaves)"},
    };
    return {spec, [] { return std::make_unique<GmmBbhPass>(); }};
}

}  // namespace fg
