// Shared by the Gaussian-mixture passes; see pem_common.h.
#include "passes/pem/pem_common.h"

#include "engine/core/error.h"
#include "engine/scene/scene.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

namespace fg {

void refuseAnisotropicMedia(const PreflightContext& pf) {
    for (const HomogeneousMedium& medium : pf.scene.media) {
        if (medium.phase().g() != 0.0f) {
            throw InputError(pf.source + ": pass '" + pf.instance +
                             "': the Gaussian mixture renders isotropic media only (Jakob et al. 2011 §9), but a "
                             "medium has Henyey-Greenstein g = " + std::to_string(medium.phase().g()));
        }
    }
}

double ridgeInSceneUnits(const EmTree& tree, double regCovar) {
    if (tree.nodes.empty()) return regCovar;
    const Vec3 extent = tree.nodes.column<EmNodeHi>()[0] - tree.nodes.column<EmNodeLo>()[0];
    const double side = std::max({static_cast<double>(extent.x), static_cast<double>(extent.y),
                                  static_cast<double>(extent.z), 1e-30});
    return regCovar * side * side;
}

void storeMixture(const std::vector<gmm::EmComponent>& components, std::uint64_t photons, GaussianMixture& mixture,
                  double powerScale) {
    mixture.photons = photons;
    mixture.components.resize(components.size());
    for (std::size_t s = 0; s < components.size(); ++s) {
        mixture.components.column<GmmWeight>()[s] = components[s].weight;
        mixture.components.column<GmmPower>()[s] = components[s].power * powerScale;
        mixture.components.column<GmmEffectiveCount>()[s] = components[s].effectiveCount;
        setGaussianAt(mixture.components, s, components[s].gaussian);
    }
    // Handed on in the single precision it is saved in (GmmStoredBuffer), so
    // that a saved and loaded mixture renders and seeds exactly as this one.
    if (!roundToStored(mixture.components))
        throw std::logic_error("a fitted Gaussian component does not survive rounding to single precision");
}

void reportFit(PassContext& ctx, const gmm::EmRun& run, const std::vector<gmm::EmComponent>& components,
               double photons) {
    double minEffective = components.empty() ? 0.0 : components.front().effectiveCount;
    for (const gmm::EmComponent& c : components) minEffective = std::min(minEffective, c.effectiveCount);
    ctx.addCounter("components", static_cast<std::int64_t>(components.size()));
    ctx.addCounter("dropped_components", static_cast<std::int64_t>(run.dropped));
    ctx.addCounter("pairs_kept", static_cast<std::int64_t>(run.responsibilities.pairsKept));
    ctx.addCounter("pairs_pruned", static_cast<std::int64_t>(run.responsibilities.pairsPruned));
    ctx.addCounter("min_n_eff", static_cast<std::int64_t>(std::floor(minEffective)));
    // F/n in millionths (counters are integers).
    if (!run.bounds.empty() && photons > 0.0)
        ctx.addCounter("bound_per_photon_e6", static_cast<std::int64_t>(std::llround(run.bounds.back() / photons * 1e6)));
}

}  // namespace fg
