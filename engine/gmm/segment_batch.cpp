// Eqs. 15-17 of Jakob et al. 2011 for a batch of Gaussians along one segment;
// see segment_batch.h.
#include "engine/gmm/segment_batch.h"

#include "engine/gmm/fast_math.h"

#include <array>
#include <cmath>
#include <cstddef>
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

void SegmentBatch::reserve(std::size_t more) {
    if (count_ + more + 1 <= c2_.size()) return;
    const std::size_t capacity = 2 * (count_ + more + 1);
    for (std::vector<double>* column : {&c2_, &rootC2_, &wPd_, &halfDPd_, &logNormaliser_, &powerRed_, &powerGreen_,
                                        &powerBlue_, &integral_, &peak_})
        column->resize(capacity);
}

void SegmentBatch::add(const SegmentGaussian& g, const Vec3d& power) {
    const PackedGaussian record(g, 0.0, power);
    const std::uint32_t first = 0;
    addAll({&record, 1}, {&first, 1}, false);
}

bool SegmentBatch::addTruncated(const SegmentGaussian& g, double radiusSquared, const Vec3d& power) {
    const PackedGaussian record(g, radiusSquared, power);
    const std::uint32_t first = 0;
    return addAll({&record, 1}, {&first, 1}, true) == 1;
}

std::size_t SegmentBatch::addAll(std::span<const PackedGaussian> records, std::span<const std::uint32_t> indices,
                                 bool truncate) {
    using namespace simd;
    if (empty_ || indices.empty()) return 0;
    reserve(indices.size() + 1);
    const std::size_t before = count_;
    const Vec3d& o = origin_;
    const Vec3d& w = direction_;
    // C2 = w^T Sigma^-1 w / 2 as the six precision entries dotted with the
    // direction's products (one multiplication and addition per entry instead
    // of the nine and six of Sigma^-1 w and the three and two of the dot).
    const Double2 wxx = broadcast(0.5 * w.x * w.x), wyy = broadcast(0.5 * w.y * w.y), wzz = broadcast(0.5 * w.z * w.z);
    const Double2 wxy = broadcast(w.x * w.y), wxz = broadcast(w.x * w.z), wyz = broadcast(w.y * w.z);
    const Double2 wx = broadcast(w.x), wy = broadcast(w.y), wz = broadcast(w.z);
    const Double2 ox = broadcast(o.x), oy = broadcast(o.y), oz = broadcast(o.z);
    const Double2 length = broadcast(length_);
    const Double2 zero = _mm_setzero_pd();
    const Double2 half = broadcast(0.5);
    // Transposes field pair `offset` (in doubles) of two records into a pair
    // of lanes: (first's, second's) of the pair's first and second field.
    const auto pair = [](const PackedGaussian& a, const PackedGaussian& b, std::size_t offset, Double2& first,
                         Double2& second) {
        const Double2 fromA = _mm_loadu_pd(reinterpret_cast<const double*>(&a) + offset);
        const Double2 fromB = _mm_loadu_pd(reinterpret_cast<const double*>(&b) + offset);
        first = _mm_unpacklo_pd(fromA, fromB);
        second = _mm_unpackhi_pd(fromA, fromB);
    };
    static_assert(offsetof(PackedGaussian, meanX) == 0 && offsetof(PackedGaussian, meanZ) == 16 &&
                  offsetof(PackedGaussian, radiusSquared) == 24 && offsetof(PackedGaussian, precision) == 32);
    for (std::size_t k = 0; k < indices.size(); k += 2) {
        const PackedGaussian& a = records[indices[k]];
        const PackedGaussian& b = records[indices[k + 1 < indices.size() ? k + 1 : k]];
        Double2 mx, my, mz, radiusSquared, p0, p1, p2, p3, p4, p5;
        pair(a, b, 0, mx, my);
        pair(a, b, 2, mz, radiusSquared);
        pair(a, b, 4, p0, p1);
        pair(a, b, 6, p2, p3);
        pair(a, b, 8, p4, p5);
        const Double2 dx = _mm_sub_pd(ox, mx), dy = _mm_sub_pd(oy, my), dz = _mm_sub_pd(oz, mz);
        const Double2 pdx = _mm_add_pd(_mm_add_pd(_mm_mul_pd(p0, dx), _mm_mul_pd(p1, dy)), _mm_mul_pd(p2, dz));
        const Double2 pdy = _mm_add_pd(_mm_add_pd(_mm_mul_pd(p1, dx), _mm_mul_pd(p3, dy)), _mm_mul_pd(p4, dz));
        const Double2 pdz = _mm_add_pd(_mm_add_pd(_mm_mul_pd(p2, dx), _mm_mul_pd(p4, dy)), _mm_mul_pd(p5, dz));
        const Double2 wPd = _mm_add_pd(_mm_add_pd(_mm_mul_pd(wx, pdx), _mm_mul_pd(wy, pdy)), _mm_mul_pd(wz, pdz));
        const Double2 halfDPd = _mm_mul_pd(
            half, _mm_add_pd(_mm_add_pd(_mm_mul_pd(dx, pdx), _mm_mul_pd(dy, pdy)), _mm_mul_pd(dz, pdz)));
        const Double2 c2 = _mm_add_pd(
            _mm_add_pd(_mm_add_pd(_mm_mul_pd(p0, wxx), _mm_mul_pd(p3, wyy)), _mm_mul_pd(p5, wzz)),
            _mm_add_pd(_mm_add_pd(_mm_mul_pd(p1, wxy), _mm_mul_pd(p2, wxz)), _mm_mul_pd(p4, wyz)));
        int kept = 3;
        if (truncate) {
            // As in truncatedSegmentIntegralRgb: q(t) = c2 t^2 + wPd t + outside
            // is half the Mahalanobis distance squared beyond the truncation;
            // the line misses the ellipsoid when min q > 0, [0, length] misses
            // the chord when q's minimum lies outside it and q > 0 at the
            // nearer end (with an infinite length minimumBeyond is false).
            const Double2 outside = _mm_sub_pd(halfDPd, _mm_mul_pd(half, radiusSquared));
            const Double2 lineMeets =
                _mm_cmple_pd(_mm_mul_pd(_mm_mul_pd(broadcast(4.0), c2), outside), _mm_mul_pd(wPd, wPd));
            const Double2 minimumBehind = _mm_cmpgt_pd(wPd, zero);
            const Double2 startOutside = _mm_cmpgt_pd(outside, zero);
            const Double2 minimumBeyond =
                _mm_cmpgt_pd(_mm_sub_pd(zero, wPd), _mm_mul_pd(_mm_add_pd(c2, c2), length));
            const Double2 endOutside = _mm_cmpgt_pd(
                _mm_add_pd(_mm_mul_pd(_mm_add_pd(_mm_mul_pd(c2, length), wPd), length), outside), zero);
            const Double2 missed = _mm_or_pd(_mm_and_pd(minimumBehind, startOutside),
                                             _mm_andnot_pd(minimumBehind, _mm_and_pd(minimumBeyond, endOutside)));
            kept = _mm_movemask_pd(_mm_andnot_pd(missed, lineMeets));
        }
        if (k + 1 >= indices.size()) kept &= 1;
        const Double2 rootC2 = _mm_sqrt_pd(c2);
        // Both lanes are written; the second goes where the first's would,
        // and count_ moves past a lane only if it is kept.
        const auto store = [&](int lane, const PackedGaussian& g) {
            double* row[] = {&c2_[count_], &rootC2_[count_], &wPd_[count_], &halfDPd_[count_]};
            const Double2 values[] = {c2, rootC2, wPd, halfDPd};
            for (std::size_t v = 0; v < 4; ++v) {
                if (lane == 0)
                    _mm_storel_pd(row[v], values[v]);
                else
                    _mm_storeh_pd(row[v], values[v]);
            }
            logNormaliser_[count_] = g.logNormaliser;
            powerRed_[count_] = g.powerRed;
            powerGreen_[count_] = g.powerGreen;
            powerBlue_[count_] = g.powerBlue;
        };
        store(0, a);
        count_ += static_cast<std::size_t>(kept & 1);
        store(1, b);
        count_ += static_cast<std::size_t>(kept >> 1);
    }
    return count_ - before;
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
    // pass computes that, two Gaussians at a time, and lists the others. Of
    // those, the ones whose peak lies inside with one end well away from it
    // (that end's erf is 1) need only the other end's erfc: a second pass
    // evaluates them, one end per lane; a third evaluates the rest in full,
    // every case computed for both lanes and the right one selected.
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
    oneEnd_.clear();
    for (std::size_t i = 0; i < n; i += 2) {
        const Lanes l = lanes(_mm_loadu_pd(wPd_.data() + i),
                              _mm_loadu_pd(rootC2_.data() + i), _mm_loadu_pd(logNormaliser_.data() + i),
                              _mm_loadu_pd(halfDPd_.data() + i));
        const Double2 startFar = _mm_cmple_pd(l.shift, _mm_sub_pd(zero, erfIsOne));
        const Double2 endFar = _mm_cmpge_pd(l.zEnd, erfIsOne);
        const int crossed = _mm_movemask_pd(_mm_and_pd(startFar, endFar));
        const int nearStart = _mm_movemask_pd(_mm_andnot_pd(startFar, _mm_and_pd(endFar, _mm_cmplt_pd(l.shift, zero))));
        const int nearEnd = _mm_movemask_pd(_mm_andnot_pd(endFar, _mm_and_pd(startFar, _mm_cmpgt_pd(l.zEnd, zero))));
        const Double2 peak = exp(l.logPeak);
        _mm_storeu_pd(peak_.data() + i, peak);
        _mm_storeu_pd(integral_.data() + i,
                      _mm_mul_pd(_mm_mul_pd(broadcast(kSqrtPi), l.halfInverseRoot), _mm_add_pd(peak, peak)));
        for (int lane = 0; lane < 2; ++lane) {
            const auto row = static_cast<std::uint32_t>(i) + static_cast<std::uint32_t>(lane);
            if (row >= count_ || ((crossed >> lane) & 1)) continue;  // the pad, or done
            if ((nearStart >> lane) & 1)
                oneEnd_.push_back(row << 1);
            else if ((nearEnd >> lane) & 1)
                oneEnd_.push_back((row << 1) | 1u);
            else
                pending_.push_back(row);
        }
    }
    const auto gather = [](const std::vector<double>& column, std::uint32_t first, std::uint32_t second) {
        return _mm_set_pd(column[second], column[first]);
    };
    // P erf(|z|) at the near end, plus P for the far one.
    for (std::size_t k = 0; k < oneEnd_.size(); k += 2) {
        const std::uint32_t firstItem = oneEnd_[k];
        const std::uint32_t secondItem = k + 1 < oneEnd_.size() ? oneEnd_[k + 1] : firstItem;
        const std::uint32_t first = firstItem >> 1, second = secondItem >> 1;
        const Double2 atEnd = _mm_castsi128_pd(_mm_set_epi64x(-static_cast<std::int64_t>(secondItem & 1u),
                                                              -static_cast<std::int64_t>(firstItem & 1u)));
        const Double2 c2 = gather(c2_, first, second);
        const Double2 wPd = gather(wPd_, first, second);
        const Lanes l = lanes(wPd, gather(rootC2_, first, second), gather(logNormaliser_, first, second),
                              gather(halfDPd_, first, second));
        const Double2 logEnd = _mm_sub_pd(
            _mm_sub_pd(l.logStart, _mm_mul_pd(length, _mm_add_pd(wPd, _mm_mul_pd(c2, length)))),
            _mm_mul_pd(sigma, length));
        const Double2 u = _mm_andnot_pd(signBit, select(atEnd, l.zEnd, l.shift));
        const Double2 t = erfcVariable(u);
        const Double2 e = _mm_mul_pd(t, exp(_mm_add_pd(select(atEnd, logEnd, l.logStart), erfcExponentPolynomial(t))));
        const Double2 peak = gather(peak_, first, second);
        Double2 part = _mm_sub_pd(peak, e);
        const Double2 small = _mm_cmplt_pd(u, seriesBelow);
        if (_mm_movemask_pd(small) != 0) part = select(small, _mm_mul_pd(peak, erfSeries(u)), part);
        alignas(16) double result[2];
        _mm_store_pd(result, _mm_mul_pd(_mm_mul_pd(broadcast(kSqrtPi), l.halfInverseRoot), _mm_add_pd(peak, part)));
        integral_[first] = result[0];
        integral_[second] = result[1];
    }
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
        // A harmless second lane (reserve left room for it).
        c2_[n] = 0.5;
        rootC2_[n] = std::sqrt(0.5);
        wPd_[n] = halfDPd_[n] = logNormaliser_[n] = 0.0;
    }
    integrate(sigmaT.x);
    // Grey media (all three coefficients equal) integrate once and sum the
    // three channels in one loop, each in the same order as apart.
    if (sigmaT.y == sigmaT.x && sigmaT.z == sigmaT.x) {
        for (std::size_t i = 0; i < n; ++i) {
            total.x += powerRed_[i] * integral_[i];
            total.y += powerGreen_[i] * integral_[i];
            total.z += powerBlue_[i] * integral_[i];
        }
        return total;
    }
    for (std::size_t i = 0; i < n; ++i) total.x += powerRed_[i] * integral_[i];
    if (sigmaT.y != sigmaT.x) integrate(sigmaT.y);
    for (std::size_t i = 0; i < n; ++i) total.y += powerGreen_[i] * integral_[i];
    if (sigmaT.z != sigmaT.y) integrate(sigmaT.z);
    for (std::size_t i = 0; i < n; ++i) total.z += powerBlue_[i] * integral_[i];
    return total;
}

}  // namespace fg::gmm
