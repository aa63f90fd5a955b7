// Chi-square goodness-of-fit test for direction sampling routines, in the style
// of Mitsuba's and pbrt-v4's test suites: samples are binned on a (theta, phi)
// grid over the sphere, expected counts come from integrating the routine's own
// density over each cell, cells with low expectation are pooled, and the
// p-value is compared with a Sidak-corrected significance level.
// Densities of area lights, environment-map pixels and horizons are
// discontinuous, so cells are integrated adaptively (midpoint rule on a
// quadtree refined where the estimate still moves) until the integration error
// is far below the cell's counting noise.
#pragma once

#include "engine/core/math.h"

#include <cstddef>
#include <functional>
#include <optional>
#include <string>

namespace fg::test {

struct Chi2Config {
    int thetaBins = 20;
    int phiBins = 40;
    std::size_t samples = 1'000'000;
    double minExpected = 5.0;
    double significance = 0.01;
    int testCount = 1;  // number of tests in the family, for the Sidak correction
    std::uint64_t seed = 1;
    int minRefinement = 2;  // quadtree levels every cell is refined to before the adaptive test
};

struct Chi2Result {
    bool passed = false;
    double statistic = 0.0;
    int degreesOfFreedom = 0;
    double pValue = 0.0;
    std::string message;  // why it failed, or a summary
};

// sample(u) returns a unit direction, or nullopt where the routine rejects the
// sample (those count as missing mass, which the density must integrate to as well).
using DirectionSampler = std::function<std::optional<Vec3>(const Vec2& u)>;
// Solid-angle density of the same routine.
using DirectionPdf = std::function<double(const Vec3& w)>;

Chi2Result chi2SphereTest(const DirectionSampler& sample, const DirectionPdf& pdf, const Chi2Config& config = {});

// Regularised upper incomplete gamma Q(a, x); the chi-square survival function is Q(dof/2, x/2).
double gammaQ(double a, double x);
double chi2Survival(double statistic, int dof);

}  // namespace fg::test
