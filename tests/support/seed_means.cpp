#include "tests/support/seed_means.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <stdexcept>

namespace fg::test {

std::vector<double> blockMeans(const Film& image) {
    const int width = image.width(), height = image.height();
    if (width % kMeanBlock != 0 || height % kMeanBlock != 0)
        throw std::invalid_argument("blockMeans: the film's sides must be multiples of the block");
    const int blocksPerRow = width / kMeanBlock;
    std::vector<double> means(static_cast<std::size_t>(blocksPerRow * (height / kMeanBlock)) + 1, 0.0);
    const std::vector<Rgb> pixels = image.resolve();
    for (int y = 0; y < height; ++y)
        for (int x = 0; x < width; ++x) {
            const Rgb& p = pixels[static_cast<std::size_t>(y) * static_cast<std::size_t>(width) + static_cast<std::size_t>(x)];
            const double v = (p.x + p.y + p.z) / 3.0;
            means[static_cast<std::size_t>((y / kMeanBlock) * blocksPerRow + x / kMeanBlock)] += v / (kMeanBlock * kMeanBlock);
            means.back() += v / (static_cast<double>(width) * height);
        }
    return means;
}

SeedComparison compareSeeds(std::span<const double> a, std::span<const double> b) {
    if (a.size() != b.size() || a.size() < 2)
        throw std::invalid_argument("compareSeeds: needs the same number (at least 2) of seeds on both sides");
    const auto seeds = static_cast<double>(a.size());
    SeedComparison c;
    for (std::size_t i = 0; i < a.size(); ++i) c.meanA += a[i] / seeds, c.meanB += b[i] / seeds;
    for (std::size_t i = 0; i < a.size(); ++i) {
        c.varianceA += (a[i] - c.meanA) * (a[i] - c.meanA) / (seeds - 1);
        c.varianceB += (b[i] - c.meanB) * (b[i] - c.meanB) / (seeds - 1);
    }
    c.sigma = std::sqrt((c.varianceA + c.varianceB) / seeds);
    c.z = std::abs(c.meanA - c.meanB) / std::max(c.sigma, 1e-12);
    return c;
}

void expectSameSeedMean(std::span<const double> a, std::span<const double> b, double maxZ, const std::string& what,
                        const std::string& nameA, const std::string& nameB) {
    const SeedComparison c = compareSeeds(a, b);
    EXPECT_GT(c.meanB, 0.0) << what;
    std::printf("%s: %s %.5f, %s %.5f (sigma of the difference %.2f %% of the mean, z %.2f, %s/%s variance %.3f)\n",
                what.c_str(), nameA.c_str(), c.meanA, nameB.c_str(), c.meanB, 100.0 * c.sigma / c.meanB, c.z,
                nameA.c_str(), nameB.c_str(), c.varianceA / c.varianceB);
    EXPECT_LT(c.z, maxZ) << what << ": " << nameA << " " << c.meanA << ", " << nameB << " " << c.meanB;
}

MeanComparison compareSeedMeans(const std::vector<std::vector<double>>& a, const std::vector<std::vector<double>>& b) {
    if (a.size() != b.size() || a.size() < 2 || a.front().empty())
        throw std::invalid_argument("compareSeedMeans: needs the same number (at least 2) of seeds on both sides");
    const std::size_t imageEntry = a.front().size() - 1;
    MeanComparison result;
    double varianceA = 0.0, varianceB = 0.0;
    std::vector<double> ak(a.size()), bk(b.size());
    for (std::size_t k = 0; k <= imageEntry; ++k) {
        for (std::size_t i = 0; i < a.size(); ++i) ak[i] = a[i][k], bk[i] = b[i][k];
        const SeedComparison c = compareSeeds(ak, bk);
        if (k == imageEntry) {
            result.imageZ = c.z;
            result.imageRelativeSigma = c.sigma / c.meanB;
            result.imageRelativeDifference = (c.meanA - c.meanB) / c.meanB;
        } else {
            result.worstBlockZ = std::max(result.worstBlockZ, c.z);
            varianceA += c.varianceA;
            varianceB += c.varianceB;
        }
    }
    result.varianceRatio = varianceA / varianceB;
    return result;
}

void expectSameMean(const MeanComparison& c, const std::string& what, const std::string& nameA, const std::string& nameB) {
    EXPECT_LT(c.worstBlockZ, 4.5) << what;
    EXPECT_LT(c.imageZ, 4.0) << what << ": image means differ by " << c.imageZ << " sigma (sigma = " << c.imageRelativeSigma
                             << " of the mean)";
    std::printf("%s: worst block z %.2f, image z %.2f (%s - %s: %+.4f of the mean, sigma %.4f), %s/%s variance %.3f\n",
                what.c_str(), c.worstBlockZ, c.imageZ, nameA.c_str(), nameB.c_str(), c.imageRelativeDifference,
                c.imageRelativeSigma, nameA.c_str(), nameB.c_str(), c.varianceRatio);
}

}  // namespace fg::test
