// Weighted stepwise EM for directional GMMs, Vorba et al. 2014: E-step Eqs.
// 2, 7 and 8, M-step Eqs. 9-10, off-line and on-line variants (§3.2 Alg. 1,
// §4.2 "Differences between the off-line and the on-line versions").
//
// The M-step as transcribed (Eqs. 9-10) is garbled: its mixing weights
// (u_γ/w̄ + ν - 1) / (1 + K(ν - 1)/n) do not sum to one, since Σ_j u_γ^j = w̄.
// Derived again: with a Dirichlet(ν) prior on π and a prior on each Σ_j whose
// mode gives Σ_j = (b I + S_j) / (a - 2 + N_j) (Gauvain and Lee 1994), the
// MAP estimates from n weighted particles with effective counts
// N_j = n u_γ^j / w̄ and scatter S_j = n (ssᵀ - s μᵀ - μ sᵀ + u_γ μ μᵀ)^j / w̄ are
//   π_j = (N_j + ν - 1) / (n + K(ν - 1)),   μ_j = s^j / u_γ^j,
//   Σ_j = (b I + S_j) / (a - 2 + N_j).
// Dividing numerator and denominator by n gives Eqs. 9-10 with (ν - 1) and
// (a - 2) divided by n:
//   π_j = (u_γ^j/w̄ + (ν - 1)/n) / (1 + K(ν - 1)/n),
//   Σ_j = (b/n I + (ssᵀ - A + u_γ B)^j / w̄) / ((a - 2)/n + u_γ^j/w̄),
// so Σ_j π_j = 1 exactly, and with one particle Σ_j stays near the prior's
// b/(a - 2) I instead of collapsing onto the point.
#include "engine/guiding/stepwise_em.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace fg {

namespace {

// Responsibilities γ_j (Eq. 2) of the mixture for s, computed from log
// densities so that a point far from every component still gets finite ones.
// Returns the log-density of s under the mixture.
double responsibilities(const DirectionalGmm& gmm, const Vec2& s, std::array<double, kGmmComponents>& gamma) {
    std::array<double, kGmmComponents> logTerms{};
    double maxLog = -std::numeric_limits<double>::infinity();
    for (int j = 0; j < kGmmComponents; ++j) {
        const GmmComponent& c = gmm.components[static_cast<std::size_t>(j)];
        if (c.weight <= 0.0f) {
            logTerms[static_cast<std::size_t>(j)] = -std::numeric_limits<double>::infinity();
            continue;
        }
        const double dx = double(s.x) - double(c.mean.x), dy = double(s.y) - double(c.mean.y);
        const double q = double(c.invXX) * dx * dx + 2.0 * double(c.invXY) * dx * dy + double(c.invYY) * dy * dy;
        const double value = std::log(double(c.weight) * double(c.normalisation)) - 0.5 * q;
        logTerms[static_cast<std::size_t>(j)] = value;
        maxLog = std::max(maxLog, value);
    }
    double sum = 0.0;
    for (int j = 0; j < kGmmComponents; ++j) {
        const double e = std::isfinite(logTerms[static_cast<std::size_t>(j)])
                             ? std::exp(logTerms[static_cast<std::size_t>(j)] - maxLog)
                             : 0.0;
        gamma[static_cast<std::size_t>(j)] = e;
        sum += e;
    }
    for (double& g : gamma) g /= sum;
    return maxLog + std::log(sum);
}

// Eqs. 7-8 for one particle with step size eta.
void accumulate(const DirectionalGmm& gmm, GmmStatistics& stats, const WeightedPoint& p, double eta) {
    std::array<double, kGmmComponents> gamma{};
    responsibilities(gmm, p.s, gamma);
    const double keep = 1.0 - eta;
    const double x = p.s.x, y = p.s.y, w = p.weight;
    for (int j = 0; j < kGmmComponents; ++j) {
        ComponentStatistics& u = stats.components[static_cast<std::size_t>(j)];
        const double g = eta * w * gamma[static_cast<std::size_t>(j)];
        u.gamma = keep * u.gamma + g;
        u.sx = keep * u.sx + g * x;
        u.sy = keep * u.sy + g * y;
        u.sxx = keep * u.sxx + g * x * x;
        u.sxy = keep * u.sxy + g * x * y;
        u.syy = keep * u.syy + g * y * y;
    }
    stats.meanWeight = keep * stats.meanWeight + eta * w;
}

double stepSize(std::uint64_t i, const EmSettings& settings) {
    return std::pow(static_cast<double>(i), -settings.stepExponent);
}

}  // namespace

DirectionalGmm initialGmm(std::span<const WeightedPoint> points, const EmSettings& settings) {
    DirectionalGmm gmm;
    const float priorVariance = static_cast<float>(settings.priorB / (settings.priorA - 2.0));
    for (int j = 0; j < kGmmComponents; ++j) {
        GmmComponent& c = gmm.components[static_cast<std::size_t>(j)];
        c.weight = 1.0f / kGmmComponents;
        if (points.empty()) {
            c.mean = Vec2((static_cast<float>(j) + 0.5f) / kGmmComponents, 0.5f);
        } else {
            c.mean = points[static_cast<std::size_t>(j) * points.size() / kGmmComponents].s;
        }
        c.covXX = c.covYY = priorVariance;
        c.covXY = 0.0f;
    }
    gmm.finalize();
    return gmm;
}

void gmmMaximisation(DirectionalGmm& gmm, const GmmStatistics& stats, double n, const EmSettings& settings) {
    if (!(stats.meanWeight > 0.0) || !(n > 0.0)) return;
    const DirectionalGmm previous = gmm;
    const double priorWeight = (settings.priorNu - 1.0) / n;
    const double priorCov = settings.priorB / n;
    const double priorCount = (settings.priorA - 2.0) / n;
    const double normaliser = 1.0 + kGmmComponents * priorWeight;
    for (int j = 0; j < kGmmComponents; ++j) {
        const ComponentStatistics& u = stats.components[static_cast<std::size_t>(j)];
        GmmComponent& c = gmm.components[static_cast<std::size_t>(j)];
        const double share = u.gamma / stats.meanWeight;  // N_j / n
        c.weight = static_cast<float>((share + priorWeight) / normaliser);
        double mx = c.mean.x, my = c.mean.y;
        double scatterXX = 0.0, scatterXY = 0.0, scatterYY = 0.0;
        if (u.gamma > 0.0 && share > 1e-12) {
            mx = u.sx / u.gamma;
            my = u.sy / u.gamma;
            // ssᵀ - A + u_γ B with μ = s/u_γ is ssᵀ - s sᵀ / u_γ.
            scatterXX = std::max(0.0, u.sxx - u.sx * mx);
            scatterYY = std::max(0.0, u.syy - u.sy * my);
            scatterXY = u.sxy - u.sx * my;
        }
        const double denominator = priorCount + share;
        c.mean = Vec2(static_cast<float>(mx), static_cast<float>(my));
        c.covXX = static_cast<float>((priorCov + scatterXX / stats.meanWeight) / denominator);
        c.covYY = static_cast<float>((priorCov + scatterYY / stats.meanWeight) / denominator);
        c.covXY = static_cast<float>((scatterXY / stats.meanWeight) / denominator);
    }
    // Rounding may still leave a covariance indefinite in float: keep the last good mixture then.
    if (!gmm.finalize()) gmm = previous;
}

double weightedLogLikelihood(const DirectionalGmm& gmm, std::span<const WeightedPoint> points) {
    std::array<double, kGmmComponents> gamma{};
    double sum = 0.0;
    for (const WeightedPoint& p : points) sum += double(p.weight) * responsibilities(gmm, p.s, gamma);
    return sum;
}

int offlineStepwiseEm(DirectionalGmm& gmm, GmmStatistics& stats, std::span<const WeightedPoint> points,
                      const EmSettings& settings) {
    stats = GmmStatistics{};
    if (points.empty()) return 0;
    const auto total = static_cast<std::uint64_t>(points.size());
    const auto interval = static_cast<std::uint64_t>(std::max(1, settings.mStepInterval));
    double previous = weightedLogLikelihood(gmm, points);
    int sweeps = 0;
    while (sweeps < settings.maxSweeps) {
        for (const WeightedPoint& p : points) {
            ++stats.count;
            accumulate(gmm, stats, p, stepSize(stats.count, settings));
            // n = min(i, N): sweeps over the same N particles are no new observations (§4.2).
            if (stats.count % interval == 0)
                gmmMaximisation(gmm, stats, static_cast<double>(std::min(stats.count, total)), settings);
        }
        ++sweeps;
        if (stats.count % interval != 0)
            gmmMaximisation(gmm, stats, static_cast<double>(std::min(stats.count, total)), settings);
        const double current = weightedLogLikelihood(gmm, points);
        const bool settled = std::abs(current - previous) < settings.tolerance * std::abs(current);
        previous = current;
        if (settled) break;
    }
    return sweeps;
}

void onlineStepwiseEm(DirectionalGmm& gmm, GmmStatistics& stats, std::span<const WeightedPoint> points,
                      const EmSettings& settings) {
    if (points.empty()) return;
    const auto interval = static_cast<std::uint64_t>(std::max(1, settings.mStepInterval));
    for (const WeightedPoint& p : points) {
        ++stats.count;
        accumulate(gmm, stats, p, stepSize(stats.count, settings));
        if (stats.count % interval == 0) gmmMaximisation(gmm, stats, static_cast<double>(stats.count), settings);
    }
    if (stats.count % interval != 0) gmmMaximisation(gmm, stats, static_cast<double>(stats.count), settings);
}

int batchEm(DirectionalGmm& gmm, std::span<const WeightedPoint> points, double priorCount, const EmSettings& settings,
            int maxIterations) {
    if (points.empty()) return 0;
    double previous = weightedLogLikelihood(gmm, points);
    std::array<double, kGmmComponents> gamma{};
    int iterations = 0;
    const double inverseCount = 1.0 / static_cast<double>(points.size());
    while (iterations < maxIterations) {
        GmmStatistics stats;
        for (const WeightedPoint& p : points) {
            responsibilities(gmm, p.s, gamma);
            const double x = p.s.x, y = p.s.y, w = double(p.weight) * inverseCount;
            for (int j = 0; j < kGmmComponents; ++j) {
                ComponentStatistics& u = stats.components[static_cast<std::size_t>(j)];
                const double g = w * gamma[static_cast<std::size_t>(j)];
                u.gamma += g;
                u.sx += g * x;
                u.sy += g * y;
                u.sxx += g * x * x;
                u.sxy += g * x * y;
                u.syy += g * y * y;
            }
            stats.meanWeight += w;
        }
        gmmMaximisation(gmm, stats, priorCount, settings);
        ++iterations;
        const double current = weightedLogLikelihood(gmm, points);
        const bool settled = std::abs(current - previous) < 1e-9 * std::abs(current);
        previous = current;
        if (settled) break;
    }
    return iterations;
}

}  // namespace fg
