// SoA buffers of the hierarchical Gaussian-mixture pipelines (Jakob, Regg &
// Jarosz 2011): the fitted mixture (§5), its level-of-detail pyramid (§6,
// Alg. 3) and the bounding-box hierarchy over the pyramid (§7.1). In memory
// parameters are doubles: the fit's moments must survive merging down to a
// single root (Eqs. 12-14) without loss; the factors of each covariance
// (Cholesky factor, precision, log normaliser of Eq. 5) are kept so that
// rendering never factorises. A fitted mixture is handed on, and saved, as
// its parameters in single precision (GmmStoredBuffer), the size §8 gives.
#pragma once

#include "engine/core/math.h"
#include "engine/core/pass.h"
#include "engine/core/soa.h"
#include "engine/gmm/gaussian.h"

#include <array>
#include <cmath>
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

// The fitted mixture as it leaves the fit and as its file holds it (§5.4:
// the next frame's seed): per component the weight, the RGB power, the mean
// and the covariance as its lower Cholesky factor L (Sigma = L L^T), 13
// parameters as floats, and n_eff (Eq. 10), 56 bytes in all against §8's
// "about 60 bytes per Gaussian" (4096 terms in 240 KB). L rather than Sigma,
// so that rounding cannot make a covariance indefinite. The doubles of
// GmmBuffer are expanded from these (expandStoredComponent), so a mixture
// loaded from its file is, bit for bit, the one the fit handed on.
FG_SOA_COLUMN(GmmStoredWeight, float, "weight");
FG_SOA_COLUMN(GmmStoredPower, Vec3, "power");
FG_SOA_COLUMN(GmmStoredMean, Vec3, "mean");
using GmmFloat6 = std::array<float, 6>;
FG_SOA_COLUMN(GmmStoredCholesky, GmmFloat6, "cholesky");  // L00, L10, L20, L11, L21, L22
FG_SOA_COLUMN(GmmStoredEffectiveCount, float, "n_eff");
using GmmStoredBuffer =
    SoaBuffer<GmmStoredWeight, GmmStoredPower, GmmStoredMean, GmmStoredCholesky, GmmStoredEffectiveCount>;

// Component s rounded to its stored form.
inline GmmStoredBuffer::Record storedComponent(const GmmBuffer& buffer, std::size_t s) {
    GmmStoredBuffer::Record r;
    const glm::dvec3 power = buffer.column<GmmPower>()[s];
    const glm::dvec3 mean = buffer.column<GmmMean>()[s];
    const gmm::Sym3& l = buffer.column<GmmCholesky>()[s];
    r.get<GmmStoredWeight>() = static_cast<float>(buffer.column<GmmWeight>()[s]);
    r.get<GmmStoredPower>() = Vec3(power);
    r.get<GmmStoredMean>() = Vec3(mean);
    for (std::size_t e = 0; e < 6; ++e) r.get<GmmStoredCholesky>()[e] = static_cast<float>(l.v[e]);
    r.get<GmmStoredEffectiveCount>() = static_cast<float>(buffer.column<GmmEffectiveCount>()[s]);
    return r;
}

// Row s of a mixture from its stored form: Sigma = L L^T, precision and log
// normaliser from L (gmm::Gaussian::fromCholesky). Returns false unless every
// value is finite, the weight non-negative and L's diagonal positive.
inline bool expandStoredComponent(const GmmStoredBuffer::Record& r, GmmBuffer& buffer, std::size_t s) {
    gmm::Sym3 l;
    for (std::size_t e = 0; e < 6; ++e) l.v[e] = static_cast<double>(r.get<GmmStoredCholesky>()[e]);
    const gmm::Gaussian g = gmm::Gaussian::fromCholesky(glm::dvec3(r.get<GmmStoredMean>()), l);
    const double weight = r.get<GmmStoredWeight>();
    const glm::dvec3 power(r.get<GmmStoredPower>());
    const double effectiveCount = r.get<GmmStoredEffectiveCount>();
    buffer.column<GmmWeight>()[s] = weight;
    buffer.column<GmmPower>()[s] = power;
    buffer.column<GmmEffectiveCount>()[s] = effectiveCount;
    buffer.column<GmmMean>()[s] = g.mean;
    buffer.column<GmmCovariance>()[s] = g.covariance;
    buffer.column<GmmCholesky>()[s] = g.factors.cholesky;
    buffer.column<GmmPrecision>()[s] = g.factors.precision;
    buffer.column<GmmLogNormaliser>()[s] = g.factors.logNormaliser;
    bool finite = std::isfinite(weight) && std::isfinite(effectiveCount) && std::isfinite(g.factors.logNormaliser);
    for (int a = 0; a < 3; ++a) finite = finite && std::isfinite(power[a]) && std::isfinite(g.mean[a]);
    for (const double v : l.v) finite = finite && std::isfinite(v);
    for (const double v : g.factors.precision.v) finite = finite && std::isfinite(v);
    return finite && weight >= 0.0 && g.factors.valid;
}

// Rounds every component to its stored form and back, as the fits do when
// they hand a mixture on, so that saving and loading it changes nothing.
// Returns false if a component does not survive (see expandStoredComponent).
// The stored form goes through a buffer of its own, as in the codec: with
// a component's rounding and widening in one expression, GCC 12's -O3 (its
// SLP vectoriser) dropped the rounding of part of the Cholesky factor.
inline bool roundToStored(GmmBuffer& buffer) {
    GmmStoredBuffer stored(buffer.size());
    for (std::size_t s = 0; s < buffer.size(); ++s) stored.set(s, storedComponent(buffer, s));
    bool usable = true;
    for (std::size_t s = 0; s < buffer.size(); ++s) usable = expandStoredComponent(stored.get(s), buffer, s) && usable;
    return usable;
}

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
