// What the Gaussian-mixture passes (Jakob et al. 2011) share: the refusal of
// anisotropic media (§9), the ridge's scale and the hand-over of a fitted
// mixture into its buffer.
#pragma once

#include "engine/core/pass.h"
#include "engine/gmm/em.h"
#include "engine/gmm/em_tree.h"
#include "engine/gmm/gmm_buffers.h"

#include <vector>

namespace fg {

// Preflight: Eq. 15 carries the phase function as 1/4 pi, so isotropic media only.
void refuseAnisotropicMedia(const PreflightContext& pf);

// reg_covar is given in unit-box coordinates (the photons' box scaled so that
// its longest side is 1); this is its value in scene units squared.
double ridgeInSceneUnits(const EmTree& tree, double regCovar);

// The fitted components as the fit's output, powers times powerScale, rounded
// to the stored form (GmmStoredBuffer).
void storeMixture(const std::vector<gmm::EmComponent>& components, std::uint64_t photons, GaussianMixture& mixture,
                  double powerScale = 1.0);

// Completes a seed of fewer than k components to k (see pem_common.cpp):
// the component with the largest weight times largest eigenvalue is split
// along that eigenvalue's axis into two of half its weight that keep its
// mean and covariance, repeatedly, ties to the lower index. The split
// component keeps its place and its second half is appended. A seed of k or
// more components is left as it is. Returns the number added.
std::size_t splitToCount(std::vector<gmm::EmComponent>& components, std::size_t k);

// Counters every fit reports.
void reportFit(PassContext& ctx, const gmm::EmRun& run, const std::vector<gmm::EmComponent>& components,
               double photons);

}  // namespace fg
