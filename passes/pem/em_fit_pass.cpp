// Accelerated EM pass (`em_fit`): Jakob et al. 2011 Alg. 1 (§3.6) on one fixed
// cut of the statistics tree, with the sparsity of §5.3 — the ablation of
// progressive EM (no further photons, no cut refinement). The E-step is Eq. 7
// with its bracket restored, the M-step Eq. 9 in centred form, F Eq. 8
// (= sum_A n_A log Z_A), n_eff Eq. 10 (engine/gmm/em.h). The initial guess is
// §5.4's: the Gaussians of a k-cell cut's own statistics. EM fits the photon
// count density, as the paper does; each component's power is
// Phi_s = sum_A q_A(s) Phi_A, so the mixture's power equals the photons' and
// colour and Russian-roulette weights survive the fit.
#include "passes/passes.h"

#include "passes/pem/pem_common.h"
#include "jobs/work_context.h"

#include <algorithm>

namespace fg {

namespace {

class EmFitPass final : public Pass {
public:
    void run(PassContext& ctx) override {
        const EmTree& tree = ctx.input<EmTree>("tree");
        const PassParams& params = ctx.params();
        const auto k = static_cast<std::size_t>(params.getInt("k"));
        const auto cellsPerComponent = static_cast<std::size_t>(params.getInt("cut"));
        gmm::EmOptions options;
        options.tau = params.getFloat("tau");
        options.epsilon = params.getFloat("epsilon");
        options.maxIterations = static_cast<int>(params.getInt("max_iterations"));
        options.regCovar = ridgeInSceneUnits(tree, params.getFloat("reg_covar"));
        options.minEffectiveCount = params.getFloat("min_n_eff");

        GaussianMixture& mixture = ctx.createOutput<GaussianMixture>("gmm");
        if (tree.nodes.empty()) return;
        const std::int64_t start = jobs::wallNanos();
        std::vector<gmm::EmComponent> components =
            gmm::componentsFromCells(cellsOf(tree, tree.cut(k)), options.regCovar);
        const gmm::EmCells cells = cellsOf(tree, tree.cut(k * cellsPerComponent));
        const gmm::EmRun run = gmm::runEm(cells, components, options);
        storeMixture(components, tree.statistics(0).count, mixture);
        ctx.addItems(static_cast<std::int64_t>(cells.size()));
        ctx.addCounter("cells", static_cast<std::int64_t>(cells.size()));
        ctx.addCounter("iterations", run.iterations);
        ctx.addCounter("converged", run.converged ? 1 : 0);
        ctx.addCounter("fit_us", (jobs::wallNanos() - start) / 1000);
        reportFit(ctx, run, components, cells.totalCount());
    }
};

}  // namespace

PassRegistration emFitPass() {
    PassSpec spec;
    spec.name = "em_fit";
    spec.doc = "Accelerated EM (Jakob et al. 2011 Alg. 1, sparse as §5.3) of a k-term Gaussian mixture on a fixed cut "
               "of the statistics tree; powers follow the responsibilities";
    spec.inputs = {{"tree", "EmTree", "statistics kd-tree (em_stats)"}};
    spec.outputs = {{"gmm", "GaussianMixture",
                     "the fitted mixture: weight, power, mean, covariance and factors, n_eff (parameters rounded "
                     "to the floats it is saved in)"}};
    spec.params = {
        {"k", ParamType::Int, std::int64_t{4096}, 1, 1 << 22, {}, "Gaussian components (initial guess: a k-cell cut)"},
        {"cut", ParamType::Int, std::int64_t{8}, 1, 1 << 10, {},
         "cells of the fixed cut per component (the paper's initial cut: 8)"},
        {"tau", ParamType::Float, 1e-4, 0.0, 1.0, {},
         "sparsity: pruned responsibility mass per cell <= tau Z_A (0: all cell-component pairs)"},
        {"epsilon", ParamType::Float, 1e-4, 0.0, 1.0, {}, "converged when F/n changes by less than this (relative)"},
        {"max_iterations", ParamType::Int, std::int64_t{100}, 1, 100000, {}, "most EM iterations"},
        {"reg_covar", ParamType::Float, 1e-6, 0.0, 1.0, {},
         "ridge added to covariance diagonals, in unit-box coordinates (the photons' longest side = 1)"},
        {"min_n_eff", ParamType::Float, 1.0, 0.0, 1e12, {}, "components explaining fewer photons are dropped"},
    };
    return {spec, [] { return std::make_unique<EmFitPass>(); }, refuseAnisotropicMedia};
}

}  // namespace fg
