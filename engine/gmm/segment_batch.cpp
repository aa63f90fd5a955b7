// Eqs. 15-17 of Jakob et al. 2011 for a batch of Gaussians along one segment;
// see segment_batch.h.
#include "engine/gmm/segment_batch.h"

#include "engine/gmm/fast_math.h"

#include <array>
#include <cmath>
#include <cstdint>
#include <limits>

namespace fg::gmm {

void SegmentBatch::begin(const Vec3d& origin, const Vec3d& direction, double length) {
    origin_ = origin;
    direction_ = direction;
    length_ = length;
    infinite_ = std::isinf(length);
    empty_ = !(length > 0.0);
    count_ = 0;
}

void SegmentBatch::keep(const SegmentGaussian& g, double c2, double wPd, double halfDPd, const Vec3d& power) {
    // Room for one more and for the pad sum may add.
    if (count_ + 2 > c2_.size()) {
        const std::size_t capacity = 2 * (count_ + 2);
        for (std::vector<double>* column : {&c2_, &rootC2_, &wPd_, &halfDPd_, &logNormaliser_, &powerRed_,
                                            &powerGreen_, &powerBlue_, &integral_, &peak_})
            column->resize(capacity);
    }
    c2_[count_] = c2;
    // Here rather than in integrate: SSE2 has a square root, but doing it
    // once per Gaussian costs no more.
    rootC2_[count_] = std::sqrt(c2);
    wPd_[count_] = wPd;
    halfDPd_[count_] = halfDPd;
    logNormaliser_[count_] = g.logNormaliser;
    powerRed_[count_] = power.x;
    powerGreen_[count_] = power.y;
    powerBlue_[count_] = power.z;
    ++count_;
}

namespace {

// d = origin - mean, Sigma^-1 w, C2, w^T Sigma^-1 d and d^T Sigma^-1 d / 2,
// written out so that they inline (Sym3's operators live in gaussian.cpp).
struct SegmentTerms {
    double c2, wPd, halfDPd;
};
SegmentTerms segmentTerms(const SegmentGaussian& g, const Vec3d& origin, const Vec3d& w) {
    const std::array<double, 6>& p = g.precision.v;
    const Vec3d d = origin - g.mean;
    const Vec3d pw(p[0] * w.x + p[1] * w.y + p[2] * w.z, p[1] * w.x + p[3] * w.y + p[4] * w.z,
                   p[2] * w.x + p[4] * w.y + p[5] * w.z);
    const Vec3d pd(p[0] * d.x + p[1] * d.y + p[2] * d.z, p[1] * d.x + p[3] * d.y + p[4] * d.z,
                   p[2] * d.x + p[4] * d.y + p[5] * d.z);
    return {0.5 * glm::dot(w, pw), glm::dot(pw, d), 0.5 * glm::dot(pd, d)};
}

}  // namespace

void SegmentBatch::add(const SegmentGaussian& g, const Vec3d& power) {
    if (empty_) return;
    const SegmentTerms terms = segmentTerms(g, origin_, direction_);
    keep(g, terms.c2, terms.wPd, terms.halfDPd, power);
}

bool SegmentBatch::addTruncated(const SegmentGaussian& g, double radiusSquared, const Vec3d& power) {
    if (empty_) return false;
    const SegmentTerms terms = segmentTerms(g, origin_, direction_);
    const double c2 = terms.c2, wPd = terms.wPd;
    // As in truncatedSegmentIntegralRgb: q(t) = c2 t^2 + wPd t + outside is
    // half the Mahalanobis distance squared beyond the truncation; the line
    // misses the ellipsoid when min q > 0, [0, length] misses the chord when
    // q's minimum lies outside it and q > 0 at the nearer end.
    const double outside = terms.halfDPd - 0.5 * radiusSquared;
    if (!(4.0 * c2 * outside <= wPd * wPd)) return false;
    if (-wPd < 0.0) {
        if (outside > 0.0) return false;
    } else if (-wPd > 2.0 * c2 * length_ && (c2 * length_ + wPd) * length_ + outside > 0.0) {
        return false;
    }
    keep(g, c2, wPd, terms.halfDPd, power);
    return true;
}

void SegmentBatch::integrate(double sigmaT) {
    using namespace simd;
    constexpr double kSqrtPi = 1.7724538509055160273;
    // erf(x) = 1 - erfc(x) is taken as 1 from here on: erfc(4) = 1.5e-8, below
    // the error of the erfc approximation itself (fast_math.h).
    constexpr double kErfIsOne = 4.0;
    const std::size_t n = count_ + count_ % 2;  // sum pads odd counts
    // An infinite segment as a zero-length one whose end is moved to +inf by
    // an added constant: arithmetic instead of a branch.
    const Double2 length = broadcast(infinite_ ? 0.0 : length_);
    const Double2 endOffset = broadcast(infinite_ ? std::numeric_limits<double>::infinity() : 0.0);
    const Double2 sigma = broadcast(sigmaT);
    const Double2 zero = _mm_setzero_pd();
    const Double2 signBit = broadcast(-0.0);
    const Double2 seriesBelow = broadcast(kErfSeriesBelow);
    const Double2 erfIsOne = broadcast(kErfIsOne);
    // With z(t) = sqrt(C2) t + C3 / 2 sqrt(C2) and l(t) = log N - C1 - C3 t -
    // C2 t^2 (the integrand's log), segmentIntegral's cases are: the integral
    // is sqrt(pi) / (2 sqrt(C2)) times
    //   E(0) - E(len)                   if z(0) >= 0,   E(t) = e^{l(t)} erfcx(|z(t)|),
    //   E(len) - E(0)                   if z(len) <= 0,
    //   P erf(|z(0)|) + P erf(|z(len)|) otherwise,     P = e^{C3^2 / 4 C2 - C1 + log N},
    // where P erf(|z|) = P - E (P e^{-z^2} = e^{l}) unless |z| is small.
    // Mostly a segment crosses a Gaussian from well before its peak to well
    // after it (both erf are 1, the integral is 2P times the factor): a first
    // pass computes that, two Gaussians at a time, and lists the others,
    // which a second pass evaluates in full, every case computed for both
    // lanes and the right one selected.
    struct Lanes {
        Double2 halfInverseRoot, shift, zEnd, logStart, logPeak;
    };
    const auto lanes = [&](Double2 wPd, Double2 rootC2, Double2 logNormaliser, Double2 halfDPd) {
        Lanes l;
        l.halfInverseRoot = _mm_div_pd(broadcast(0.5), rootC2);
        l.shift = _mm_mul_pd(_mm_add_pd(wPd, sigma), l.halfInverseRoot);  // C3 / 2 sqrt(C2) = z(0)
        l.zEnd = _mm_add_pd(_mm_add_pd(_mm_mul_pd(rootC2, length), l.shift), endOffset);
        l.logStart = _mm_sub_pd(logNormaliser, halfDPd);
        l.logPeak = _mm_add_pd(l.logStart, _mm_mul_pd(l.shift, l.shift));
        return l;
    };
    pending_.clear();
    for (std::size_t i = 0; i < n; i += 2) {
        const Lanes l = lanes(_mm_loadu_pd(wPd_.data() + i),
                              _mm_loadu_pd(rootC2_.data() + i), _mm_loadu_pd(logNormaliser_.data() + i),
                              _mm_loadu_pd(halfDPd_.data() + i));
        const Double2 crossed = _mm_and_pd(_mm_cmple_pd(l.shift, _mm_sub_pd(zero, erfIsOne)),
                                           _mm_cmpge_pd(l.zEnd, erfIsOne));
        const Double2 peak = exp(l.logPeak);
        _mm_storeu_pd(peak_.data() + i, peak);
        _mm_storeu_pd(integral_.data() + i,
                      _mm_mul_pd(_mm_mul_pd(broadcast(kSqrtPi), l.halfInverseRoot), _mm_add_pd(peak, peak)));
        const int mask = _mm_movemask_pd(crossed);
        if ((mask & 1) == 0) pending_.push_back(static_cast<std::uint32_t>(i));
        if ((mask & 2) == 0) pending_.push_back(static_cast<std::uint32_t>(i + 1));
    }
    const auto gather = [](const std::vector<double>& column, std::uint32_t first, std::uint32_t second) {
        return _mm_set_pd(column[second], column[first]);
    };
    for (std::size_t k = 0; k < pending_.size(); k += 2) {
        const std::uint32_t first = pending_[k];
        const std::uint32_t second = k + 1 < pending_.size() ? pending_[k + 1] : first;
        const Double2 c2 = gather(c2_, first, second);
        const Double2 wPd = gather(wPd_, first, second);
        const Lanes l = lanes(wPd, gather(rootC2_, first, second), gather(logNormaliser_, first, second),
                              gather(halfDPd_, first, second));
        const Double2 zStart = l.shift;
        // l(len) = l(0) - len (w^T Sigma^-1 d + C2 len) - sigma_t len.
        const Double2 logEnd = _mm_sub_pd(
            _mm_sub_pd(_mm_sub_pd(l.logStart, _mm_mul_pd(length, _mm_add_pd(wPd, _mm_mul_pd(c2, length)))),
                       _mm_mul_pd(sigma, length)),
            endOffset);
        const Double2 uStart = _mm_andnot_pd(signBit, zStart);
        const Double2 uEnd = _mm_andnot_pd(signBit, l.zEnd);
        const Double2 tStart = erfcVariable(uStart);
        const Double2 tEnd = erfcVariable(uEnd);
        const Double2 eStart = _mm_mul_pd(tStart, exp(_mm_add_pd(l.logStart, erfcExponentPolynomial(tStart))));
        const Double2 eEnd = _mm_mul_pd(tEnd, exp(_mm_add_pd(logEnd, erfcExponentPolynomial(tEnd))));
        const Double2 peak = gather(peak_, first, second);
        const Double2 tail =
            select(_mm_cmpge_pd(zStart, zero), _mm_sub_pd(eStart, eEnd), _mm_sub_pd(eEnd, eStart));
        const Double2 startSmall = _mm_cmplt_pd(uStart, seriesBelow);
        const Double2 endSmall = _mm_cmplt_pd(uEnd, seriesBelow);
        Double2 startPart = _mm_sub_pd(peak, eStart);
        Double2 endPart = _mm_sub_pd(peak, eEnd);
        if (_mm_movemask_pd(_mm_or_pd(startSmall, endSmall)) != 0) {
            startPart = select(startSmall, _mm_mul_pd(peak, erfSeries(uStart)), startPart);
            endPart = select(endSmall, _mm_mul_pd(peak, erfSeries(uEnd)), endPart);
        }
        const Double2 peakInside = _mm_and_pd(_mm_cmplt_pd(zStart, zero), _mm_cmpgt_pd(l.zEnd, zero));
        const Double2 value = select(peakInside, _mm_add_pd(startPart, endPart), tail);
        alignas(16) double result[2];
        _mm_store_pd(result, _mm_mul_pd(_mm_mul_pd(broadcast(kSqrtPi), l.halfInverseRoot), value));
        integral_[first] = result[0];
        integral_[second] = result[1];
    }
}

Vec3d SegmentBatch::sum(const Vec3d& sigmaT) {
    const std::size_t n = count_;
    Vec3d total(0.0);
    if (n == 0) return total;
    if (n % 2 != 0) {
        keep(SegmentGaussian(), 0.5, 0.0, 0.0, Vec3d(0.0));  // a harmless second lane
        --count_;
    }
    // Grey media (all three coefficients equal) integrate once.
    integrate(sigmaT.x);
    for (std::size_t i = 0; i < n; ++i) total.x += powerRed_[i] * integral_[i];
    if (sigmaT.y != sigmaT.x) integrate(sigmaT.y);
    for (std::size_t i = 0; i < n; ++i) total.y += powerGreen_[i] * integral_[i];
    if (sigmaT.z != sigmaT.y) integrate(sigmaT.z);
    for (std::size_t i = 0; i < n; ++i) total.z += powerBlue_[i] * integral_[i];
    return total;
}

}  // namespace fg::gmm
