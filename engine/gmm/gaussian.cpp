// Gaussian arithmetic of Jakob et al. 2011 (Eqs. 5, 7, 11-14, 16-17); see gaussian.h.
#include "engine/gmm/gaussian.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace fg::gmm {

namespace {

constexpr double kLog2Pi = 1.8378770664093454836;
constexpr double kSqrtPi = 1.7724538509055160273;

// Index of entry (row, col) in the upper-triangle storage.
constexpr int packedIndex(int row, int col) {
    if (row > col) std::swap(row, col);
    constexpr int rowStart[3] = {0, 3, 5};
    return rowStart[row] + (col - row);
}

// Lower-triangular L stored as L00, L10, L20, L11, L21, L22: solves L y = x.
Vec3d forwardSubstitute(const Sym3& l, const Vec3d& x) {
    const double y0 = x.x / l.v[0];
    const double y1 = (x.y - l.v[1] * y0) / l.v[3];
    const double y2 = (x.z - l.v[2] * y0 - l.v[4] * y1) / l.v[5];
    return {y0, y1, y2};
}

}  // namespace

double Sym3::operator()(int row, int col) const { return v[static_cast<std::size_t>(packedIndex(row, col))]; }

double Sym3::quadratic(const Vec3d& x) const {
    return v[0] * x.x * x.x + v[3] * x.y * x.y + v[5] * x.z * x.z +
           2.0 * (v[1] * x.x * x.y + v[2] * x.x * x.z + v[4] * x.y * x.z);
}

Vec3d Sym3::operator*(const Vec3d& x) const {
    return {v[0] * x.x + v[1] * x.y + v[2] * x.z, v[1] * x.x + v[3] * x.y + v[4] * x.z,
            v[2] * x.x + v[4] * x.y + v[5] * x.z};
}

double Sym3::traceProduct(const Sym3& n) const {
    return v[0] * n.v[0] + v[3] * n.v[3] + v[5] * n.v[5] + 2.0 * (v[1] * n.v[1] + v[2] * n.v[2] + v[4] * n.v[4]);
}

double Sym3::determinant() const {
    return v[0] * (v[3] * v[5] - v[4] * v[4]) - v[1] * (v[1] * v[5] - v[4] * v[2]) +
           v[2] * (v[1] * v[4] - v[3] * v[2]);
}

double Sym3::largestEigenvalue() const {
    // Smith 1961: the eigenvalues of a symmetric 3x3 matrix from the
    // trigonometric solution of its characteristic cubic.
    const double offDiagonal = v[1] * v[1] + v[2] * v[2] + v[4] * v[4];
    if (offDiagonal == 0.0) return std::max({v[0], v[3], v[5]});
    const double q = trace() / 3.0;
    const double a = v[0] - q, b = v[3] - q, c = v[5] - q;
    const double p = std::sqrt((a * a + b * b + c * c + 2.0 * offDiagonal) / 6.0);
    const Sym3 shifted{{a / p, v[1] / p, v[2] / p, b / p, v[4] / p, c / p}};
    const double r = std::clamp(shifted.determinant() / 2.0, -1.0, 1.0);
    return q + 2.0 * p * std::cos(std::acos(r) / 3.0);
}

Mat3d Sym3::toMat3() const {
    Mat3d m;
    for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) m[c][r] = (*this)(r, c);
    return m;
}

GaussianFactors factorise(const Sym3& s) {
    GaussianFactors f;
    const double l00sq = s.v[0];
    if (!(l00sq > 0.0)) return f;
    const double l00 = std::sqrt(l00sq);
    const double l10 = s.v[1] / l00, l20 = s.v[2] / l00;
    const double l11sq = s.v[3] - l10 * l10;
    if (!(l11sq > 0.0)) return f;
    const double l11 = std::sqrt(l11sq);
    const double l21 = (s.v[4] - l20 * l10) / l11;
    const double l22sq = s.v[5] - l20 * l20 - l21 * l21;
    if (!(l22sq > 0.0)) return f;
    const double l22 = std::sqrt(l22sq);
    return factorsFromCholesky(Sym3{{l00, l10, l20, l11, l21, l22}});
}

GaussianFactors factorsFromCholesky(const Sym3& l) {
    GaussianFactors f;
    const double l00 = l.v[0], l10 = l.v[1], l20 = l.v[2], l11 = l.v[3], l21 = l.v[4], l22 = l.v[5];
    if (!(l00 > 0.0 && l11 > 0.0 && l22 > 0.0)) return f;
    f.cholesky = l;
    // M = L^-1 (lower triangular), Sigma^-1 = M^T M.
    const double m00 = 1.0 / l00, m11 = 1.0 / l11, m22 = 1.0 / l22;
    const double m10 = -l10 * m00 / l11;
    const double m21 = -l21 * m11 / l22;
    const double m20 = -(l20 * m00 + l21 * m10) / l22;
    f.precision = Sym3{{m00 * m00 + m10 * m10 + m20 * m20, m10 * m11 + m20 * m21, m20 * m22,
                        m11 * m11 + m21 * m21, m21 * m22, m22 * m22}};
    f.logNormaliser = -1.5 * kLog2Pi - (std::log(l00) + std::log(l11) + std::log(l22));
    f.valid = std::isfinite(f.logNormaliser);
    return f;
}

Gaussian Gaussian::fromCholesky(const Vec3d& mu, const Sym3& l) {
    Gaussian g;
    g.mean = mu;
    // Sigma = L L^T entry by entry (L lower triangular).
    g.covariance = Sym3{{l.v[0] * l.v[0], l.v[0] * l.v[1], l.v[0] * l.v[2], l.v[1] * l.v[1] + l.v[3] * l.v[3],
                         l.v[1] * l.v[2] + l.v[3] * l.v[4], l.v[2] * l.v[2] + l.v[4] * l.v[4] + l.v[5] * l.v[5]}};
    g.factors = factorsFromCholesky(l);
    return g;
}

double Gaussian::logDensity(const Vec3d& x) const {
    const Vec3d y = forwardSubstitute(factors.cholesky, x - mean);
    return factors.logNormaliser - 0.5 * glm::dot(y, y);
}

double Gaussian::density(const Vec3d& x) const { return std::exp(logDensity(x)); }

double Gaussian::expectedLogDensity(const Vec3d& cellMean, const Sym3& cellCovariance) const {
    const Vec3d y = forwardSubstitute(factors.cholesky, cellMean - mean);
    return factors.logNormaliser - 0.5 * (glm::dot(y, y) + factors.precision.traceProduct(cellCovariance));
}

double klDivergence(const Gaussian& a, const Gaussian& b) {
    const Vec3d y = forwardSubstitute(b.factors.cholesky, b.mean - a.mean);
    // log(|Sb| / |Sa|) = 2 (logNormaliser_a - logNormaliser_b).
    return 0.5 * (b.factors.precision.traceProduct(a.covariance) + glm::dot(y, y) - 3.0) +
           (a.factors.logNormaliser - b.factors.logNormaliser);
}

WeightedMoments merge(const WeightedMoments& a, const WeightedMoments& b) {
    WeightedMoments m;
    m.weight = a.weight + b.weight;
    if (!(m.weight > 0.0)) return m;
    const double fa = a.weight / m.weight, fb = b.weight / m.weight;
    m.mean = fa * a.mean + fb * b.mean;
    // Eq. 14 in the form sum_k f_k (Sigma_k + (mu_k - mu)(mu_k - mu)^T).
    m.covariance = (a.covariance + Sym3::outer(a.mean - m.mean)) * fa + (b.covariance + Sym3::outer(b.mean - m.mean)) * fb;
    return m;
}

double truncationRadius(double tail) {
    if (!(tail < 1.0)) return 0.0;
    // P(chi_3 > r) = erfc(r / sqrt 2) + sqrt(2 / pi) r e^{-r^2 / 2}, decreasing in r.
    const auto chi3Tail = [](double r) {
        return std::erfc(r / std::sqrt(2.0)) + std::sqrt(2.0 / M_PI) * r * std::exp(-0.5 * r * r);
    };
    double lo = 0.0, hi = 64.0;
    for (int i = 0; i < 100; ++i) {
        const double mid = 0.5 * (lo + hi);
        (chi3Tail(mid) > tail ? lo : hi) = mid;
    }
    return hi;
}

double erfcx(double x) {
    // Below 25 erfc keeps its relative accuracy and e^{x^2} stays finite;
    // beyond, erfc underflows and the asymptotic series is exact to ~1e-13.
    if (x < 25.0) return std::exp(x * x) * std::erfc(x);
    const double inv2 = 1.0 / (2.0 * x * x);
    double term = 1.0, sum = 1.0;
    for (int k = 1; k <= 6; ++k) {
        term *= -(2.0 * k - 1.0) * inv2;
        sum += term;
    }
    return sum / (x * kSqrtPi);
}

double segmentIntegral(const Gaussian& g, const Vec3d& origin, const Vec3d& direction, double sigmaT, double a,
                       double b) {
    if (!(b > a)) return 0.0;
    const Sym3& precision = g.factors.precision;
    const Vec3d d = origin - g.mean;
    const Vec3d pw = precision * direction;
    const double c2 = 0.5 * glm::dot(direction, pw);
    const double c3 = glm::dot(pw, d) + sigmaT;
    const double rootC2 = std::sqrt(c2);
    const double scale = kSqrtPi / (2.0 * rootC2);
    const bool bInfinite = std::isinf(b);
    const auto argument = [&](double t) { return rootC2 * t + c3 / (2.0 * rootC2); };
    // log N + the exponent of the integrand at t: log N - C1 - C3 t - C2 t^2. The
    // identities C3^2/4C2 - C1 - z(t)^2 = -C1 - C3 t - C2 t^2 turn
    // e^{C3^2/4C2 - C1} erfc(z) into e^{exponent(t)} erfcx(z), which neither
    // overflows nor cancels when both erf arguments are far in one tail.
    const auto logIntegrand = [&](double t) {
        const Vec3d r = d + t * direction;
        return g.factors.logNormaliser - 0.5 * precision.quadratic(r) - sigmaT * t;
    };
    const double za = argument(a);
    const double zb = bInfinite ? std::numeric_limits<double>::infinity() : argument(b);
    if (za >= 0.0) {
        const double lower = std::exp(logIntegrand(a)) * erfcx(za);
        const double upper = bInfinite ? 0.0 : std::exp(logIntegrand(b)) * erfcx(zb);
        return scale * (lower - upper);
    }
    if (zb <= 0.0) {
        return scale * (std::exp(logIntegrand(b)) * erfcx(-zb) - std::exp(logIntegrand(a)) * erfcx(-za));
    }
    // The peak lies inside [a, b]: erf of opposite signs does not cancel and
    // the exponent is the integrand's largest, so it cannot overflow.
    const double logPeak = g.factors.logNormaliser + c3 * c3 / (4.0 * c2) - 0.5 * precision.quadratic(d);
    const double upperErf = bInfinite ? 1.0 : std::erf(zb);
    return scale * std::exp(logPeak) * (upperErf - std::erf(za));
}

namespace {

// glibc's erf rounds to exactly +-1 from |x| = 6 on (erfc(6) = 2e-17 is below
// half an ulp of 1); answering those without the call changes no value. A
// segment that ends well before or begins well after a Gaussian's chord is the
// common case, so most integrals need no erf at all.
constexpr double kErfIsOne = 6.0;
double erfSaturated(double x) {
    if (x >= kErfIsOne) return 1.0;
    if (x <= -kErfIsOne) return -1.0;
    return std::erf(x);
}

// The part of segmentIntegralRgb after the terms that do not depend on the
// segment's ends: d = origin - mean, pw = Sigma^-1 w, c2 = w^T Sigma^-1 w / 2,
// wPd = w^T Sigma^-1 d and halfDPd = d^T Sigma^-1 d / 2.
Vec3d integralFromTerms(const SegmentGaussian& g, const Vec3d& d, const Vec3d& direction, double c2, double wPd,
                        double halfDPd, const Vec3d& sigmaT, double a, double b) {
    const Sym3& precision = g.precision;
    const double rootC2 = std::sqrt(c2);
    const double scale = kSqrtPi / (2.0 * rootC2);
    const bool bInfinite = std::isinf(b);
    // The sigma_t-free parts of segmentIntegral's logIntegrand at a and b and
    // of its logPeak, in the same order of operations so that both give the
    // same values; the first two only where a tail needs them.
    const auto quadraticA = [&] { return g.logNormaliser - 0.5 * precision.quadratic(d + a * direction); };
    const auto quadraticB = [&] { return g.logNormaliser - 0.5 * precision.quadratic(d + b * direction); };
    const auto channel = [&](double sigma) {
        const double c3 = wPd + sigma;
        const double za = rootC2 * a + c3 / (2.0 * rootC2);
        const double zb = bInfinite ? std::numeric_limits<double>::infinity() : rootC2 * b + c3 / (2.0 * rootC2);
        if (za >= 0.0) {
            const double lower = std::exp(quadraticA() - sigma * a) * erfcx(za);
            const double upper = bInfinite ? 0.0 : std::exp(quadraticB() - sigma * b) * erfcx(zb);
            return scale * (lower - upper);
        }
        if (zb <= 0.0)
            return scale *
                   (std::exp(quadraticB() - sigma * b) * erfcx(-zb) - std::exp(quadraticA() - sigma * a) * erfcx(-za));
        const double logPeak = g.logNormaliser + c3 * c3 / (4.0 * c2) - halfDPd;
        const double upperErf = bInfinite ? 1.0 : erfSaturated(zb);
        return scale * std::exp(logPeak) * (upperErf - erfSaturated(za));
    };
    const double red = channel(sigmaT.x);
    const double green = sigmaT.y == sigmaT.x ? red : channel(sigmaT.y);
    const double blue = sigmaT.z == sigmaT.x ? red : sigmaT.z == sigmaT.y ? green : channel(sigmaT.z);
    return {red, green, blue};
}

}  // namespace

Vec3d segmentIntegralRgb(const SegmentGaussian& g, const Vec3d& origin, const Vec3d& direction, const Vec3d& sigmaT,
                         double a, double b) {
    if (!(b > a)) return Vec3d(0.0);
    const Vec3d d = origin - g.mean;
    const Vec3d pw = g.precision * direction;
    const double c2 = 0.5 * glm::dot(direction, pw);
    const double wPd = glm::dot(pw, d);
    return integralFromTerms(g, d, direction, c2, wPd, 0.5 * g.precision.quadratic(d), sigmaT, a, b);
}

bool truncatedSegmentIntegralRgb(const SegmentGaussian& g, double radiusSquared, const Vec3d& origin,
                                 const Vec3d& direction, const Vec3d& sigmaT, double a, double b, Vec3d& integral) {
    if (!(b > a)) return false;
    const Sym3& precision = g.precision;
    const Vec3d d = origin - g.mean;
    const Vec3d pw = precision * direction;
    const double c2 = 0.5 * glm::dot(direction, pw);
    const double wPd = glm::dot(pw, d);
    const double halfDPd = 0.5 * precision.quadratic(d);
    // Half the Mahalanobis distance squared beyond the truncation,
    // q(t) = (m(t) - r^2) / 2 = c2 t^2 + wPd t + q(0): the ellipsoid is where
    // q <= 0. Decided without a division or a square root, which dominated
    // this test's cost: the line misses when min q = q(0) - wPd^2 / 4 c2 > 0,
    // and [a, b] misses the chord when the peak -wPd / 2 c2 lies outside it
    // and q > 0 at the nearer end.
    const double outside = halfDPd - 0.5 * radiusSquared;
    if (!(4.0 * c2 * outside <= wPd * wPd)) return false;
    const auto q = [&](double t) { return (c2 * t + wPd) * t + outside; };
    if (-wPd < 2.0 * c2 * a) {
        if (q(a) > 0.0) return false;
    } else if (-wPd > 2.0 * c2 * b && q(b) > 0.0) {
        return false;
    }
    // integralFromTerms with one division for the three quotients by
    // sqrt(C2) (the same values up to rounding).
    const double rootC2 = std::sqrt(c2);
    const double halfInverseRoot = 0.5 / rootC2;
    const double scale = kSqrtPi * halfInverseRoot;
    const bool bInfinite = std::isinf(b);
    const auto channel = [&](double sigma) {
        const double shift = (wPd + sigma) * halfInverseRoot;  // C3 / 2 sqrt(C2)
        const double za = rootC2 * a + shift;
        const double zb = bInfinite ? std::numeric_limits<double>::infinity() : rootC2 * b + shift;
        if (za >= 0.0) {
            const double lower =
                std::exp(g.logNormaliser - 0.5 * precision.quadratic(d + a * direction) - sigma * a) * erfcx(za);
            const double upper =
                bInfinite ? 0.0
                          : std::exp(g.logNormaliser - 0.5 * precision.quadratic(d + b * direction) - sigma * b) *
                                erfcx(zb);
            return scale * (lower - upper);
        }
        if (zb <= 0.0)
            return scale *
                   (std::exp(g.logNormaliser - 0.5 * precision.quadratic(d + b * direction) - sigma * b) * erfcx(-zb) -
                    std::exp(g.logNormaliser - 0.5 * precision.quadratic(d + a * direction) - sigma * a) * erfcx(-za));
        const double logPeak = g.logNormaliser + shift * shift - halfDPd;
        const double upperErf = bInfinite ? 1.0 : erfSaturated(zb);
        return scale * std::exp(logPeak) * (upperErf - erfSaturated(za));
    };
    const double red = channel(sigmaT.x);
    const double green = sigmaT.y == sigmaT.x ? red : channel(sigmaT.y);
    const double blue = sigmaT.z == sigmaT.x ? red : sigmaT.z == sigmaT.y ? green : channel(sigmaT.z);
    integral = {red, green, blue};
    return true;
}

}  // namespace fg::gmm
