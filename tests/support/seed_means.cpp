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

MeanComparison compareSeedMeans(const std::vector<std::vector<double>>& a, const std::vector<std::vector<double>>& b) {
    if (a.size() != b.size() || a.size() < 2 || a.front().empty())
        throw std::invalid_argument("compareSeedMeans: needs the same number (at least 2) of seeds on both sides");
    const auto seeds = static_cast<double>(a.size());
    const std::size_t imageEntry = a.front().size() - 1;
    MeanComparison result;
    double varianceA = 0.0, varianceB = 0.0;
    for (std::size_t k = 0; k <= imageEntry; ++k) {
        double ma = 0, mb = 0, va = 0, vb = 0;
        for (std::size_t i = 0; i < a.size(); ++i) ma += a[i][k] / seeds, mb += b[i][k] / seeds;
        for (std::size_t i = 0; i < a.size(); ++i) va += (a[i][k] - ma) * (a[i][k] - ma), vb += (b[i][k] - mb) * (b[i][k] - mb);
        va /= seeds - 1;
        vb /= seeds - 1;
        const double sigma = std::sqrt((va + vb) / seeds);
        const double z = std::abs(ma - mb) / std::max(sigma, 1e-12);
        if (k == imageEntry) {
            result.imageZ = z;
            result.imageRelativeSigma = sigma / mb;
            result.imageRelativeDifference = (ma - mb) / mb;
        } else {
            result.worstBlockZ = std::max(result.worstBlockZ, z);
            varianceA += va;
            varianceB += vb;
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
