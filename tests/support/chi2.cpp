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

Vec3 sphericalDirection(double theta, double phi) {
    return Vec3(static_cast<float>(std::sin(theta) * std::cos(phi)),
                static_cast<float>(std::sin(theta) * std::sin(phi)), static_cast<float>(std::cos(theta)));
}

// Integral of pdf * sin(theta) over one cell by composite Simpson's rule in 2D.
double integrateCell(const DirectionPdf& pdf, double t0, double t1, double p0, double p1) {
    constexpr int kSteps = 8;  // even
    // The theta nodes are inset by a negligible fraction of the cell so that a
    // density with a jump across a cell edge (the horizon, theta = pi/2, where
    // reflection and transmission lobes meet) is evaluated on the cell's own
    // side: cos(pi/2) rounds to a tiny positive float, which would otherwise
    // count the upper hemisphere's density into the cell below the horizon.
    const double inset = 1e-4 * (t1 - t0);
    const double ht = (t1 - t0 - 2.0 * inset) / kSteps, hp = (p1 - p0) / kSteps;
    double sum = 0.0;
    for (int i = 0; i <= kSteps; ++i) {
        const double wt = (i == 0 || i == kSteps) ? 1.0 : (i % 2 ? 4.0 : 2.0);
        const double theta = t0 + inset + i * ht;
        const double sinT = std::sin(theta);
        for (int j = 0; j <= kSteps; ++j) {
            const double wp = (j == 0 || j == kSteps) ? 1.0 : (j % 2 ? 4.0 : 2.0);
            const double phi = p0 + j * hp;
            sum += wt * wp * pdf(sphericalDirection(theta, phi)) * sinT;
        }
    }
    // Rescaled to the full cell width; the missing slivers are O(inset).
    return sum * ht * hp / 9.0 * (t1 - t0) / (t1 - t0 - 2.0 * inset);
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
    for (int ti = 0; ti < nt; ++ti)
        for (int pi = 0; pi < np; ++pi)
            expected[static_cast<std::size_t>(ti * np + pi)] =
                config.samples * integrateCell(pdf, M_PI * ti / nt, M_PI * (ti + 1) / nt,
                                               2.0 * M_PI * pi / np, 2.0 * M_PI * (pi + 1) / np);

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
    if (pooledExpected > 0.0) {
        if (pooledExpected < config.minExpected && bins > 0) {
            // Too small to stand alone: fold into the statistic only if samples landed there.
            statistic += squared(pooledObserved - pooledExpected) / std::max(pooledExpected, 1.0);
        } else {
            statistic += squared(pooledObserved - pooledExpected) / pooledExpected;
        }
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
