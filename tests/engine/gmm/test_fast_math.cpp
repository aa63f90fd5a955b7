// The straight-line exp, erfc and erf of engine/gmm/fast_math.h against the C
// library on dense grids over the ranges the Gaussian renderer feeds them.
#include "engine/gmm/fast_math.h"

#include "engine/gmm/gaussian.h"

#include <gtest/gtest.h>

#include <cmath>

#if defined(__SSE__) || defined(_M_X64)
#include <xmmintrin.h>
#endif

namespace fg::gmm {
namespace {

// Parallel loops leave the calling thread in flush-to-zero mode
// (jobs::useDeterministicFloatMode), so whether a subnormal result survives
// depends on which tests ran before; the subnormal checks set the mode they
// mean and put the caller's back.
class FloatModeScope {
public:
    explicit FloatModeScope(bool flushSubnormals) {
#if defined(__SSE__) || defined(_M_X64)
        constexpr unsigned kFlushAndDenormalsAreZero = (1u << 15) | (1u << 6);
        saved_ = _mm_getcsr();
        _mm_setcsr(flushSubnormals ? saved_ | kFlushAndDenormalsAreZero : saved_ & ~kFlushAndDenormalsAreZero);
#else
        (void)flushSubnormals;
#endif
    }
    ~FloatModeScope() {
#if defined(__SSE__) || defined(_M_X64)
        _mm_setcsr(saved_);
#endif
    }
    FloatModeScope(const FloatModeScope&) = delete;
    FloatModeScope& operator=(const FloatModeScope&) = delete;

private:
    unsigned saved_ = 0;
};

double relativeError(double value, double reference) { return std::abs(value / reference - 1.0); }

TEST(GmmFastMath, ExpMatchesTheLibraryOnADenseGrid) {
    double worst = 0.0;
    for (double x = -708.0; x <= 709.0; x += 0.0137) worst = std::max(worst, relativeError(fastExp(x), std::exp(x)));
    for (double x = -1.0; x <= 1.0; x += 1.1e-5) worst = std::max(worst, relativeError(fastExp(x), std::exp(x)));
    EXPECT_LT(worst, 1e-9);
    EXPECT_GT(worst, 0.0);  // an approximation, so the grid does reach it
    EXPECT_EQ(fastExp(0.0), 1.0);
    // Far below the smallest subnormal, and -inf: exactly 0, no NaN.
    EXPECT_EQ(fastExp(-800.0), 0.0);
    EXPECT_EQ(fastExp(-std::numeric_limits<double>::infinity()), 0.0);
}

TEST(GmmFastMath, ExpOfSubnormalResultsFollowsTheFloatMode) {
    {
        // Without flushing, subnormal results keep a few digits rather than vanishing.
        const FloatModeScope gradualUnderflow(false);
        EXPECT_NEAR(fastExp(-720.0) / std::exp(-720.0), 1.0, 1e-6);
    }
#if defined(__SSE__) || defined(_M_X64)
    {
        // In the mode every job runs in they are exactly zero, never NaN.
        const FloatModeScope flushToZero(true);
        EXPECT_EQ(fastExp(-720.0), 0.0);
        EXPECT_EQ(fastExp(-800.0), 0.0);
    }
#endif
}

TEST(GmmFastMath, ErfcxMatchesTheLibraryOnADenseGrid) {
    double worst = 0.0;
    for (double x = 0.0; x <= 40.0; x += 1.3e-4) worst = std::max(worst, relativeError(erfcxPositive(x), erfcx(x)));
    EXPECT_LT(worst, 1.3e-7);
    EXPECT_EQ(erfcxPositive(std::numeric_limits<double>::infinity()), 0.0);
}

TEST(GmmFastMath, ErfMatchesTheLibraryOnADenseGrid) {
    double worst = 0.0;
    // Down to tiny arguments, where 1 - erfc would cancel.
    for (double x = 1e-9; x <= 1.0; x *= 1.01) worst = std::max(worst, relativeError(erfPositive(x), std::erf(x)));
    for (double x = 0.0; x <= 8.0; x += 1.1e-5) {
        if (x > 0.0) worst = std::max(worst, relativeError(erfPositive(x), std::erf(x)));
    }
    EXPECT_LT(worst, 1.3e-7);
    EXPECT_EQ(erfPositive(0.0), 0.0);
    EXPECT_EQ(erfPositive(std::numeric_limits<double>::infinity()), 1.0);
}

}  // namespace
}  // namespace fg::gmm
