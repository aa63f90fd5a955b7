#include "tests/support/chi2.h"

#include "jobs/random.h"

#include <algorithm>
#include <cmath>
#include <numeric>
#include <sstream>
#include <vector>

namespace fg::test {

namespace {

// Series for P(a, x), valid for x < a + 1.
double gammaPSeries(double a, double x) {
    double sum = 1.0 / a, term = sum;
    for (int n = 1; n < 10000; ++n) {
        term *= x / (a + n);
        sum += term;
        if (std::abs(term) < std::abs(sum) * 1e-15) break;
    }
    return sum * std::exp(-x + a * std::log(x) - std::lgamma(a));
}

// Lentz continued fraction for Q(a, x), valid for x >= a + 1.
double gammaQFraction(double a, double x) {
    const double tiny = 1e-300;
    double b = x + 1.0 - a, c = 1.0 / tiny, d = 1.0 / b, h = d;
    for (int i = 1; i < 10000; ++i) {
        const double an = -i * (i - a);
        b += 2.0;
        d = an * d + b;
        if (std::abs(d) < tiny) d = tiny;
        c = b + an / c;
        if (std::abs(c) < tiny) c = tiny;
        d = 1.0 / d;
        const double delta = d * c;
        h *= delta;
        if (std::abs(delta - 1.0) < 1e-15) break;
    }
    return std::exp(-x + a * std::log(x) - std::lgamma(a)) * h;
}

double squared(double x) { return x * x; }

// Midpoint rule on a 6 x 6 grid over one (theta, phi) cell of pdf * sin(theta).
double midpointIntegral(const DirectionPdf& pdf, double t0, double t1, double p0, double p1) {
    constexpr int kGrid = 6;
    const double ht = (t1 - t0) / kGrid, hp = (p1 - p0) / kGrid;
    double sum = 0.0;
    for (int i = 0; i < kGrid; ++i) {
        const double theta = t0 + (i + 0.5) * ht;
        const double sinT = std::sin(theta), cosT = std::cos(theta);
        for (int j = 0; j < kGrid; ++j) {
            const double phi = p0 + (j + 0.5) * hp;
            sum += pdf(Vec3(static_cast<float>(sinT * std::cos(phi)), static_cast<float>(sinT * std::sin(phi)),
                            static_cast<float>(cosT))) *
                   sinT;
        }
    }
    return sum * ht * hp;
}

// Refines to at least `minDepth` levels, then wherever the estimate still moves by more than `tolerance`.
double adaptiveIntegral(const DirectionPdf& pdf, double t0, double t1, double p0, double p1, double coarse,
                        double tolerance, int depth, int minDepth) {
    const double tm = 0.5 * (t0 + t1), pm = 0.5 * (p0 + p1);
    const double q[4] = {midpointIntegral(pdf, t0, tm, p0, pm), midpointIntegral(pdf, tm, t1, p0, pm),
                         midpointIntegral(pdf, t0, tm, pm, p1), midpointIntegral(pdf, tm, t1, pm, p1)};
    const double fine = q[0] + q[1] + q[2] + q[3];
    if (depth == 0 || (minDepth <= 0 && std::abs(fine - coarse) <= tolerance)) return fine;
    const double half = 0.5 * tolerance;
    return adaptiveIntegral(pdf, t0, tm, p0, pm, q[0], half, depth - 1, minDepth - 1) +
           adaptiveIntegral(pdf, tm, t1, p0, pm, q[1], half, depth - 1, minDepth - 1) +
           adaptiveIntegral(pdf, t0, tm, pm, p1, q[2], half, depth - 1, minDepth - 1) +
           adaptiveIntegral(pdf, tm, t1, pm, p1, q[3], half, depth - 1, minDepth - 1);
}

}  // namespace

double gammaQ(double a, double x) {
    if (x <= 0.0) return 1.0;
    if (x < a + 1.0) return 1.0 - gammaPSeries(a, x);
    return gammaQFraction(a, x);
}

double chi2Survival(double statistic, int dof) { return gammaQ(0.5 * dof, 0.5 * statistic); }

Chi2Result chi2SphereTest(const DirectionSampler& sample, const DirectionPdf& pdf, const Chi2Config& config) {
    const int nt = config.thetaBins, np = config.phiBins;
    std::vector<double> observed(static_cast<std::size_t>(nt * np), 0.0);
    jobs::Rng rng(config.seed, jobs::streamKey("chi2"), 0);
    for (std::size_t i = 0; i < config.samples; ++i) {
        const std::optional<Vec3> w = sample(rng.uniform2());
        if (!w) continue;
        const Vec3 d = glm::normalize(*w);
        if (!std::isfinite(d.x) || !std::isfinite(d.y) || !std::isfinite(d.z)) {
            return {false, 0, 0, 0, "sampler returned a non-finite direction"};
        }
        const double theta = std::acos(std::clamp(static_cast<double>(d.z), -1.0, 1.0));
        double phi = std::atan2(static_cast<double>(d.y), static_cast<double>(d.x));
        if (phi < 0) phi += 2.0 * M_PI;
        const int ti = std::min(nt - 1, static_cast<int>(theta / M_PI * nt));
        const int pi = std::min(np - 1, static_cast<int>(phi / (2.0 * M_PI) * np));
        observed[static_cast<std::size_t>(ti * np + pi)] += 1.0;
    }

    std::vector<double> expected(observed.size());
    const double n = static_cast<double>(config.samples);
    for (int ti = 0; ti < nt; ++ti) {
        for (int pi = 0; pi < np; ++pi) {
            const double t0 = M_PI * ti / nt, t1 = M_PI * (ti + 1) / nt;
            const double p0 = 2.0 * M_PI * pi / np, p1 = 2.0 * M_PI * (pi + 1) / np;
            const double coarse = midpointIntegral(pdf, t0, t1, p0, p1);
            // Integration error well below the counting noise of the cell.
            const double tolerance = 0.02 * std::sqrt(std::max(coarse * n, 1.0)) / n;
            const auto k = static_cast<std::size_t>(ti * np + pi);
            expected[k] = n * adaptiveIntegral(pdf, t0, t1, p0, p1, coarse, tolerance, 5, config.minRefinement);
            // A discontinuity crossing the cell between all integration points: resolve it on a much finer grid.
            if (observed[k] > 0.0 && expected[k] < std::max(config.minExpected, 0.5 * observed[k]))
                expected[k] = n * adaptiveIntegral(pdf, t0, t1, p0, p1, coarse, tolerance, 5, 5);
        }
    }

    // Cells sorted by expectation; the smallest are pooled until the pool is large enough.
    std::vector<std::size_t> order(observed.size());
    std::iota(order.begin(), order.end(), 0);
    std::sort(order.begin(), order.end(), [&](auto a, auto b) { return expected[a] < expected[b]; });

    double statistic = 0.0, pooledExpected = 0.0, pooledObserved = 0.0;
    int bins = 0;
    for (std::size_t k : order) {
        if (expected[k] <= 0.0 && observed[k] > 0.0) {
            std::ostringstream msg;
            msg << "cell (theta " << k / np << ", phi " << k % np << ") received " << observed[k]
                << " samples where the density integrates to zero";
            return {false, 0, 0, 0, msg.str()};
        }
        if (expected[k] < config.minExpected) {
            pooledExpected += expected[k];
            pooledObserved += observed[k];
        } else {
            statistic += squared(observed[k] - expected[k]) / expected[k];
            ++bins;
        }
    }
    if (pooledExpected > 0.0 || pooledObserved > 0.0) {
        statistic += squared(pooledObserved - pooledExpected) / std::max(pooledExpected, config.minExpected);
        ++bins;
    }

    Chi2Result result;
    result.statistic = statistic;
    result.degreesOfFreedom = std::max(1, bins - 1);
    result.pValue = chi2Survival(statistic, result.degreesOfFreedom);
    const double alpha = 1.0 - std::pow(1.0 - config.significance, 1.0 / config.testCount);
    result.passed = result.pValue >= alpha;
    std::ostringstream msg;
    msg << "chi2 = " << statistic << ", dof = " << result.degreesOfFreedom << ", p = " << result.pValue
        << " (reject below " << alpha << ")";
    result.message = msg.str();
    return result;
}

}  // namespace fg::test
