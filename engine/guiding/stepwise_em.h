// Weighted stepwise EM with a MAP prior for directional GMMs (Vorba et al.
// 2014, §3.2 and §4.2, Eqs. 2-10, Alg. 1): the off-line variant fits a new
// mixture to a fixed particle set by sweeping it until the weighted
// log-likelihood (Eq. 6) settles; the on-line variant folds a stream of
// particles into stored sufficient statistics, each particle once. Batch EM
// (§3.2) is here as the reference the off-line variant is tested against.
#pragma once

#include "engine/guiding/directional_gmm.h"

#include <array>
#include <cstdint>
#include <limits>
#include <span>

namespace fg {

// A point of the square with its particle weight (photon flux, importon weight).
struct WeightedPoint {
    Vec2 s{0.0f};
    float weight = 1.0f;
};

// Running averages of Eq. 7, per component: (u_γ, s, s sᵀ) of the
// responsibility-weighted particle weights.
struct ComponentStatistics {
    double gamma = 0.0;
    double sx = 0.0, sy = 0.0;
    double sxx = 0.0, sxy = 0.0, syy = 0.0;
};

struct GmmStatistics {
    std::array<ComponentStatistics, kGmmComponents> components{};
    double meanWeight = 0.0;  // w̄ of Eq. 8
    // The running average of w² with the same steps: with w̄ it gives the
    // particles' effective count (EmSettings::effectiveCount).
    double meanSquaredWeight = 0.0;
    std::uint64_t count = 0;  // i: particles folded in so far
};

struct EmSettings {
    double stepExponent = 0.7;  // η_i = i^-stepExponent (§3.2: 0.6 .. 0.9)
    int mStepInterval = 10;     // m of Alg. 1
    double priorA = 2.01;       // a, b: prior on the covariances (Eq. 10)
    double priorB = 5e-4;
    double priorNu = 1.01;      // ν: prior on the mixing weights (Eq. 9)
    // ε: a sweep that changes the log-likelihood L by less than ε max(|L|, total
    // weight) ends the off-line EM. Not given in the paper; 1e-3 took 26 sweeps
    // per new record on average in a small occluded room (1e-4: 81, most of
    // them stopped by maxSweeps).
    double tolerance = 1e-3;
    int maxSweeps = 100;
    // The prior's n of Eqs. 9-10 as the particles' effective count
    // n w̄² / mean(w²) (Kish's effective sample size) instead of their number n.
    // Not in the paper, whose n counts particles whatever their weights: a
    // record fitted to a few heavy photons among many light ones then meets
    // a prior as weak as for n even ones, and a lobe collapses onto the heavy
    // photons' directions (Σ -> b / n).
    bool effectiveCount = false;
};

// A deterministic starting mixture for a particle set: equal weights, means at
// evenly spaced particles, the prior's covariance b/(a-2) I.
DirectionalGmm initialGmm(std::span<const WeightedPoint> points, const EmSettings& settings);

// M-step, Eqs. 9-10 with n observed particles (see the .cpp for the derivation).
void gmmMaximisation(DirectionalGmm& gmm, const GmmStatistics& stats, double n, const EmSettings& settings);

// Weighted log-likelihood, Eq. 6, of the points under the (untruncated) mixture.
double weightedLogLikelihood(const DirectionalGmm& gmm, std::span<const WeightedPoint> points);

// Off-line stepwise EM (Alg. 1 with Eqs. 7-8, n = min(i, N)) from `gmm` as a
// start; `stats` is overwritten and left ready for on-line updates. Returns
// the number of sweeps over the points.
int offlineStepwiseEm(DirectionalGmm& gmm, GmmStatistics& stats, std::span<const WeightedPoint> points,
                      const EmSettings& settings);

// Where an off-line EM stands between sweeps, so that it can be stopped after
// a few sweeps and resumed later: a fit resumed up to maxSweeps is the fit of
// one offlineStepwiseEm call, bit for bit (the cache update decides whether
// guiding is rare on the first sweeps and finishes the fits only if not).
struct OfflineEmProgress {
    double previousLikelihood = std::numeric_limits<double>::quiet_NaN();  // the last sweep's running L
    int sweeps = 0;
    bool settled = false;  // the convergence test ended it
};

// Off-line stepwise EM continued from `progress` (a default one: from the
// start, `stats` reset) until it settles or has run min(sweepLimit,
// settings.maxSweeps) sweeps in all.
void continueOfflineStepwiseEm(DirectionalGmm& gmm, GmmStatistics& stats, OfflineEmProgress& progress,
                               std::span<const WeightedPoint> points, const EmSettings& settings, int sweepLimit);

// On-line stepwise EM: every point once, continuing the counter i (n = i).
void onlineStepwiseEm(DirectionalGmm& gmm, GmmStatistics& stats, std::span<const WeightedPoint> points,
                      const EmSettings& settings);

// Batch EM (§3.2) with the same weighted MAP M-step, n = priorCount, until the
// log-likelihood changes by less than 1e-9 relative or after maxIterations.
// Returns the iterations run.
int batchEm(DirectionalGmm& gmm, std::span<const WeightedPoint> points, double priorCount, const EmSettings& settings,
            int maxIterations = 10000);

}  // namespace fg
