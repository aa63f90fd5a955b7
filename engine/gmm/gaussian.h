// Anisotropic 3D Gaussians in double precision, the terms of the Gaussian
// mixtures of Jakob, Regg & Jarosz 2011 ("Progressive Expectation-Maximization
// for Hierarchical Volumetric Photon Mapping"): the density of Eq. 5, the
// cell-averaged log-density of accelerated EM (Verbeek, Nunnink & Vlassis
// 2006; the bracket of Eq. 7), the closed-form Kullback-Leibler divergence
// behind the dissimilarity of Eq. 11, the moment-matching merge of Eqs. 12-14
// and the transmittance-weighted line integral of Eqs. 16-17, in corrected form
// (see segmentIntegral).
#pragma once

#include <glm/glm.hpp>

#include <array>
#include <cstddef>

namespace fg::gmm {

using Vec3d = glm::dvec3;
using Mat3d = glm::dmat3;

// A symmetric 3x3 matrix stored as its upper triangle: xx, xy, xz, yy, yz, zz.
struct Sym3 {
    std::array<double, 6> v{};

    static Sym3 identity(double scale = 1.0) { return Sym3{{scale, 0, 0, scale, 0, scale}}; }
    static Sym3 outer(const Vec3d& a) {
        return Sym3{{a.x * a.x, a.x * a.y, a.x * a.z, a.y * a.y, a.y * a.z, a.z * a.z}};
    }
    double operator()(int row, int col) const;
    Sym3& operator+=(const Sym3& o) {
        for (std::size_t i = 0; i < 6; ++i) v[i] += o.v[i];
        return *this;
    }
    Sym3 operator+(const Sym3& o) const { return Sym3(*this) += o; }
    Sym3 operator*(double s) const {
        Sym3 r = *this;
        for (double& x : r.v) x *= s;
        return r;
    }
    // x^T M x
    double quadratic(const Vec3d& x) const;
    Vec3d operator*(const Vec3d& x) const;
    double trace() const { return v[0] + v[3] + v[5]; }
    // tr(M N) for symmetric M, N.
    double traceProduct(const Sym3& n) const;
    double determinant() const;
    // The largest eigenvalue (closed form for symmetric 3x3 matrices).
    double largestEigenvalue() const;
    Mat3d toMat3() const;
};

// The quantities a Gaussian is evaluated with, derived from its covariance.
struct GaussianFactors {
    Sym3 cholesky;   // lower factor L of Sigma = L L^T, stored as L00, L10, L20, L11, L21, L22
    Sym3 precision;  // Sigma^-1
    double logNormaliser = 0.0;  // log((2 pi)^-3/2 |Sigma|^-1/2)
    bool valid = false;          // false when Sigma is not positive definite
};
GaussianFactors factorise(const Sym3& covariance);
// The same factors from the lower Cholesky factor L itself (L00, L10, L20,
// L11, L21, L22); invalid unless its diagonal is positive. factorise(Sigma)
// is factorsFromCholesky of Sigma's factor, bit for bit.
GaussianFactors factorsFromCholesky(const Sym3& cholesky);

struct Gaussian {
    Vec3d mean{0.0};
    Sym3 covariance = Sym3::identity();
    GaussianFactors factors;

    Gaussian() = default;
    Gaussian(const Vec3d& mu, const Sym3& sigma) : mean(mu), covariance(sigma), factors(factorise(sigma)) {}
    // The Gaussian whose covariance is L L^T, for a mixture kept as its
    // Cholesky factors (see GmmStoredBuffer): positive definite whenever L's
    // diagonal is positive, however it was rounded.
    static Gaussian fromCholesky(const Vec3d& mu, const Sym3& cholesky);

    // log g(x | Theta), Eq. 5.
    double logDensity(const Vec3d& x) const;
    double density(const Vec3d& x) const;
    // <log g>_A over a cell whose points have mean m and (biased) covariance C:
    // -1/2 [log|2 pi Sigma| + (m - mu)^T Sigma^-1 (m - mu) + tr(Sigma^-1 C)].
    double expectedLogDensity(const Vec3d& cellMean, const Sym3& cellCovariance) const;
};

// D_KL(a || b) of two 3D Gaussians:
// 1/2 [tr(Sb^-1 Sa) + (mb - ma)^T Sb^-1 (mb - ma) - 3 + log(|Sb| / |Sa|)].
double klDivergence(const Gaussian& a, const Gaussian& b);

// Eqs. 12-14: the moment-matching merge of two weighted Gaussians; the result's
// weight is the sum, its mean and covariance those of the two-term mixture.
struct WeightedMoments {
    double weight = 0.0;
    Vec3d mean{0.0};
    Sym3 covariance;
};
WeightedMoments merge(const WeightedMoments& a, const WeightedMoments& b);

// erfc(x) e^{x^2} for x >= 0, accurate where erfc underflows.
double erfcx(double x);

// The Mahalanobis radius beyond which a share `tail` of a 3D Gaussian's mass
// lies (P(chi_3 > r) = tail); 0 for tail >= 1. The truncated ellipsoids of
// gmm_bbh and gmm_splat cut each Gaussian there.
double truncationRadius(double tail);

// Eqs. 16-17 as they should read: for r(t) = x + t w (w of unit length),
//   int_a^b g(r(t)) e^{-sigma_t t} dt
//     = N sqrt(pi) / (2 sqrt(C2)) e^{C3^2 / 4 C2 - C1}
//       [erf((C3 + 2 C2 b) / 2 sqrt(C2)) - erf((C3 + 2 C2 a) / 2 sqrt(C2))],
// N = (2 pi)^-3/2 |Sigma|^-1/2, d = x - mu, C1 = 1/2 d^T Sigma^-1 d,
// C2 = 1/2 w^T Sigma^-1 w, C3 = w^T Sigma^-1 d + sigma_t. The paper's C0 lacks
// the factor sqrt(pi) / (2 sqrt(C2)) from integrating exp(-C2 u^2) and its C1
// holds a spurious -sigma_t b; derived by completing the square in
// -C1 - C3 t - C2 t^2, the exponent of the integrand. b may be infinite;
// a <= b. Evaluated without cancellation or overflow (see the definition).
double segmentIntegral(const Gaussian& g, const Vec3d& origin, const Vec3d& direction, double sigmaT, double a,
                       double b);

// What the segment integral reads of a Gaussian: 80 bytes instead of the
// whole Gaussian's 184, so that a renderer walking thousands of them per ray
// keeps them in cache.
struct SegmentGaussian {
    Vec3d mean{0.0};
    Sym3 precision = Sym3::identity();
    double logNormaliser = 0.0;

    SegmentGaussian() = default;
    explicit SegmentGaussian(const Gaussian& g)
        : mean(g.mean), precision(g.factors.precision), logNormaliser(g.factors.logNormaliser) {}
};

// segmentIntegral for three extinction coefficients (RGB) at once. The terms
// that do not depend on sigma_t (d, Sigma^-1 w, C2, the quadratic forms at a
// and b) are computed once, and when all three coefficients are equal (grey
// media) the erf/exp part is evaluated once and copied: the same values as
// three calls of segmentIntegral, at a third of the cost.
Vec3d segmentIntegralRgb(const SegmentGaussian& g, const Vec3d& origin, const Vec3d& direction, const Vec3d& sigmaT,
                         double a, double b);

// segmentIntegralRgb for a Gaussian truncated to its ellipsoid
// (x - mu)^T Sigma^-1 (x - mu) <= radiusSquared (§7.1). Along the line,
// m(t) = d^T Sigma^-1 d + 2 t w^T Sigma^-1 d + t^2 w^T Sigma^-1 w has its
// minimum d^T Sigma^-1 d - (w^T Sigma^-1 d)^2 / w^T Sigma^-1 w; the line meets
// the ellipsoid on the chord where m(t) <= radiusSquared. Returns false, and
// leaves `integral` alone, when the line misses the ellipsoid or [a, b] misses
// the chord; otherwise sets it to segmentIntegralRgb's value up to rounding
// (the untruncated integral over [a, b]: the truncation only decides which
// Gaussians a segment sees, as the boxes of the bounding hierarchy do).
bool truncatedSegmentIntegralRgb(const SegmentGaussian& g, double radiusSquared, const Vec3d& origin,
                                 const Vec3d& direction, const Vec3d& sigmaT, double a, double b, Vec3d& integral);

}  // namespace fg::gmm
