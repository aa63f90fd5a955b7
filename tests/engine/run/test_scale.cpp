// The arithmetic behind `fluxgraph scale`: the Amdahl fit must recover the
// serial fraction of synthetic timings exactly (including the pure-parallel
// and pure-serial ends), medians and speed-ups must follow their definitions,
// and malformed thread lists must be refused with a message naming the list.
#include "engine/run/scale.h"

#include "engine/core/error.h"

#include <gtest/gtest.h>

#include <cmath>
#include <string>
#include <utility>
#include <vector>

namespace fg::run {
namespace {

std::vector<double> amdahlTimes(const std::vector<int>& threads, double oneThread, double serialFraction) {
    std::vector<double> seconds;
    for (int n : threads) seconds.push_back(oneThread * (serialFraction + (1.0 - serialFraction) / n));
    return seconds;
}

TEST(ScaleAmdahl, RecoversTheSerialFractionOfExactTimings) {
    const std::vector<int> threads = {1, 2, 4, 8, 16};
    for (double f : {0.0, 0.05, 0.3, 0.75, 1.0}) {
        const std::vector<double> seconds = amdahlTimes(threads, 12.5, f);
        EXPECT_NEAR(fitSerialFraction(threads, seconds, 12.5), f, 1e-12) << "f = " << f;
    }
}

TEST(ScaleAmdahl, PerfectScalingIsZeroAndNoScalingIsOne) {
    const std::vector<int> threads = {1, 2, 3, 7};
    EXPECT_NEAR(fitSerialFraction(threads, {6.0, 3.0, 2.0, 6.0 / 7.0}, 6.0), 0.0, 1e-12);
    EXPECT_NEAR(fitSerialFraction(threads, {6.0, 6.0, 6.0, 6.0}, 6.0), 1.0, 1e-12);
}

TEST(ScaleAmdahl, ClampsFitsOutsideTheUnitInterval) {
    const std::vector<int> threads = {1, 2, 4};
    // Slower with more threads: the unclamped fit exceeds 1.
    EXPECT_EQ(fitSerialFraction(threads, {1.0, 2.0, 3.0}, 1.0), 1.0);
    // Superlinear (cache effects): the unclamped fit is negative.
    EXPECT_EQ(fitSerialFraction(threads, {1.0, 0.3, 0.1}, 1.0), 0.0);
}

TEST(ScaleAmdahl, NothingToFitWithoutMoreThanOneThreadOrABaseline) {
    EXPECT_TRUE(std::isnan(fitSerialFraction({1}, {2.0}, 2.0)));
    EXPECT_TRUE(std::isnan(fitSerialFraction({1, 2}, {2.0, 1.0}, 0.0)));
}

TEST(ScaleAmdahl, NoisyTimingsGiveTheLeastSquaresFraction) {
    // y = T(N) - T1/N against x = T1 (1 - 1/N): with T1 = 1, points
    // (0.5, 0.1) and (0.75, 0.2) give f = (0.05 + 0.15) / (0.25 + 0.5625).
    const double f = fitSerialFraction({1, 2, 4}, {1.0, 0.6, 0.45}, 1.0);
    EXPECT_NEAR(f, 0.2 / 0.8125, 1e-12);
}

TEST(ScaleStatistics, MedianOfOddAndEvenSamples) {
    EXPECT_EQ(median({3.0, 1.0, 2.0}), 2.0);
    EXPECT_EQ(median({4.0, 1.0, 3.0, 2.0}), 2.5);
    EXPECT_EQ(median({7.0}), 7.0);
}

TEST(ScaleStatistics, SummaryGivesSpeedUpEfficiencyAndOversubscription) {
    ScaleSeries series;
    series.name = "pt";
    const auto timing = [](int threads, std::vector<double> seconds) {
        ThreadTiming t;
        t.threads = threads;
        t.seconds = std::move(seconds);
        return t;
    };
    series.timings = {timing(1, {8.0, 9.0, 8.5}), timing(2, {4.5, 4.0, 4.25}), timing(4, {2.5, 2.0, 2.125})};
    summarize(series, 2);
    ASSERT_EQ(series.timings.size(), 3u);
    EXPECT_EQ(series.timings[0].median, 8.5);
    EXPECT_EQ(series.timings[0].min, 8.0);
    EXPECT_EQ(series.timings[0].max, 9.0);
    EXPECT_EQ(series.timings[0].speedup, 1.0);
    EXPECT_EQ(series.timings[1].speedup, 2.0);
    EXPECT_EQ(series.timings[1].efficiency, 1.0);
    EXPECT_EQ(series.timings[2].speedup, 4.0);
    EXPECT_FALSE(series.timings[1].oversubscribed);
    EXPECT_TRUE(series.timings[2].oversubscribed);
    EXPECT_EQ(series.serialFraction, 0.0);
}

TEST(ScaleThreadList, ParsesSortsAndDropsDuplicates) {
    EXPECT_EQ(parseThreadList("1,2,4,8,16"), (std::vector<int>{1, 2, 4, 8, 16}));
    EXPECT_EQ(parseThreadList("8,2,2,1"), (std::vector<int>{1, 2, 8}));
    EXPECT_EQ(parseThreadList("3"), (std::vector<int>{3}));
}

TEST(ScaleThreadList, RefusesMalformedListsNamingThem) {
    for (const std::string bad : {"", "1,,2", "1,2,", ",1", "two", "1.5", "1 2", "0", "1,-2", "1,0", "4,x",
                                  "99999999999999999999", "100000"}) {
        try {
            parseThreadList(bad);
            ADD_FAILURE() << "accepted '" << bad << "'";
        } catch (const InputError& e) {
            const std::string message = e.what();
            EXPECT_NE(message.find("--threads '" + bad + "'"), std::string::npos) << message;
            EXPECT_EQ(message.find('\n'), std::string::npos) << message;
        }
    }
}

}  // namespace
}  // namespace fg::run
