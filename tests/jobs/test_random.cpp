#include "jobs/random.h"

#include "tests/support/chi2.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <vector>

namespace fg::jobs {
namespace {

std::vector<std::uint32_t> firstValues(Rng rng, int count) {
    std::vector<std::uint32_t> out(static_cast<std::size_t>(count));
    for (auto& v : out) v = rng.nextU32();
    return out;
}

TEST(Rng, SameKeyGivesTheSameSequence) {
    for (std::uint64_t item : {0ull, 1ull, 123456789ull, ~0ull}) {
        const Rng a(42, streamKey("pt"), item);
        const Rng b(42, streamKey("pt"), item);
        EXPECT_EQ(firstValues(a, 256), firstValues(b, 256)) << "item " << item;
    }
}

TEST(Rng, AnyKeyComponentChangesTheSequence) {
    const auto reference = firstValues(Rng(1, 2, 3), 8);
    EXPECT_NE(firstValues(Rng(2, 2, 3), 8), reference);  // seed
    EXPECT_NE(firstValues(Rng(1, 3, 3), 8), reference);  // pass
    EXPECT_NE(firstValues(Rng(1, 2, 4), 8), reference);  // item
    // The components are not interchangeable.
    EXPECT_NE(firstValues(Rng(1, 3, 2), 8), reference);
    EXPECT_NE(firstValues(Rng(3, 2, 1), 8), reference);
    EXPECT_NE(firstValues(Rng(42, streamKey("pt"), 0), 8), firstValues(Rng(42, streamKey("photons"), 0), 8));

    // No two of many neighbouring items share their first value.
    std::vector<std::uint64_t> firsts;
    for (std::uint64_t item = 0; item < 4096; ++item) {
        Rng rng(1, 0, item);
        firsts.push_back((static_cast<std::uint64_t>(rng.nextU32()) << 32) | rng.nextU32());
    }
    std::sort(firsts.begin(), firsts.end());
    EXPECT_EQ(std::adjacent_find(firsts.begin(), firsts.end()), firsts.end());
}

TEST(Rng, StreamKeyIsStableAndDistinguishesNames) {
    static_assert(streamKey("pt") == streamKey("pt"));
    EXPECT_NE(streamKey("pt"), streamKey("tp"));
    EXPECT_NE(streamKey(""), streamKey("a"));
    // FNV-1a of the empty string is its offset basis.
    EXPECT_EQ(streamKey(""), 0xCBF29CE484222325ull);
}

TEST(Rng, UniformIsInTheHalfOpenUnitInterval) {
    float lo = 1.0f, hi = 0.0f;
    for (std::uint64_t item = 0; item < 64; ++item) {
        Rng rng(9, 1, item);
        for (int k = 0; k < 16384; ++k) {
            const float u = rng.uniform();
            ASSERT_GE(u, 0.0f);
            ASSERT_LT(u, 1.0f);
            lo = std::min(lo, u);
            hi = std::max(hi, u);
        }
    }
    EXPECT_LT(lo, 1e-4f);
    EXPECT_GT(hi, 1.0f - 1e-4f);
}

TEST(Rng, Uniform2DrawsTwoConsecutiveValues) {
    Rng a(5, 6, 7), b(5, 6, 7);
    for (int k = 0; k < 10; ++k) {
        const glm::vec2 u = a.uniform2();
        EXPECT_EQ(u.x, b.uniform());
        EXPECT_EQ(u.y, b.uniform());
    }
}

// Pearson's chi-square statistic of `counts` against equal expectation.
double chi2Statistic(const std::vector<double>& counts, double total) {
    const double expected = total / static_cast<double>(counts.size());
    double statistic = 0.0;
    for (double c : counts) statistic += (c - expected) * (c - expected) / expected;
    return statistic;
}

constexpr int kBins = 64;
constexpr double kMinPValue = 1e-3;

TEST(Rng, UniformIsUniformAlongOneStream) {
    Rng rng(11, streamKey("chi2"), 0);
    const int samples = 1 << 20;
    std::vector<double> counts(kBins, 0.0);
    for (int k = 0; k < samples; ++k) counts[static_cast<std::size_t>(rng.uniform() * kBins)] += 1.0;
    const double p = test::chi2Survival(chi2Statistic(counts, samples), kBins - 1);
    EXPECT_GT(p, kMinPValue);
}

TEST(Rng, FirstValuesOfSuccessiveItemsAreUniform) {
    // Items are streams: a pass draws a handful of numbers from each of many, so
    // uniformity across items matters more than along one stream.
    const int items = 1 << 19;
    std::vector<double> first(kBins, 0.0), second(kBins, 0.0);
    for (int item = 0; item < items; ++item) {
        Rng rng(11, streamKey("chi2"), static_cast<std::uint64_t>(item));
        first[static_cast<std::size_t>(rng.uniform() * kBins)] += 1.0;
        second[static_cast<std::size_t>(rng.uniform() * kBins)] += 1.0;
    }
    EXPECT_GT(test::chi2Survival(chi2Statistic(first, items), kBins - 1), kMinPValue);
    EXPECT_GT(test::chi2Survival(chi2Statistic(second, items), kBins - 1), kMinPValue);
}

TEST(Rng, UniformIndexStaysInRangeAndIsUniform) {
    Rng rng(2, 3, 4);
    const std::uint32_t n = 10;
    const int samples = 200000;
    std::vector<double> counts(n, 0.0);
    for (int k = 0; k < samples; ++k) {
        const std::uint32_t i = rng.uniformIndex(n);
        ASSERT_LT(i, n);
        counts[i] += 1.0;
    }
    EXPECT_GT(test::chi2Survival(chi2Statistic(counts, samples), static_cast<int>(n) - 1), kMinPValue);
}

double correlation(const std::vector<double>& x, const std::vector<double>& y) {
    const double n = static_cast<double>(x.size());
    double mx = 0, my = 0;
    for (std::size_t i = 0; i < x.size(); ++i) {
        mx += x[i];
        my += y[i];
    }
    mx /= n;
    my /= n;
    double sxy = 0, sxx = 0, syy = 0;
    for (std::size_t i = 0; i < x.size(); ++i) {
        sxy += (x[i] - mx) * (y[i] - my);
        sxx += (x[i] - mx) * (x[i] - mx);
        syy += (y[i] - my) * (y[i] - my);
    }
    return sxy / std::sqrt(sxx * syy);
}

TEST(Rng, NeighbouringKeysAreUncorrelated) {
    const std::size_t n = 100000;
    // Four standard errors of a correlation coefficient between independent samples.
    const double bound = 4.0 / std::sqrt(static_cast<double>(n));
    std::vector<double> base(n), nextItem(n), nextPass(n), nextSeed(n);
    for (std::size_t i = 0; i < n; ++i) {
        base[i] = Rng(1, 10, i).uniform();
        nextItem[i] = Rng(1, 10, i + 1).uniform();
        nextPass[i] = Rng(1, 11, i).uniform();
        nextSeed[i] = Rng(2, 10, i).uniform();
    }
    EXPECT_LT(std::abs(correlation(base, nextItem)), bound);
    EXPECT_LT(std::abs(correlation(base, nextPass)), bound);
    EXPECT_LT(std::abs(correlation(base, nextSeed)), bound);

    // Sanity check of the estimator: a dependent pair is flagged.
    std::vector<double> dependent(n);
    for (std::size_t i = 0; i < n; ++i) dependent[i] = 0.9 * base[i] + 0.1 * nextItem[i];
    EXPECT_GT(correlation(base, dependent), 0.9);
}

}  // namespace
}  // namespace fg::jobs
