// Accelerated EM (Jakob et al. 2011 §3.6, §5.1-5.3) against a plain EM over
// points written here, against the log-likelihood it bounds, and the
// statistics tree against itself fed the same photons in other batches.
#include "engine/gmm/em.h"
#include "engine/gmm/em_tree.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <vector>

namespace fg::gmm {
namespace {

struct Sample {
    std::vector<Vec3> positions;
    std::vector<Rgb> power;
};

// Points of a mixture of `clusters` anisotropic Gaussians inside the unit box.
Sample mixtureSample(std::size_t n, int clusters, std::uint64_t seed, double size = 1.0) {
    std::mt19937_64 rng(seed);
    std::uniform_real_distribution<double> uniform(0.0, 1.0);
    std::normal_distribution<double> normal;
    std::vector<Vec3d> centres(static_cast<std::size_t>(clusters));
    std::vector<Mat3d> shapes(static_cast<std::size_t>(clusters));
    for (int c = 0; c < clusters; ++c) {
        centres[static_cast<std::size_t>(c)] = Vec3d(0.2 + 0.6 * uniform(rng), 0.2 + 0.6 * uniform(rng), 0.2 + 0.6 * uniform(rng));
        Mat3d m;
        for (int i = 0; i < 3; ++i)
            for (int j = 0; j < 3; ++j) m[i][j] = size * (0.04 * normal(rng) + (i == j ? 0.03 : 0.0));
        shapes[static_cast<std::size_t>(c)] = m;
    }
    Sample s;
    for (std::size_t i = 0; i < n; ++i) {
        const std::size_t c = static_cast<std::size_t>(uniform(rng) * clusters) % static_cast<std::size_t>(clusters);
        const Vec3d x = centres[c] + shapes[c] * Vec3d(normal(rng), normal(rng), normal(rng));
        s.positions.emplace_back(x);
        s.power.emplace_back(static_cast<float>(0.5 + uniform(rng)), 1.0f, 0.25f);
    }
    return s;
}

EmCells cellsOf(const EmTree& tree, const std::vector<std::uint32_t>& cut) {
    EmCells cells;
    for (const std::uint32_t node : cut) {
        const EmStatistics s = tree.statistics(node);
        const double n = static_cast<double>(s.count);
        cells.count.push_back(n);
        cells.mean.push_back(s.mean);
        cells.covariance.push_back(s.scatter * (1.0 / n));
        cells.power.push_back(s.power);
    }
    return cells;
}

double logLikelihood(const std::vector<EmComponent>& components, const std::vector<Vec3>& points) {
    double total = 0.0;
    for (const Vec3& p : points) {
        double sum = 0.0;
        for (const EmComponent& c : components) sum += c.weight * c.gaussian.density(Vec3d(p));
        total += std::log(sum);
    }
    return total;
}

// A plain EM over points, from the textbook: responsibilities from densities
// computed with GLM's inverse and determinant, raw-sum M-step.
struct PlainComponent {
    double weight;
    Vec3d mean;
    Mat3d covariance;
};
void plainEmIteration(std::vector<PlainComponent>& mixture, const std::vector<Vec3>& points, double regCovar) {
    const std::size_t k = mixture.size(), n = points.size();
    std::vector<std::vector<double>> r(n, std::vector<double>(k));
    for (std::size_t i = 0; i < n; ++i) {
        std::vector<double> logTerm(k);
        double top = -1e300;
        for (std::size_t s = 0; s < k; ++s) {
            const Vec3d d = Vec3d(points[i]) - mixture[s].mean;
            logTerm[s] = std::log(mixture[s].weight) - 0.5 * glm::dot(d, glm::inverse(mixture[s].covariance) * d) -
                         0.5 * std::log(glm::determinant(mixture[s].covariance)) - 1.5 * std::log(2.0 * M_PI);
            top = std::max(top, logTerm[s]);
        }
        double sum = 0.0;
        for (std::size_t s = 0; s < k; ++s) sum += std::exp(logTerm[s] - top);
        for (std::size_t s = 0; s < k; ++s) r[i][s] = std::exp(logTerm[s] - top) / sum;
    }
    for (std::size_t s = 0; s < k; ++s) {
        double nk = 0.0;
        Vec3d mean(0.0);
        for (std::size_t i = 0; i < n; ++i) {
            nk += r[i][s];
            mean += r[i][s] * Vec3d(points[i]);
        }
        mean /= nk;
        Mat3d cov(0.0);
        for (std::size_t i = 0; i < n; ++i) {
            const Vec3d d = Vec3d(points[i]) - mean;
            cov += r[i][s] * glm::outerProduct(d, d);
        }
        cov = cov / nk + Mat3d(regCovar);
        mixture[s] = {nk / static_cast<double>(n), mean, cov};
    }
}

TEST(GmmEm, OnePointPerCellEqualsPlainEm) {
    const Sample sample = mixtureSample(500, 4, 21);
    EmCells cells;
    for (const Vec3& p : sample.positions) {
        cells.count.push_back(1.0);
        cells.mean.emplace_back(p);
        cells.covariance.emplace_back();
        cells.power.emplace_back(1.0);
    }
    const double reg = 1e-6;
    std::vector<EmComponent> components;
    std::vector<PlainComponent> plain;
    for (std::size_t s = 0; s < 5; ++s) {
        const Vec3d mean(sample.positions[s * 97]);
        const Sym3 covariance = Sym3::identity(0.01);
        components.push_back({0.2, Vec3d(0.0), Gaussian(mean, covariance), 0.0});
        plain.push_back({0.2, mean, Mat3d(0.01)});
    }
    EmOptions options;
    options.tau = 0.0;
    options.regCovar = reg;
    options.epsilon = 0.0;
    options.maxIterations = 15;
    options.minEffectiveCount = 0.0;
    const EmRun run = runEm(cells, components, options);
    ASSERT_EQ(run.iterations, 15);
    for (int i = 0; i < 15; ++i) plainEmIteration(plain, sample.positions, reg);
    ASSERT_EQ(components.size(), plain.size());
    for (std::size_t s = 0; s < plain.size(); ++s) {
        EXPECT_NEAR(components[s].weight, plain[s].weight, 1e-9);
        for (int i = 0; i < 3; ++i) EXPECT_NEAR(components[s].gaussian.mean[i], plain[s].mean[i], 1e-9);
        for (int r = 0; r < 3; ++r)
            for (int c = 0; c < 3; ++c)
                EXPECT_NEAR(components[s].gaussian.covariance(r, c), plain[s].covariance[c][r],
                            1e-9 * plain[s].covariance[r][r]);
    }
}

TEST(GmmEm, BoundNeverDecreasesAndNeverExceedsLikelihood) {
    const Sample sample = mixtureSample(20000, 6, 22);
    EmTree tree;
    tree.build(sample.positions, sample.power);
    const EmCells cells = cellsOf(tree, tree.cut(256));
    std::vector<EmComponent> components = componentsFromCells(cellsOf(tree, tree.cut(16)), 0.0);
    Responsibilities q;
    double previous = -1e300;
    for (int iteration = 0; iteration < 25; ++iteration) {
        const double bound = eStep(cells, components, 0.0, q);
        const double likelihood = logLikelihood(components, sample.positions);
        EXPECT_LE(bound, likelihood + 1e-9 * std::abs(likelihood)) << "iteration " << iteration;
        EXPECT_GE(bound, previous - 1e-9 * std::abs(previous)) << "iteration " << iteration;
        previous = bound;
        mStep(cells, q, 0.0, components);
    }
}

// pem_fit leaves out an inner loop's last E-step when a map of photons
// follows: the parameters must be those of the full run, and n_eff that of
// the responsibilities the last M-step used (which differs from the full
// run's, so the skip is seen to have happened).
TEST(GmmEm, SkippedLastEStepKeepsTheParametersAndTheMStepsEffectiveCounts) {
    const Sample sample = mixtureSample(20000, 8, 23, 0.5);
    EmTree tree;
    tree.build(sample.positions, sample.power);
    const EmCells cells = cellsOf(tree, tree.cut(512));
    const std::vector<EmComponent> start = componentsFromCells(cellsOf(tree, tree.cut(32)), 1e-7);
    for (const double tau : {0.0, 1e-4}) {
        EmOptions options;
        options.tau = tau;
        options.regCovar = 1e-7;
        options.epsilon = 0.0;
        options.maxIterations = 3;
        std::vector<EmComponent> full = start, skipped = start, twoIterations = start;
        const EmRun fullRun = runEm(cells, full, options);
        int asked = 0;
        options.skipLastEStep = [&](const std::vector<EmComponent>& components) {
            ++asked;
            EXPECT_EQ(components.size(), start.size());
            return true;
        };
        const EmRun skippedRun = runEm(cells, skipped, options);
        EXPECT_EQ(asked, 1);
        EXPECT_TRUE(skippedRun.lastEStepSkipped);
        EXPECT_FALSE(fullRun.lastEStepSkipped);
        EXPECT_EQ(skippedRun.iterations, fullRun.iterations);
        ASSERT_EQ(skippedRun.bounds.size() + 1, fullRun.bounds.size());
        for (std::size_t i = 0; i < skippedRun.bounds.size(); ++i) EXPECT_EQ(skippedRun.bounds[i], fullRun.bounds[i]);
        // The responsibilities the last M-step used: those of two iterations' E-step.
        options.skipLastEStep = nullptr;
        options.maxIterations = 2;
        const EmRun twoRun = runEm(cells, twoIterations, options);
        EXPECT_EQ(skippedRun.responsibilities.q, twoRun.responsibilities.q);
        ASSERT_EQ(full.size(), skipped.size());
        double effective = 0.0;
        bool anyDiffers = false;
        for (std::size_t c = 0; c < full.size(); ++c) {
            EXPECT_EQ(full[c].weight, skipped[c].weight);
            EXPECT_EQ(full[c].gaussian.mean, skipped[c].gaussian.mean);
            EXPECT_EQ(full[c].gaussian.covariance.v, skipped[c].gaussian.covariance.v);
            EXPECT_EQ(skipped[c].effectiveCount, twoIterations[c].effectiveCount);
            EXPECT_NEAR(skipped[c].effectiveCount, skipped[c].weight * cells.totalCount(), 1e-9 * cells.totalCount());
            anyDiffers = anyDiffers || skipped[c].effectiveCount != full[c].effectiveCount;
            effective += skipped[c].effectiveCount;
        }
        EXPECT_TRUE(anyDiffers);
        EXPECT_NEAR(effective, cells.totalCount(), 1e-3 * cells.totalCount() * std::max(tau, 1e-9));
    }
}

TEST(GmmEmTree, LeavesHoldAtMostFourAndRootHoldsAll) {
    const Sample sample = mixtureSample(5000, 3, 23);
    EmTree tree;
    tree.build(sample.positions, sample.power);
    std::uint64_t leafTotal = 0;
    for (std::uint32_t node = 0; node < tree.size(); ++node) {
        if (!tree.isLeaf(node)) {
            EXPECT_EQ(tree.statistics(node).count,
                      tree.statistics(tree.left(node)).count + tree.statistics(tree.right(node)).count);
            continue;
        }
        EXPECT_LE(tree.statistics(node).count, 4u);
        leafTotal += tree.statistics(node).count;
    }
    EXPECT_EQ(leafTotal, sample.positions.size());
    // The root against a direct two-pass computation.
    Vec3d mean(0.0);
    for (const Vec3& p : sample.positions) mean += Vec3d(p);
    mean /= static_cast<double>(sample.positions.size());
    Sym3 scatter;
    for (const Vec3& p : sample.positions) scatter += Sym3::outer(Vec3d(p) - mean);
    const EmStatistics root = tree.statistics(0);
    for (int i = 0; i < 3; ++i) EXPECT_NEAR(root.mean[i], mean[i], 1e-12);
    for (std::size_t i = 0; i < 6; ++i) EXPECT_NEAR(root.scatter.v[i], scatter.v[i], 1e-12 * scatter.trace());
    // A cut of 2^l cells of a balanced tree is its level l.
    EXPECT_EQ(tree.cut(64).size(), 64u);
}

TEST(GmmEmTree, StreamedBatchesEqualOneBatch) {
    const Sample first = mixtureSample(8000, 4, 24);
    const Sample later = mixtureSample(12000, 4, 25);
    EmTree streamed, whole;
    streamed.build(first.positions, first.power);
    whole.build(first.positions, first.power);
    for (std::size_t start = 0; start < later.positions.size(); start += 3000) {
        streamed.update(std::span(later.positions).subspan(start, 3000), std::span(later.power).subspan(start, 3000));
    }
    whole.update(later.positions, later.power);
    ASSERT_EQ(streamed.size(), whole.size());
    for (std::uint32_t node = 0; node < whole.size(); ++node) {
        const EmStatistics a = streamed.statistics(node), b = whole.statistics(node);
        ASSERT_EQ(a.count, b.count);
        for (int i = 0; i < 3; ++i) {
            EXPECT_NEAR(a.mean[i], b.mean[i], 1e-12 * std::max(1.0, std::abs(b.mean[i])));
            EXPECT_NEAR(a.power[i], b.power[i], 1e-12 * std::abs(b.power[i]));
        }
        for (std::size_t i = 0; i < 6; ++i)
            EXPECT_NEAR(a.scatter.v[i], b.scatter.v[i], 1e-12 * std::max(b.scatter.trace(), 1e-300));
    }
    // And the fit on the same cut does not depend on the batches.
    EmOptions options;
    options.regCovar = 1e-7;
    std::vector<EmComponent> fitStreamed = componentsFromCells(cellsOf(streamed, streamed.cut(32)), 1e-7);
    std::vector<EmComponent> fitWhole = componentsFromCells(cellsOf(whole, whole.cut(32)), 1e-7);
    runEm(cellsOf(streamed, streamed.cut(512)), fitStreamed, options);
    runEm(cellsOf(whole, whole.cut(512)), fitWhole, options);
    ASSERT_EQ(fitStreamed.size(), fitWhole.size());
    for (std::size_t s = 0; s < fitWhole.size(); ++s) {
        EXPECT_NEAR(fitStreamed[s].weight, fitWhole[s].weight, 1e-9);
        for (int i = 0; i < 3; ++i) EXPECT_NEAR(fitStreamed[s].gaussian.mean[i], fitWhole[s].gaussian.mean[i], 1e-9);
    }
}

TEST(GmmEm, SparseEStepPrunesWithinTolerance) {
    // Small clusters far apart relative to their size, as a caustic's
    // Gaussians are relative to a room: most pairs are negligible.
    const Sample sample = mixtureSample(60000, 48, 26, 0.2);
    EmTree tree;
    tree.build(sample.positions, sample.power);
    const EmCells cells = cellsOf(tree, tree.cut(2048));
    std::vector<EmComponent> dense = componentsFromCells(cellsOf(tree, tree.cut(256)), 1e-7);
    std::vector<EmComponent> sparse = dense;
    EmOptions options;
    options.regCovar = 1e-7;
    options.maxIterations = 10;
    options.epsilon = 0.0;
    options.tau = 0.0;
    const EmRun denseRun = runEm(cells, dense, options);
    options.tau = 1e-4;
    const EmRun sparseRun = runEm(cells, sparse, options);
    const double n = cells.totalCount();
    EXPECT_LE(sparseRun.responsibilities.maxPrunedShare, 1e-4);
    EXPECT_NEAR(sparseRun.bounds.back() / n, denseRun.bounds.back() / n, 1e-3);
    const double denseKept = static_cast<double>(denseRun.responsibilities.pairsKept);
    const double sparseKept = static_cast<double>(sparseRun.responsibilities.pairsKept);
    std::printf("pairs kept: dense %.0f, tau = 1e-4 %.0f (%.1fx fewer)\n", denseKept, sparseKept, denseKept / sparseKept);
    EXPECT_LT(sparseKept * 2.0, denseKept);

    // Per cell, for the same components: what the sparse E-step leaves out
    // (pruned nodes and dropped kept terms) is at most tau of the Z_A it
    // keeps, so 0 <= log Z_dense - log Z_sparse <= log(1 + tau), up to the
    // sparse walk's exponential (fast_math.h's, relative error below 1e-9).
    Responsibilities all, some;
    eStep(cells, sparse, 0.0, all);
    eStep(cells, sparse, 1e-4, some);
    const double expError = 1e-9;
    double largest = 0.0;
    for (std::size_t a = 0; a < cells.size(); ++a) {
        const double missing = all.logZ[a] - some.logZ[a];
        ASSERT_GE(missing, -expError) << a;
        largest = std::max(largest, missing);
    }
    EXPECT_LE(largest, std::log1p(1e-4) + expError);
    EXPECT_GT(largest, 0.0);  // something was left out
}

// The sparse E-step decides which of an opened leaf's terms pass its skip
// bound from single-precision terms raised by a bound on their error, and
// computes only those in double. That must change nothing: the same terms,
// q and log Z, bit for bit, as computing every term in double, also for thin
// Gaussians far from the origin (where the rounding of d = m_A - mu_s and of
// the precisions is largest) and after EM has moved the components.
TEST(GmmEm, SinglePrecisionFilterChangesNoBit) {
    for (const double size : {0.2, 0.02}) {
        for (const double shift : {0.0, 200.0}) {
            Sample sample = mixtureSample(60000, 48, 31, size);
            for (Vec3& p : sample.positions) p += Vec3(static_cast<float>(shift), static_cast<float>(-0.5 * shift), 0.0f);
            EmTree tree;
            tree.build(sample.positions, sample.power);
            const EmCells cells = cellsOf(tree, tree.cut(4096));
            std::vector<EmComponent> components = componentsFromCells(cellsOf(tree, tree.cut(512)), 1e-7);
            for (int iteration = 0; iteration < 3; ++iteration) {
                Responsibilities filtered, full;
                eStep(cells, components, 1e-4, filtered, true);
                eStep(cells, components, 1e-4, full, false);
                ASSERT_EQ(filtered.offset, full.offset) << size << " " << shift;
                ASSERT_EQ(filtered.component, full.component);
                ASSERT_EQ(filtered.q, full.q);
                ASSERT_EQ(filtered.logZ, full.logZ);
                ASSERT_EQ(filtered.prunedPerCell, full.prunedPerCell);
                EXPECT_EQ(filtered.maxPrunedShare, full.maxPrunedShare);
                EXPECT_LE(filtered.maxPrunedShare, 1e-4);
                mStep(cells, filtered, 1e-7, components);
                dropWeakComponents(components, 1.0);
            }
        }
    }
}

// A cut expansion's E-step over the old cut and the children of its nodes is
// reused as the first E-step on the expanded cut (pem_fit). That is exact
// only if a cell's responsibilities do not depend on which other cells are
// evaluated with it: the selected rows must equal an E-step on those cells
// alone, bit for bit, E-steps on two sets joined must equal one on both, and
// a run started from selected rows must equal a cold run.
TEST(GmmEm, SelectedAndJoinedCellsEqualAnEStepOnThoseCells) {
    const Sample sample = mixtureSample(20000, 12, 31, 0.3);
    EmTree tree;
    tree.build(sample.positions, sample.power);
    const std::vector<std::uint32_t> coarse = tree.cut(512);
    std::vector<std::uint32_t> both = coarse;
    for (const std::uint32_t node : coarse) {
        if (tree.isLeaf(node)) continue;
        both.push_back(tree.left(node));
        both.push_back(tree.right(node));
    }
    std::vector<EmComponent> components = componentsFromCells(cellsOf(tree, tree.cut(64)), 1e-7);
    for (const double tau : {0.0, 1e-4}) {
        Responsibilities all;
        eStep(cellsOf(tree, both), components, tau, all);
        // Every other cell of the union, in reverse order.
        std::vector<std::size_t> rows;
        std::vector<std::uint32_t> subset;
        for (std::size_t i = both.size(); i-- > 0;) {
            if (i % 2 != 0) continue;
            rows.push_back(i);
            subset.push_back(both[i]);
        }
        const EmCells cells = cellsOf(tree, subset);
        Responsibilities alone;
        const double bound = eStep(cells, components, tau, alone);
        Responsibilities selected = selectCells(all, rows);
        EXPECT_EQ(selected.offset, alone.offset);
        EXPECT_EQ(selected.component, alone.component);
        EXPECT_EQ(selected.q, alone.q);
        EXPECT_EQ(selected.logZ, alone.logZ);
        EXPECT_EQ(selected.pairsKept, alone.pairsKept);
        EXPECT_EQ(selected.pairsPruned, alone.pairsPruned);
        EXPECT_EQ(boundOf(cells, selected), bound);
        if (tau > 0.0) {
            EXPECT_GT(alone.pairsPruned, 0u);
        }
        // Two E-steps, on the coarse cut and on the rest, joined: the E-step on both.
        const std::vector<std::uint32_t> rest(both.begin() + static_cast<std::ptrdiff_t>(coarse.size()), both.end());
        Responsibilities first, second;
        eStep(cellsOf(tree, coarse), components, tau, first);
        eStep(cellsOf(tree, rest), components, tau, second);
        const Responsibilities joined = concatenate(first, second);
        EXPECT_EQ(joined.offset, all.offset);
        EXPECT_EQ(joined.component, all.component);
        EXPECT_EQ(joined.q, all.q);
        EXPECT_EQ(joined.logZ, all.logZ);
        EXPECT_EQ(joined.pairsPruned, all.pairsPruned);

        EmOptions options;
        options.tau = tau;
        options.regCovar = 1e-7;
        options.maxIterations = 3;
        std::vector<EmComponent> cold = components, warm = components;
        const EmRun coldRun = runEm(cells, cold, options);
        const EmRun warmRun = runEm(cells, warm, options, &selected);
        EXPECT_EQ(coldRun.bounds, warmRun.bounds);
        ASSERT_EQ(cold.size(), warm.size());
        for (std::size_t c = 0; c < cold.size(); ++c) {
            EXPECT_EQ(cold[c].gaussian.mean, warm[c].gaussian.mean);
            EXPECT_EQ(cold[c].gaussian.covariance.v, warm[c].gaussian.covariance.v);
            EXPECT_EQ(cold[c].effectiveCount, warm[c].effectiveCount);
        }
    }
}

}  // namespace
}  // namespace fg::gmm
