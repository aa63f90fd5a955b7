// Eq. 15 of Jakob, Regg & Jarosz 2011 summed over many Gaussians along one
// segment x + t w, t in [0, length], with the closed form of Eqs. 16-17 as
// corrected in gaussian.h (segmentIntegral). Evaluated in two phases, so that
// the transcendental part vectorises: `add` computes a Gaussian's terms that
// do not depend on sigma_t (d = x - mu, C2, w^T Sigma^-1 d, d^T Sigma^-1 d / 2)
// and, for `addTruncated`, the ellipsoid test of truncatedSegmentIntegralRgb,
// keeping them in columns (`addAll` tests two Gaussians at a time and keeps
// those that pass); `sum` then evaluates all kept Gaussians with the
// straight-line exp, erfc and erf of fast_math.h, several at a time. The
// result equals the sum of power * segmentIntegralRgb in the order of the
// calls to within about 1e-7 of each term (fast_math.h).
#pragma once

#include "engine/gmm/gaussian.h"

#include <array>
#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

namespace fg::gmm {

// What a batch reads of one Gaussian, in one record of two cache lines' size
// at most, so that a segment's candidates cost two line loads each, and with
// its fields in pairs that two records' loads transpose into SSE2 lanes.
struct alignas(16) PackedGaussian {
    double meanX = 0.0, meanY = 0.0, meanZ = 0.0;
    double radiusSquared = 0.0;  // the truncation, r_j^2 (gmm_bbh)
    std::array<double, 6> precision{};  // Sigma^-1 as Sym3
    double logNormaliser = 0.0;
    double powerRed = 0.0, powerGreen = 0.0, powerBlue = 0.0;

    PackedGaussian() = default;
    PackedGaussian(const SegmentGaussian& g, double truncationSquared, const Vec3d& power)
        : meanX(g.mean.x), meanY(g.mean.y), meanZ(g.mean.z), radiusSquared(truncationSquared),
          precision(g.precision.v), logNormaliser(g.logNormaliser), powerRed(power.x), powerGreen(power.y),
          powerBlue(power.z) {}
};

class SegmentBatch {
public:
    // Starts a segment (w of unit length; length may be +inf) and forgets
    // the Gaussians kept for the previous one.
    void begin(const Vec3d& origin, const Vec3d& direction, double length);
    // Keeps g unless the segment misses its ellipsoid of Mahalanobis radius^2
    // radiusSquared (the same test as truncatedSegmentIntegralRgb); returns
    // whether it was kept.
    bool addTruncated(const SegmentGaussian& g, double radiusSquared, const Vec3d& power);
    void add(const SegmentGaussian& g, const Vec3d& power);
    // records[indices[0]], records[indices[1]], ... in that order, each kept
    // as by addTruncated (truncate) or add; returns how many were kept.
    std::size_t addAll(std::span<const PackedGaussian> records, std::span<const std::uint32_t> indices, bool truncate);
    std::size_t size() const { return count_; }
    // Sum over the kept Gaussians, in the order they were added, of power *
    // int_0^length g(x + t w) e^{-sigma_t t} dt per RGB channel.
    Vec3d sum(const Vec3d& sigmaT);

private:
    // Room for `more` rows, and for the pad sum may add.
    void reserve(std::size_t more);
    // integral_[i] for one extinction coefficient.
    void integrate(double sigmaT);

    Vec3d origin_{0.0}, direction_{0.0};
    double length_ = 0.0;
    bool infinite_ = false;
    bool empty_ = true;  // the segment has no length: every integral is 0
    std::size_t count_ = 0;
    // Columns of the kept Gaussians' terms, count_ of them in use.
    std::vector<double> c2_, rootC2_, wPd_, halfDPd_, logNormaliser_, powerRed_, powerGreen_, powerBlue_;
    std::vector<double> integral_, peak_;  // per channel: the integral, P (see integrate)
    std::vector<std::uint32_t> pending_;  // Gaussians integrate evaluates in full
    std::vector<std::uint32_t> oneEnd_;   // those it evaluates at one end: row << 1 | (1 at the segment's end)
};

}  // namespace fg::gmm
