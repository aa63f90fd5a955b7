// SoA buffers of the hierarchical Gaussian-mixture pipelines (Jakob, Regg &
// Jarosz 2011): the fitted mixture (§5), its level-of-detail pyramid (§6,
// Alg. 3) and the bounding-box hierarchy over the pyramid (§7.1). Parameters
// are doubles: the fit's moments must survive merging down to a single root
// (Eqs. 12-14) without loss; the factors of each covariance (Cholesky factor,
// precision, log normaliser of Eq. 5) are stored so that rendering never
// factorises.
#pragma once

#include "engine/core/math.h"
#include "engine/core/pass.h"
#include "engine/core/soa.h"
#include "engine/gmm/gaussian.h"

#include <cstdint>
#include <limits>

namespace fg {

// The mixture weight w_s (Eq. 4): the share of photons the component explains.
FG_SOA_COLUMN(GmmWeight, double, "weight");
// Phi_s = sum_A q_A(s) Phi_A: the RGB power of the photons it explains, which
// Eq. 15 multiplies the normalised density by.
FG_SOA_COLUMN(GmmPower, glm::dvec3, "power");
// The summed RGB power a component's truncation is measured against (the
// W and w_j of gmm_bbh's delta rule).
inline double energy(const glm::dvec3& power) { return power.x + power.y + power.z; }
FG_SOA_COLUMN(GmmMean, glm::dvec3, "mean");
FG_SOA_COLUMN(GmmCovariance, gmm::Sym3, "covariance");
FG_SOA_COLUMN(GmmCholesky, gmm::Sym3, "cholesky");
FG_SOA_COLUMN(GmmPrecision, gmm::Sym3, "precision");
FG_SOA_COLUMN(GmmLogNormaliser, double, "log_normaliser");
FG_SOA_COLUMN(GmmEffectiveCount, double, "n_eff");  // Eq. 10

using GmmBuffer = SoaBuffer<GmmWeight, GmmPower, GmmMean, GmmCovariance, GmmCholesky, GmmPrecision, GmmLogNormaliser,
                            GmmEffectiveCount>;

struct GaussianMixture {
    GmmBuffer components;
    std::uint64_t photons = 0;  // photons the fit saw
    std::size_t bytes() const { return components.bytes(); }
};
template <>
struct BufferTypeName<GaussianMixture> {
    static constexpr const char* value = "GaussianMixture";
};

inline constexpr std::uint32_t kNoGmmNode = std::numeric_limits<std::uint32_t>::max();

// Pyramid nodes depth first: a node's left child follows it; `right` names the
// other (kNoGmmNode for the k leaves, which are the mixture's components).
FG_SOA_COLUMN(GmmRight, std::uint32_t, "right");
FG_SOA_COLUMN(GmmLevel, std::uint32_t, "level");  // 0 at the leaves, the root's is the largest

using GmmPyramidBuffer = SoaBuffer<GmmWeight, GmmPower, GmmMean, GmmCovariance, GmmCholesky, GmmPrecision,
                                   GmmLogNormaliser, GmmEffectiveCount, GmmRight, GmmLevel>;

struct GmmPyramid {
    GmmPyramidBuffer nodes;
    std::uint32_t levels = 0;  // levels above the leaves
    std::size_t bytes() const { return nodes.bytes(); }
};
template <>
struct BufferTypeName<GmmPyramid> {
    static constexpr const char* value = "GmmPyramid";
};

// Per pyramid node (same order): the box of its truncated ellipsoid united
// with its children's boxes, and the sphere around that box (§7.1).
FG_SOA_COLUMN(BbhLo, Vec3, "lo");
FG_SOA_COLUMN(BbhHi, Vec3, "hi");
FG_SOA_COLUMN(BbhSphere, Vec4, "sphere");  // centre, radius
// The truncation's Mahalanobis radius r_j: the node's Gaussian is cut to
// (x - mu)^T Sigma^-1 (x - mu) <= r_j^2, the ellipsoid its box bounds.
FG_SOA_COLUMN(BbhRadius, double, "radius");
using GmmBbhBuffer = SoaBuffer<BbhLo, BbhHi, BbhSphere, BbhRadius>;

struct GmmBbh {
    GmmBbhBuffer nodes;
    double truncation = 0.0;  // delta: truncated energy per node <= delta W / k
    std::size_t bytes() const { return nodes.bytes(); }
};
template <>
struct BufferTypeName<GmmBbh> {
    static constexpr const char* value = "GmmBbh";
};

// The Gaussian of row i of a mixture or pyramid buffer.
template <class Buffer>
gmm::Gaussian gaussianAt(const Buffer& buffer, std::size_t i) {
    gmm::Gaussian g;
    g.mean = buffer.template column<GmmMean>()[i];
    g.covariance = buffer.template column<GmmCovariance>()[i];
    g.factors.cholesky = buffer.template column<GmmCholesky>()[i];
    g.factors.precision = buffer.template column<GmmPrecision>()[i];
    g.factors.logNormaliser = buffer.template column<GmmLogNormaliser>()[i];
    g.factors.valid = true;
    return g;
}

template <class Buffer>
void setGaussianAt(Buffer& buffer, std::size_t i, const gmm::Gaussian& g) {
    buffer.template column<GmmMean>()[i] = g.mean;
    buffer.template column<GmmCovariance>()[i] = g.covariance;
    buffer.template column<GmmCholesky>()[i] = g.factors.cholesky;
    buffer.template column<GmmPrecision>()[i] = g.factors.precision;
    buffer.template column<GmmLogNormaliser>()[i] = g.factors.logNormaliser;
}

}  // namespace fg
