// The straight-line exp, erfc and erf of engine/gmm/fast_math.h against the C
// library on dense grids over the ranges the Gaussian renderer feeds them.
#include "engine/gmm/fast_math.h"

#include "engine/gmm/gaussian.h"

#include <gtest/gtest.h>

#include <cmath>

namespace fg::gmm {
namespace {

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
    // Subnormal results keep a few digits rather than vanishing.
    EXPECT_NEAR(fastExp(-720.0) / std::exp(-720.0), 1.0, 1e-6);
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
