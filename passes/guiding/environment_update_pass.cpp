// Environment sampler update (`environment_update`), Vorba et al. 2014 §4.4
// (Fig. 6a) and §4.1 (Fig. 2d: it runs with the importance distributions
// update): the importons that left the scene in this training pass refine
// the model guided environment emission draws photons from
// (engine/guiding/environment_guide.h), carried from pass to pass like the
// caches.
//
// - p_W(ω): every bitmap cell adds this pass's kernel density estimate at its
//   centre, Σ_i w_i K_r(ω_c·ω_i), K_r(μ) = max(0, μ − cos r) / (π (1 − cos r)²);
//   then the kernel's cap shrinks as a progressive photon mapping disc does,
//   (1 − cos r) <- (1 − cos r)(t + α)/(t + 1) after pass t (§4.4 cites
//   Hachisuka et al. 2008 for the progressive estimate without details; the
//   kernel, its first radius and the schedule are chosen here).
// - p(x|ω): each cell's GMM on the unit square (the disk by the concentric
//   map) is fitted by off-line stepwise EM (Eqs. 7-10, n = min(i, N)) the
//   first time at least min_disk_particles importons fall into its window,
//   and continued by on-line stepwise EM (n = i) in later passes, as cache
//   records are (§4.2). Each importon's disk point is the line it left along,
//   projected onto the disk perpendicular to its own direction, in the frame
//   the photon pass emits with (EnvironmentGuide::diskFrame).
//
// The window. The paper trains p(x|ω) on importons that left within 1° of ω.
// A 1° cap is 1/13000 of the sphere, so at the particle counts a training pass
// has here (tens of thousands of camera paths, a few per cent of them leaving
// through an opening) most cells would see no importon at all. The window is
// instead a cap around the cell's centre, disk_window_degrees (default 10°,
// twice a default cell's size: 32 x 16 cells of 0.025 sr, a cap of radius
// 5.1°), so that the GMM describes the lines of the directions the cell's
// photons are drawn from, and enough importons fall into it (in a box of
// side 2 whose only opening is a 0.3 square, 4096 camera paths left 81
// importons in a pass, and no cell's 6° window held 16 of them). Photons emitted in a cell use its GMM for any
// direction within it; importons from a few degrees away shift the learnt
// lines by about their distance from the scene's centre times the angle,
// which only widens the fitted lobes. The mixture with the uniform disk keeps
// the emission unbiased whatever the GMM.
//
// Only importons that scattered at least once train the model (§4.1: paths
// straight from the camera to the sky meet no surface a photon could be
// stored on). Without an environment emitter (a non-delta infinite light)
// the pass makes the empty model, with which photons are emitted as without
// one. Cells are independent and each reads the importons in their stored
// order, so the model is the same for any thread count.
#include "passes/passes.h"

#include "engine/core/error.h"
#include "engine/guiding/environment_guide.h"
#include "engine/guiding/importons.h"
#include "engine/scene/scene.h"
#include "jobs/parallel.h"

#include <algorithm>
#include <cmath>
#include <vector>

namespace fg {

namespace {

class EnvironmentUpdatePass final : public Pass {
public:
    void run(PassContext& ctx) override {
        const Scene& scene = ctx.scene();
        const PassParams& params = ctx.params();
        EnvironmentGuide& guide = ctx.createOutput<EnvironmentGuide>("environment");
        if (!hasEnvironmentEmitter(scene)) return;

        if (ctx.hasInput("previous") && ctx.input<EnvironmentGuide>("previous").cellCount() > 0) {
            const EnvironmentGuide& previous = ctx.input<EnvironmentGuide>("previous");
            guide.columns = previous.columns;
            guide.rows = previous.rows;
            guide.center = previous.center;
            guide.radius = previous.radius;
            guide.passes = previous.passes;
            guide.kernelCap = previous.kernelCap;
            guide.cells.resize(previous.cells.size());
            for (std::size_t i = 0; i < previous.cells.size(); ++i) guide.cells.set(i, previous.cells.get(i));
        } else {
            guide.columns = static_cast<std::uint32_t>(params.getInt("columns"));
            guide.rows = static_cast<std::uint32_t>(params.getInt("rows"));
            guide.center = 0.5f * (scene.boundsMin + scene.boundsMax);
            guide.radius = glm::length(scene.boundsMax - guide.center);
            const float kernel = static_cast<float>(params.getFloat("kernel_degrees")) * (kPi / 180.0f);
            guide.kernelCap = 1.0f - std::cos(kernel);
            guide.cells.resize(guide.cellCount());
        }
        if (!(guide.radius > 0.0f)) return;

        const ImportonExits& exits = ctx.input<ImportonExits>("exits");
        std::vector<Vec3> directions, positions;
        std::vector<float> weights;
        {
            const auto position = exits.exits.column<ExitPosition>();
            const auto direction = exits.exits.column<ExitDirection>();
            const auto weight = exits.exits.column<ExitWeight>();
            const auto bounces = exits.exits.column<ExitBounces>();
            for (std::size_t i = 0; i < exits.exits.size(); ++i) {
                if (bounces[i] == 0 || !(weight[i] > 0.0f)) continue;
                directions.push_back(direction[i]);
                positions.push_back(position[i]);
                weights.push_back(weight[i]);
            }
        }

        EmSettings em;
        em.maxSweeps = static_cast<int>(params.getInt("max_sweeps"));
        em.effectiveCount = true;  // as cache_update's default prior_count
        const auto minParticles = static_cast<std::size_t>(params.getInt("min_disk_particles"));
        const float cosWindow = std::cos(static_cast<float>(params.getFloat("disk_window_degrees")) * (kPi / 180.0f));
        const double cap = guide.kernelCap;
        const double cosKernel = 1.0 - cap;
        const double normaliser = 1.0 / (static_cast<double>(kPi) * cap * cap);

        auto density = guide.cells.column<EnvCellDensity>();
        auto gmms = guide.cells.column<EnvCellMixture>();
        auto stats = guide.cells.column<EnvCellStatistics>();
        auto fitted = guide.cells.column<EnvCellFitted>();
        std::vector<std::int64_t> fits(guide.cellCount(), 0), updates(guide.cellCount(), 0);
        if (!directions.empty()) {
            jobs::parallelFor(guide.cellCount(), 8, [&](std::size_t c) {
                const auto cell = static_cast<std::uint32_t>(c);
                const Vec3 centre = guide.cellCentre(cell);
                double sum = 0.0;
                std::vector<WeightedPoint> points;
                for (std::size_t i = 0; i < directions.size(); ++i) {
                    const float mu = glm::dot(centre, directions[i]);
                    if (static_cast<double>(mu) > cosKernel)
                        sum += static_cast<double>(weights[i]) * (static_cast<double>(mu) - cosKernel);
                    if (mu >= cosWindow) {
                        const Vec2 d = guide.diskPoint(cell, directions[i], positions[i]);
                        points.push_back({unitDiskToSquare(d), weights[i]});
                    }
                }
                density[c] += static_cast<float>(sum * normaliser);
                if (points.empty()) return;
                if (fitted[c] != 0) {
                    onlineStepwiseEm(gmms[c], stats[c], points, em);
                    fitted[c] = gmms[c].usable() ? 1u : 0u;
                    updates[c] = 1;
                } else if (points.size() >= minParticles) {
                    gmms[c] = initialGmm(points, em);
                    offlineStepwiseEm(gmms[c], stats[c], points, em);
                    fitted[c] = gmms[c].usable() ? 1u : 0u;
                    fits[c] = 1;
                }
            });
        }
        ++guide.passes;
        const double t = static_cast<double>(guide.passes);
        const double alpha = params.getFloat("kernel_alpha");
        guide.kernelCap = static_cast<float>(cap * (t + alpha) / (t + 1.0));

        std::int64_t fitCount = 0, updateCount = 0, fittedCells = 0, cellsWithDensity = 0;
        for (std::size_t c = 0; c < guide.cellCount(); ++c) {
            fitCount += fits[c];
            updateCount += updates[c];
            fittedCells += fitted[c];
            cellsWithDensity += density[c] > 0.0f ? 1 : 0;
        }
        ctx.addItems(static_cast<std::int64_t>(directions.size()));
        ctx.addCounter("training_exits", static_cast<std::int64_t>(directions.size()));
        ctx.addCounter("cells_with_importance", cellsWithDensity);
        ctx.addCounter("disk_gmms_fitted", fitCount);
        ctx.addCounter("disk_gmms_updated", updateCount);
        ctx.addCounter("disk_gmms", fittedCells);
    }
};

}  // namespace

PassRegistration environmentUpdatePass() {
    PassSpec spec;
    spec.name = "environment_update";
    spec.doc = "Environment sampler update (Vorba et al. 2014, §4.4): a direction bitmap by progressive kernel "
               "density estimation and per-cell disk GMMs, from the importons that left the scene";
    SlotSpec exits{"exits", "ImportonExits", "the importons that left the scene in this training pass"};
    SlotSpec previous{"previous", "EnvironmentGuide", "the sampler of the previous training pass (absent: a new one)"};
    previous.optional = true;
    spec.inputs = {exits, previous};
    spec.outputs = {{"environment", "EnvironmentGuide",
                     "the updated environment sampler (empty without an environment emitter)"}};
    spec.params = {
        {"columns", ParamType::Int, std::int64_t{32}, 4, 4096, {},
         "bitmap cells in phi (a new sampler's; a carried one keeps its layout)"},
        {"rows", ParamType::Int, std::int64_t{16}, 2, 2048, {},
         "bitmap cells in cos theta (equal-area rows; a new sampler's)"},
        {"kernel_degrees", ParamType::Float, 10.0, 0.01, 90.0, {},
         "radius of the first pass's cone kernel of the progressive density estimate of p_W (not in the paper)"},
        {"kernel_alpha", ParamType::Float, 2.0 / 3.0, 0.01, 1.0, {},
         "alpha of the kernel's shrinking cap, (1 - cos r) x (t + alpha) / (t + 1) after pass t (PPM's 2/3)"},
        {"disk_window_degrees", ParamType::Float, 10.0, 0.01, 90.0, {},
         "importons within this angle of a cell's centre train its disk GMM p(x|w) (the paper's 1 degree needs far "
         "more importons per pass)"},
        {"min_disk_particles", ParamType::Int, std::int64_t{8}, 1, 1 << 24, {},
         "importons a cell's window must hold in one pass to fit its disk GMM (off-line EM); later passes continue "
         "it on-line"},
        {"max_sweeps", ParamType::Int, std::int64_t{12}, 1, 100000, {},
         "off-line EM ends after this many sweeps over a new disk GMM's importons (as cache_update's)"},
    };
    return {spec, [] { return std::make_unique<EnvironmentUpdatePass>(); }, {}, {}};
}

}  // namespace fg
