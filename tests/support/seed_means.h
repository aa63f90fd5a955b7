// Two estimators of the same image compared by their means over independent
// seeds: per 4x4-pixel block and for the whole image, z = difference of the
// means / its standard error from the seeds' spread (with 2(seeds - 1)
// degrees of freedom z is close to normal). The unbiasedness tests of the
// guided estimators against their unguided ones use it.
#pragma once

#include "engine/image/film.h"

#include <span>
#include <string>
#include <vector>

namespace fg::test {

inline constexpr int kMeanBlock = 4;

// An image's channel-average means per kMeanBlock² block (row-major), then
// the image mean as one more entry. The film's sides must be multiples of kMeanBlock.
std::vector<double> blockMeans(const Film& image);

struct MeanComparison {
    double worstBlockZ = 0.0;
    double imageZ = 0.0;
    double imageRelativeSigma = 0.0;       // standard error of the difference of the image means / B's mean
    double imageRelativeDifference = 0.0;  // (A - B) / B of the image means
    double varianceRatio = 0.0;            // A / B variance of the block means, summed over blocks
};

// One quantity measured over independent seeds by estimator A (a[i]) and by
// estimator B (b[i]): the two means, the standard error of their difference
// from the seeds' spread (sample variances varianceA, varianceB) and
// z = |difference| / that error.
struct SeedComparison {
    double meanA = 0.0, meanB = 0.0, varianceA = 0.0, varianceB = 0.0, sigma = 0.0, z = 0.0;
};
SeedComparison compareSeeds(std::span<const double> a, std::span<const double> b);

// Fails unless B's mean is positive and |z| < maxZ; prints the figures,
// naming the quantity and the two estimators.
void expectSameSeedMean(std::span<const double> a, std::span<const double> b, double maxZ, const std::string& what,
                        const std::string& nameA, const std::string& nameB);

// a[i], b[i]: blockMeans of seed i's image by estimator A and by estimator B.
MeanComparison compareSeedMeans(const std::vector<std::vector<double>>& a, const std::vector<std::vector<double>>& b);

// Fails unless A and B have the same mean: with 16 blocks at |z| < 4.5 they
// fail together with probability about 16 x 7e-5 (t with 38 degrees of
// freedom) when both means are the same, the image mean at |z| < 4 with about
// 1e-4. Prints the figures, naming the case and the two estimators.
void expectSameMean(const MeanComparison& c, const std::string& what, const std::string& nameA, const std::string& nameB);

}  // namespace fg::test
