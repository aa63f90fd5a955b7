// Eq. 15 of Jakob, Regg & Jarosz 2011 summed over many Gaussians along one
// segment x + t w, t in [0, length], with the closed form of Eqs. 16-17 as
// corrected in gaussian.h (segmentIntegral). Evaluated in two phases, so that
// the transcendental part vectorises: `add` computes a Gaussian's terms that
// do not depend on sigma_t (d = x - mu, C2, w^T Sigma^-1 d, d^T Sigma^-1 d / 2)
// and, for `addTruncated`, the ellipsoid test of truncatedSegmentIntegralRgb,
// keeping them in columns; `sum` then evaluates all kept Gaussians with the
// straight-line exp, erfc and erf of fast_math.h, several at a time. The
// result equals the sum of power * segmentIntegralRgb in the order of the
// calls to within about 1e-7 of each term (fast_math.h).
#pragma once

#include "engine/gmm/gaussian.h"

#include <cstddef>
#include <cstdint>
#include <vector>

namespace fg::gmm {

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
    std::size_t size() const { return count_; }
    // Sum over the kept Gaussians, in the order they were added, of power *
    // int_0^length g(x + t w) e^{-sigma_t t} dt per RGB channel.
    Vec3d sum(const Vec3d& sigmaT);

private:
    void keep(const SegmentGaussian& g, double c2, double wPd, double halfDPd, const Vec3d& power);
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
};

}  // namespace fg::gmm
