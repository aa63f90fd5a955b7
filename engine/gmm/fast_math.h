// exp, erfc(x) e^{x^2} and erf in double precision as straight-line SSE2 code
// on two doubles at once (the x86-64 baseline; no calls, no table lookups, no
// branches), with scalar forms that run the same operations in one lane and
// so give the same values. They replace the C library's functions where a
// renderer evaluates Eqs. 16-17 of Jakob et al. 2011 for many Gaussians at
// once (engine/gmm/segment_batch.h). Accuracy, checked against std::exp and
// std::erfc on dense grids in tests/engine/gmm/test_fast_math.cpp:
//   fastExp        relative error below 1e-9 on [-708, 709];
//   erfcxPositive  relative error below 1.3e-7 on [0, inf);
//   erfPositive    relative error below 1.3e-7 on [0, inf).
// Each Gaussian's Eq. 16 value is thus off by about 1e-7 of itself, four
// orders of magnitude below the truncation delta = 1e-3 of the energy that
// gmm_bbh already accepts for the same pictures.
#pragma once

#include <emmintrin.h>

namespace fg::gmm {

namespace simd {

using Double2 = __m128d;

inline Double2 broadcast(double x) { return _mm_set1_pd(x); }
inline Double2 select(Double2 mask, Double2 ifTrue, Double2 ifFalse) {
    return _mm_or_pd(_mm_and_pd(mask, ifTrue), _mm_andnot_pd(mask, ifFalse));
}
inline Double2 multiplyAdd(Double2 a, Double2 b, double c) { return _mm_add_pd(_mm_mul_pd(a, b), broadcast(c)); }

// e^x: x = n ln 2 + r with |r| <= ln 2 / 2 (Cody and Waite's two-part ln 2, so
// that r carries no rounding error of n ln 2), e^r by its Taylor series to r^8
// (remainder below 3e-10 of e^r), times 2^n as 2^(n/2) 2^(n - n/2), two
// normal powers whose exponent bits are built directly, so that results that
// are subnormal or below the smallest subnormal round as a multiplication
// would (0 from about -745 on). Arguments are clamped to [-746, 709]: e^x for
// x > 709 (+inf included) is e^709; NaN gives NaN.
inline Double2 exp(Double2 x) {
    const double kLog2E = 1.4426950408889634074;
    const double kLn2High = 6.93145751953125e-1;      // 22 significant bits: n ln2High is exact
    const double kLn2Low = 1.42860682030941723212e-6;  // ln 2 - kLn2High
    const Double2 roundShift = broadcast(6755399441055744.0);  // 1.5 * 2^52: adding it rounds to an integer
    const Double2 clamped = _mm_min_pd(_mm_max_pd(x, broadcast(-746.0)), broadcast(709.0));
    const Double2 n = _mm_sub_pd(_mm_add_pd(_mm_mul_pd(clamped, broadcast(kLog2E)), roundShift), roundShift);
    const Double2 r =
        _mm_sub_pd(_mm_sub_pd(clamped, _mm_mul_pd(n, broadcast(kLn2High))), _mm_mul_pd(n, broadcast(kLn2Low)));
    Double2 p = broadcast(1.0 / 40320.0);
    p = multiplyAdd(p, r, 1.0 / 5040.0);
    p = multiplyAdd(p, r, 1.0 / 720.0);
    p = multiplyAdd(p, r, 1.0 / 120.0);
    p = multiplyAdd(p, r, 1.0 / 24.0);
    p = multiplyAdd(p, r, 1.0 / 6.0);
    p = multiplyAdd(p, r, 0.5);
    p = multiplyAdd(p, r, 1.0);
    p = multiplyAdd(p, r, 1.0);
    // An integer m below 2^51 in magnitude sits in the low bits of m +
    // roundShift; 2^m has m + 1023 in the exponent field.
    const auto powerOfTwo = [&](Double2 m) {
        const __m128i bits =
            _mm_sub_epi64(_mm_castpd_si128(_mm_add_pd(m, roundShift)), _mm_castpd_si128(roundShift));
        return _mm_castsi128_pd(_mm_slli_epi64(_mm_add_epi64(bits, _mm_set1_epi64x(1023)), 52));
    };
    const Double2 half = _mm_sub_pd(_mm_add_pd(_mm_mul_pd(n, broadcast(0.5)), roundShift), roundShift);
    return _mm_mul_pd(_mm_mul_pd(p, powerOfTwo(half)), powerOfTwo(_mm_sub_pd(n, half)));
}

// With t = 1 / (1 + x / 2), erfc(x) = t e^{-x^2 + P(t)} for x >= 0, P the
// degree-9 Chebyshev-fitted polynomial of Press et al., Numerical Recipes
// (2nd ed.) §6.2, fractional error below 1.2e-7 everywhere. Returns t.
inline Double2 erfcVariable(Double2 x) {
    return _mm_div_pd(broadcast(1.0), _mm_add_pd(broadcast(1.0), _mm_mul_pd(broadcast(0.5), x)));
}
// P(t).
inline Double2 erfcExponentPolynomial(Double2 t) {
    Double2 p = broadcast(0.17087277);
    p = multiplyAdd(p, t, -0.82215223);
    p = multiplyAdd(p, t, 1.48851587);
    p = multiplyAdd(p, t, -1.13520398);
    p = multiplyAdd(p, t, 0.27886807);
    p = multiplyAdd(p, t, -0.18628806);
    p = multiplyAdd(p, t, 0.09678418);
    p = multiplyAdd(p, t, 0.37409196);
    p = multiplyAdd(p, t, 1.00002368);
    p = multiplyAdd(p, t, -1.26551223);
    return p;
}

// erf(x) by its Maclaurin series to x^19, for 0 <= x < 1/2, where 1 - erfc(x)
// would lose erfc's relative accuracy to cancellation (the next term is below
// 1e-13 of the sum at x = 1/2).
inline Double2 erfSeries(Double2 x) {
    const Double2 x2 = _mm_mul_pd(x, x);
    // Coefficients (-1)^n / (n! (2n + 1)).
    Double2 series = broadcast(-1.0 / 6894720.0);
    series = multiplyAdd(series, x2, 1.0 / 685440.0);
    series = multiplyAdd(series, x2, -1.0 / 75600.0);
    series = multiplyAdd(series, x2, 1.0 / 9360.0);
    series = multiplyAdd(series, x2, -1.0 / 1320.0);
    series = multiplyAdd(series, x2, 1.0 / 216.0);
    series = multiplyAdd(series, x2, -1.0 / 42.0);
    series = multiplyAdd(series, x2, 1.0 / 10.0);
    series = multiplyAdd(series, x2, -1.0 / 3.0);
    series = multiplyAdd(series, x2, 1.0);
    return _mm_mul_pd(_mm_mul_pd(broadcast(1.1283791670955125739), x), series);  // 2 / sqrt(pi)
}
constexpr double kErfSeriesBelow = 0.5;

// erfc(x) e^{x^2} for x >= 0 (+inf gives 0).
inline Double2 erfcxPositive(Double2 x) {
    const Double2 t = erfcVariable(x);
    return _mm_mul_pd(t, exp(erfcExponentPolynomial(t)));
}

// erf(x) for x >= 0 (+inf gives 1).
inline Double2 erfPositive(Double2 x) {
    const Double2 t = erfcVariable(x);
    const Double2 large = _mm_sub_pd(
        broadcast(1.0), _mm_mul_pd(t, exp(_mm_sub_pd(erfcExponentPolynomial(t), _mm_mul_pd(x, x)))));
    return select(_mm_cmplt_pd(x, broadcast(kErfSeriesBelow)), erfSeries(x), large);
}

}  // namespace simd

// One-lane forms of the above (the same operations, so the same values).
inline double fastExp(double x) { return _mm_cvtsd_f64(simd::exp(_mm_set1_pd(x))); }
inline double erfcxPositive(double x) { return _mm_cvtsd_f64(simd::erfcxPositive(_mm_set1_pd(x))); }
inline double erfPositive(double x) { return _mm_cvtsd_f64(simd::erfPositive(_mm_set1_pd(x))); }

}  // namespace fg::gmm
