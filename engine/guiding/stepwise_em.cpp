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
#include <vector>

namespace fg {

namespace {

// What the E-step needs of a mixture, computed once per M-step rather than
// once per particle and component: the log of each component's weight times
// its normalisation (the logarithm was most of the off-line EM's time).
struct MixtureTerms {
    std::array<double, kGmmComponents> logConstant{};
    std::array<double, kGmmComponents> invXX{}, invXY{}, invYY{}, meanX{}, meanY{};
    std::array<bool, kGmmComponents> active{};

    explicit MixtureTerms(const DirectionalGmm& gmm) {
        for (std::size_t j = 0; j < kGmmComponents; ++j) {
            const GmmComponent& c = gmm.components[j];
            active[j] = c.weight > 0.0f;
            if (!active[j]) continue;
            logConstant[j] = std::log(double(c.weight) * double(c.normalisation));
            invXX[j] = c.invXX;
            invXY[j] = c.invXY;
            invYY[j] = c.invYY;
            meanX[j] = c.mean.x;
            meanY[j] = c.mean.y;
        }
    }
};

// Responsibilities γ_j (Eq. 2) for s, from log densities so that a point far
// from every component still gets finite ones. Returns the log-density of s
// under the mixture when `withLogDensity` (only the likelihood needs it).
double responsibilities(const MixtureTerms& terms, const Vec2& s, std::array<double, kGmmComponents>& gamma,
                        bool withLogDensity) {
    std::array<double, kGmmComponents> logTerms{};
    double maxLog = -std::numeric_limits<double>::infinity();
    for (std::size_t j = 0; j < kGmmComponents; ++j) {
        if (!terms.active[j]) continue;
        const double dx = double(s.x) - terms.meanX[j], dy = double(s.y) - terms.meanY[j];
        const double q = terms.invXX[j] * dx * dx + 2.0 * terms.invXY[j] * dx * dy + terms.invYY[j] * dy * dy;
        logTerms[j] = terms.logConstant[j] - 0.5 * q;
        maxLog = std::max(maxLog, logTerms[j]);
    }
    double sum = 0.0;
    for (std::size_t j = 0; j < kGmmComponents; ++j) {
        // Below e^-40 a component's share is lost in double rounding anyway;
        // skipping its exp() saves time. A share needs no more than float
        // precision (the statistics still add up in double), and expf costs
        // a fraction of exp: the double exp was a fifth of a Cornell-box
        // training run's time.
        const double d = logTerms[j] - maxLog;
        const double e = terms.active[j] && d > -40.0 ? double(std::exp(static_cast<float>(d))) : 0.0;
        gamma[j] = e;
        sum += e;
    }
    const double inverse = 1.0 / sum;
    for (double& g : gamma) g *= inverse;
    return withLogDensity ? maxLog + std::log(sum) : 0.0;
}

// Eqs. 7-8 for one particle with step size eta. Returns the particle's
// weighted log-density under `terms` when `withLogDensity`.
double accumulate(const MixtureTerms& terms, GmmStatistics& stats, const WeightedPoint& p, double eta,
                  bool withLogDensity = false) {
    std::array<double, kGmmComponents> gamma{};
    const double logDensity = responsibilities(terms, p.s, gamma, withLogDensity);
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
    stats.meanSquaredWeight = keep * stats.meanSquaredWeight + eta * w * w;
    return w * logDensity;
}

// η_i = i^-exponent. pow() was a tenth of the off-line EM's time; the values
// of the first counts are kept per thread (the same numbers on every thread,
// so results still do not depend on scheduling).
double stepSize(std::uint64_t i, const EmSettings& settings) {
    constexpr std::uint64_t kTabulated = 1u << 16;
    if (i >= kTabulated) return std::pow(static_cast<double>(i), -settings.stepExponent);
    thread_local std::vector<double> table;
    thread_local double tableExponent = 0.0;
    if (table.empty() || tableExponent != settings.stepExponent) {
        table.resize(kTabulated);
        table[0] = 1.0;
        for (std::uint64_t k = 1; k < kTabulated; ++k) table[k] = std::pow(static_cast<double>(k), -settings.stepExponent);
        tableExponent = settings.stepExponent;
    }
    return table[i];
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
    if (settings.effectiveCount && stats.meanSquaredWeight > 0.0)
        n = std::max(1.0, n * stats.meanWeight * stats.meanWeight / stats.meanSquaredWeight);
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
    const MixtureTerms terms(gmm);
    double sum = 0.0;
    for (const WeightedPoint& p : points) sum += double(p.weight) * responsibilities(terms, p.s, gamma, true);
    return sum;
}

int offlineStepwiseEm(DirectionalGmm& gmm, GmmStatistics& stats, std::span<const WeightedPoint> points,
                      const EmSettings& settings) {
    OfflineEmProgress progress;
    continueOfflineStepwiseEm(gmm, stats, progress, points, settings, settings.maxSweeps);
    return progress.sweeps;
}

void continueOfflineStepwiseEm(DirectionalGmm& gmm, GmmStatistics& stats, OfflineEmProgress& progress,
                               std::span<const WeightedPoint> points, const EmSettings& settings, int sweepLimit) {
    if (progress.sweeps == 0) stats = GmmStatistics{};
    if (points.empty()) return;
    const auto total = static_cast<std::uint64_t>(points.size());
    const auto interval = static_cast<std::uint64_t>(std::max(1, settings.mStepInterval));
    double totalWeight = 0.0;
    for (const WeightedPoint& p : points) totalWeight += double(p.weight);
    // Convergence is judged by the sweep's running log-likelihood: each
    // particle's log-density under the mixture the E-step used for it, summed
    // while the sweep goes. A separate pass over the particles after every
    // sweep, for the likelihood under the sweep's final mixture, was about a
    // fifth of a Cornell-box training run's time and almost never decided
    // anything there (2435 sweeps for 203 new records in a pass, at most 12
    // each). The first sweep has nothing to be compared with, so a record
    // settles after two sweeps at the earliest.
    const int limit = std::min(sweepLimit, settings.maxSweeps);
    while (!progress.settled && progress.sweeps < limit) {
        MixtureTerms terms(gmm);
        double current = 0.0;
        for (const WeightedPoint& p : points) {
            ++stats.count;
            current += accumulate(terms, stats, p, stepSize(stats.count, settings), true);
            // n = min(i, N): sweeps over the same N particles are no new observations (§4.2).
            if (stats.count % interval == 0) {
                gmmMaximisation(gmm, stats, static_cast<double>(std::min(stats.count, total)), settings);
                terms = MixtureTerms(gmm);
            }
        }
        ++progress.sweeps;
        if (stats.count % interval != 0)
            gmmMaximisation(gmm, stats, static_cast<double>(std::min(stats.count, total)), settings);
        // Relative to |L|, but never to less than the total weight: a nearly
        // uniform mixture on the square has log-density near 0, so |L| alone
        // would ask for an ever smaller change and every such record ran to
        // maxSweeps (measured: 91 of at most 100 sweeps on average over the
        // records of a Cornell-box training pass).
        const double scale = std::max(std::abs(current), totalWeight);
        progress.settled = std::abs(current - progress.previousLikelihood) < settings.tolerance * scale;
        progress.previousLikelihood = current;
    }
}

void onlineStepwiseEm(DirectionalGmm& gmm, GmmStatistics& stats, std::span<const WeightedPoint> points,
                      const EmSettings& settings) {
    if (points.empty()) return;
    const auto interval = static_cast<std::uint64_t>(std::max(1, settings.mStepInterval));
    MixtureTerms terms(gmm);
    for (const WeightedPoint& p : points) {
        ++stats.count;
        accumulate(terms, stats, p, stepSize(stats.count, settings));
        if (stats.count % interval == 0) {
            gmmMaximisation(gmm, stats, static_cast<double>(stats.count), settings);
            terms = MixtureTerms(gmm);
        }
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
        const MixtureTerms terms(gmm);
        for (const WeightedPoint& p : points) {
            responsibilities(terms, p.s, gamma, false);
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
            stats.meanSquaredWeight += double(p.weight) * double(p.weight) * inverseCount;
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
