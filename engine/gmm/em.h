// Accelerated EM on a partition (Jakob et al. 2011 §3.6 and Alg. 1, after
// Verbeek, Nunnink & Vlassis 2006), with the sparsity of §5.3.
//
// Every photon of cell A shares the responsibilities q_A(s). The E-step is
// Eq. 7 with its lost bracket restored:
//   q_A(s) = w_s exp<log g_s>_A / Z_A,  Z_A = sum_a w_a exp<log g_a>_A,
// <log g_s>_A = -1/2 [log|2 pi Sigma_s| + (m_A - mu_s)^T Sigma_s^-1 (m_A - mu_s)
// + tr(Sigma_s^-1 C_A)], all in the log domain. With this q, Eq. 8 (p(s) = w_s)
// collapses to F = sum_A n_A log Z_A, a lower bound on the log-likelihood.
// The M-step is Eq. 9 in centred form,
//   w_s = sum_A n_A q_A(s) / n,  mu_s = sum_A n_A q_A(s) m_A / (n w_s),
//   Sigma_s = sum_A n_A q_A(s) [C_A + (m_A - mu_s)(m_A - mu_s)^T] / (n w_s),
// plus a ridge reg_covar I (the printed <xx^T>_A - mu mu^T cancels
// catastrophically for cells far from the origin). n_eff(s) = sum_A n_A q_A(s)
// (Eq. 10) and the component's power Phi_s = sum_A q_A(s) Phi_A.
//
// Sparsity (§5.3): for tau > 0 a cell's terms w_s exp<log g_s>_A are visited
// best first down a hierarchy over the components, bounded per node by the
// upper envelope over its components of w_s N_s exp(-(|m_A - box of means|^2 +
// tr C_A) / 2 lambda_max(Sigma_s)) (see em.cpp), and the walk stops
// once the bound on what is left is at most tau times the Z_A found so far;
// the pruned terms are dropped. What remains of the budget drops the kept
// terms that are each at most an equal share of it, so that pruned and
// dropped mass together stay <= tau Z_A (terms of a leaf below
// tau Z / (10 k) are counted into that mass unevaluated). The walk's
// exponentials are fast_math.h's (relative error below 1e-9, two at a time);
// tau = 0 visits all pairs with the C library's.
//
// Cells are processed in fixed blocks and the M-step's sums merged in block
// order, so a fit is bit-identical for any thread count.
#pragma once

#include "engine/gmm/gaussian.h"

#include <cstdint>
#include <functional>
#include <vector>

namespace fg::gmm {

// The statistics of the cells of a cut: count, mean, covariance C_A = S_A / n_A, power.
struct EmCells {
    std::vector<double> count;
    std::vector<Vec3d> mean;
    std::vector<Sym3> covariance;
    std::vector<Vec3d> power;
    std::size_t size() const { return count.size(); }
    double totalCount() const;
};

struct EmComponent {
    double weight = 0.0;
    Vec3d power{0.0};
    Gaussian gaussian;
    double effectiveCount = 0.0;
};

struct EmOptions {
    double tau = 1e-4;         // pruned mass per cell <= tau Z_A; 0: all pairs
    double regCovar = 0.0;     // ridge added to every covariance's diagonal
    double epsilon = 1e-4;     // converged when |F/n change| <= epsilon max(1, |F/n|)
    int maxIterations = 100;
    double minEffectiveCount = 1.0;  // components explaining fewer photons are dropped
    // Asked after the M-step of the last allowed iteration, with the new
    // components: true leaves out the E-step that would follow. A caller that
    // will change the cells before it reads the responsibilities again (e.g.
    // blends in more photons) does not need it. n_eff and the powers are then
    // those of the responsibilities that M-step used, from which it set the
    // weights (w_s = n_eff(s) / n).
    std::function<bool(const std::vector<EmComponent>&)> skipLastEStep;
};

// Sparse responsibilities, cell by cell: entries [offset[A], offset[A + 1]).
struct Responsibilities {
    std::vector<std::uint64_t> offset;
    std::vector<std::uint32_t> component;
    std::vector<double> q;
    std::vector<double> logZ;  // log Z_A per cell
    std::vector<std::uint32_t> prunedPerCell;  // components pruned per cell
    std::uint64_t pairsKept = 0, pairsPruned = 0;
    double maxPrunedShare = 0.0;  // the largest pruned mass bound / Z_A over cells
};

// The responsibilities of some of the cells (rows of `from`, in the order
// given), as an E-step over those cells alone would give them: each cell's
// terms depend on that cell and the components only. maxPrunedShare is
// `from`'s, an upper bound.
Responsibilities selectCells(const Responsibilities& from, const std::vector<std::size_t>& rows);
// The cells of `b` after those of `a`, as one E-step over both would give them.
Responsibilities concatenate(const Responsibilities& a, const Responsibilities& b);
// F = sum_A n_A log Z_A of responsibilities computed for these cells.
double boundOf(const EmCells& cells, const Responsibilities& q);

// E-step (Eq. 7) for all cells; returns F = sum_A n_A log Z_A.
// singlePrecisionFilter = false computes every term of a leaf the walk opens
// in double instead of only those a single-precision pass says may pass the
// skip bound; the result is the same bit for bit (tested), only slower.
double eStep(const EmCells& cells, const std::vector<EmComponent>& components, double tau, Responsibilities& out,
             bool singlePrecisionFilter = true);
// M-step (Eq. 9, centred), n_eff (Eq. 10) and powers from the responsibilities.
// With updateParameters = false only n_eff and the powers are recomputed.
void mStep(const EmCells& cells, const Responsibilities& q, double regCovar, std::vector<EmComponent>& components,
           bool updateParameters = true);
// Removes components with n_eff below the threshold (or unusable
// covariances); returns how many were removed. Order is kept.
std::size_t dropWeakComponents(std::vector<EmComponent>& components, double minEffectiveCount);

struct EmRun {
    int iterations = 0;
    bool converged = false;
    std::vector<double> bounds;  // F after each E-step, the first for the initial guess
    std::size_t dropped = 0;
    Responsibilities responsibilities;  // of the final parameters, unless lastEStepSkipped
    bool lastEStepSkipped = false;      // skipLastEStep said so; responsibilities are those before the last M-step
};
// Alg. 1: E- and M-steps until F/n settles; components keep n_eff and powers
// of the final E-step.
// `initial`, when given, holds the E-step of the present components on these
// cells (e.g. from a cut expansion) and replaces the first E-step; it is
// moved from.
EmRun runEm(const EmCells& cells, std::vector<EmComponent>& components, const EmOptions& options,
            Responsibilities* initial = nullptr);

// One Gaussian per cell: the cell's own mean and covariance (plus the ridge),
// weight n_A / n (§5.4's initial guess from a cut).
std::vector<EmComponent> componentsFromCells(const EmCells& cells, double regCovar);

}  // namespace fg::gmm
