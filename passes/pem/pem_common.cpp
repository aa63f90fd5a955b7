// Shared by the Gaussian-mixture passes; see pem_common.h.
#include "passes/pem/pem_common.h"

#include "engine/core/error.h"
#include "engine/scene/scene.h"

#include <algorithm>
#include <array>
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

namespace {

// A unit eigenvector of the symmetric covariance for its largest eigenvalue
// lambda: the rows of Sigma - lambda I span the orthogonal complement of the
// eigenspace, so the longest cross product of two rows is along it. When
// lambda is a double root (one independent row) any vector orthogonal to that
// row is one; when it is a triple root (Sigma = lambda I) any vector is.
gmm::Vec3d principalAxis(const gmm::Sym3& sigma, double lambda) {
    std::array<gmm::Vec3d, 3> rows;
    for (int r = 0; r < 3; ++r)
        rows[static_cast<std::size_t>(r)] = {sigma(r, 0) - (r == 0 ? lambda : 0.0),
                                             sigma(r, 1) - (r == 1 ? lambda : 0.0),
                                             sigma(r, 2) - (r == 2 ? lambda : 0.0)};
    const std::array<gmm::Vec3d, 3> crosses = {glm::cross(rows[0], rows[1]), glm::cross(rows[0], rows[2]),
                                               glm::cross(rows[1], rows[2])};
    double rowScale = 0.0;
    for (const gmm::Vec3d& r : rows) rowScale = std::max(rowScale, glm::dot(r, r));
    gmm::Vec3d best = crosses[0];
    for (const gmm::Vec3d& c : crosses)
        if (glm::dot(c, c) > glm::dot(best, best)) best = c;
    // Relative to the rows' size: below this the rows are parallel to rounding.
    if (glm::dot(best, best) > 1e-20 * rowScale * rowScale) return glm::normalize(best);
    gmm::Vec3d row = rows[0];
    for (const gmm::Vec3d& r : rows)
        if (glm::dot(r, r) > glm::dot(row, row)) row = r;
    if (glm::dot(row, row) <= 1e-30 * std::max(lambda * lambda, 1e-300)) return {1.0, 0.0, 0.0};
    const gmm::Vec3d a = glm::abs(row);
    const gmm::Vec3d axis = a.x <= a.y && a.x <= a.z ? gmm::Vec3d{1, 0, 0}
                            : a.y <= a.z             ? gmm::Vec3d{0, 1, 0}
                                                     : gmm::Vec3d{0, 0, 1};
    return glm::normalize(glm::cross(row, axis));
}

}  // namespace

// §5.4 seeds a frame with the previous frame's converged parameters but says
// nothing of components the previous fit dropped (n_eff < min_n_eff); without
// replacements a coherent sequence would lose them for good. The split is the
// moment-preserving one: for Sigma's largest eigenpair (lambda, v) the halves
// sit at mu -/+ a sqrt(lambda) v with covariance Sigma - a^2 lambda v v^T, so
// the pair has the parent's weight, mean and covariance (a two-term mixture's
// covariance is its terms' mean covariance plus the spread of their means,
// a^2 lambda v v^T) and the seed's density moments are unchanged; a = 1/2
// leaves 3/4 of lambda along v, so the halves overlap and EM pulls them apart
// from a point where F has barely moved. The widest heavy component is split
// first since it is where one Gaussian stands in for the most photons spread
// over the most space.
std::size_t splitToCount(std::vector<gmm::EmComponent>& components, std::size_t k) {
    if (components.empty() || components.size() >= k) return 0;
    const std::size_t added = k - components.size();
    components.reserve(k);
    std::vector<double> lambda(components.size());
    std::vector<double> score(components.size());
    for (std::size_t s = 0; s < components.size(); ++s) {
        lambda[s] = components[s].gaussian.covariance.largestEigenvalue();
        score[s] = components[s].weight * lambda[s];
    }
    constexpr double a = 0.5;
    while (components.size() < k) {
        std::size_t s = 0;
        for (std::size_t i = 1; i < components.size(); ++i)
            if (score[i] > score[s]) s = i;
        gmm::EmComponent& parent = components[s];
        const gmm::Vec3d v = principalAxis(parent.gaussian.covariance, lambda[s]);
        const gmm::Vec3d offset = v * (a * std::sqrt(lambda[s]));
        gmm::Sym3 covariance = parent.gaussian.covariance;
        const gmm::Sym3 along = gmm::Sym3::outer(v) * (a * a * lambda[s]);
        for (std::size_t e = 0; e < 6; ++e) covariance.v[e] -= along.v[e];
        gmm::EmComponent half = parent;
        half.weight = 0.5 * parent.weight;
        half.power = 0.5 * parent.power;
        half.effectiveCount = 0.5 * parent.effectiveCount;
        gmm::EmComponent other = half;
        half.gaussian = gmm::Gaussian(parent.gaussian.mean - offset, covariance);
        other.gaussian = gmm::Gaussian(parent.gaussian.mean + offset, covariance);
        components[s] = half;
        components.push_back(other);
        for (const std::size_t i : {s, components.size() - 1}) {
            if (i >= lambda.size()) {
                lambda.push_back(0.0);
                score.push_back(0.0);
            }
            lambda[i] = components[i].gaussian.covariance.largestEigenvalue();
            score[i] = components[i].weight * lambda[i];
        }
    }
    return added;
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
