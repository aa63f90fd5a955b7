// Progressive EM pass (`pem_fit`): Jakob et al. 2011 Alg. 2 (§5.2-5.4) on
// the statistics kd-tree of §5.1.
//
// The volume photons arrive as a demand-driven stream from the one photon pass
// (its volume_photons target first, then maps of volume_batch further photons
// while this pass wants more). The fit therefore happens while the stream is
// read: a pass reading a stream is run with its producer, and a statistics
// tree made by a separate pass would not exist before the producer ends. So
// the first map (n0 = 128 k photons in the paper, §5.1) is built into the
// tree here, with the code `em_stats` uses, and freed; later maps are binned
// down the frozen splits and blended in with Chan's update (§5.2), and freed.
// Memory is bounded by n0, never by the photons streamed.
//
// Alg. 2, as run here:
//   initial guess: one Gaussian per cell of a k-cell cut (§5.4); cut: 8 k cells (§5.1);
//     or, seeded by the previous frame's mixture (§5.4), its components on a cut of seeded_cut k cells;
//   repeat
//     inner EM (Alg. 1: E-step Eq. 7, M-step Eq. 9 centred, sparse as §5.3) until F/n settles (ε),
//       at most max_iterations from the initial guess and max_refit_iterations after that;
//     if a live component has n_eff (Eq. 10) < n_eff_threshold (64, §5.2) that more photons
//       can lift to it within max_photons (below): take the next map and update the statistics;
//     expand the cut: for every cut node with children, ΔF = n_A1 log Z_A1 + n_A2 log Z_A2 -
//       n_A log Z_A (Eq. 8's terms); the expand_fraction (50 %, §5.2) with the largest ΔF are
//       replaced by their children (ties by node index);
//   until the expansion's gain, the sum of its ΔF per photon, is below outer_epsilon nats, or
//   the cut is all leaves, or max_outer.
// The paper's line 7 compares F between iterations; F/n is used so that a
// larger sample after line 9 is no progress in itself (the ε of em.h).
// Line 11 ("the relative change in the expanded F") is read as the change
// that expanding makes: F on the expanded cut minus F on the cut before, both
// with the same parameters and the same photons, which is the sum of the
// chosen nodes' ΔF. Comparing F after this expansion with F after the last
// one would instead count the inner EM's progress and the statistics of the
// maps taken in between, which need not settle while the cut is still
// useful to refine, and ran the cut down to the tree's leaves (12 to 14
// outer iterations at k = 1024).
// The outer threshold is its own parameter, in nats per photon, not relative
// to F/n: a change of units shifts F/n by -3 log(scale) for every cut, so the
// gain of an expansion does not depend on the units but its ratio to F/n does
// (|F/n| is 1.75 on volumetric-caustic and below 1 on spot-fog). The paper
// does not state its ε. With 1e-4 the gains of successive expansions at
// k = 1024 (0.035, 0.024, 0.013, 0.0048, 0.0018, ... on volumetric-caustic;
// 0.041, 0.028, 0.012, 0.0045, 0.0018 on spot-fog) stayed above it until the
// cut held 0.99 of the tree's leaves; Table 2's final cuts hold 0.67 to 0.94
// of them (21 to 30 cells per Gaussian). The default 8e-3 stops both scenes
// after the fourth expansion at 0.86 of the leaves; it was chosen for that,
// from these two scenes.
// Inner iterations: §5.2 runs EM "until convergence", but Table 2's whole
// fits took 10 to 20 EM iterations, so the inner loops cannot have run to a
// tight tolerance. Ours, to ε = 1e-4 nats per photon, took 61 from the
// initial guess and 85 to 87 in all (73 CPU s at k = 1024 on either data
// scene). The inner loops are therefore capped: max_iterations (8) from the
// initial guess, max_refit_iterations (1) after an expansion or a map, where
// the previous solution is a warm start on a cut that differs from the last
// in half its cells; they still stop earlier once F/n settles. 8 is what
// `aem` (em_fit) runs on the initial cut with the same image error; one
// refit instead of two took pem_fit from 7.6 to 6.0 CPU s on
// volumetric-caustic (RMSE 4.4996 -> 4.4963) and from 13.0 to 9.5 s on
// spot-fog (0.0122387 both), 11 EM iterations in all instead of 14.
// The expansion evaluates one E-step over the cut and the children of its
// expandable nodes (both sides of every ΔF); a cell's responsibilities depend
// only on that cell and the components, so its rows for the expanded cut are
// exactly the first E-step of the next inner loop (or of finish()), which is
// therefore not recomputed. Likewise the cut's part of that E-step is the last
// inner loop's final one when no map has been blended in since (counted:
// expansions_reusing_inner_estep).
// Conversely, an inner loop that ends at its iteration cap right before a
// map leaves out its last E-step (EmOptions::skipLastEStep): the map changes
// the statistics, so the expansion after it would recompute that E-step, a
// quarter of all cell E-steps at k = 4096. Whether a map is wanted is then
// read from the n_eff the last M-step set the weights from (Eq. 10 with the
// responsibilities before it), not after it.
// Components with n_eff < min_n_eff are dropped (counted). After the last
// expansion one E-step on the final cut gives n_eff and the powers.
//
// Which components may ask for photons. §5.2 takes photons while any Gaussian
// explains fewer than 64, and is silent on a component in a sparse region:
// its share of the photons, w_s = n_eff(s) / n (Eqs. 9-10), is what more
// photons do not change, so n_eff(s) grows only as w_s per photon and one with
// w_s = 1e-5 needs 6.4 M photons to reach 64; read literally, the rule spends
// the whole budget on it (226 s at k = 1024 on volumetric-caustic). We let a
// short component ask only when its n_eff would reach the threshold within the
// budget at its present share: n_eff(s) max_photons / n >= n_eff_threshold.
// One that cannot is counted (`sparse_components`) and left as it is: its
// statistics stay noisy at any affordable photon count, and since its power
// is about w_s of the total its share of the image is as small. The budget's
// default is 4 n0: Table 2's fits used n = 1.75 to 2.25 n0 (917,504 photons
// at k = 4K, 294,912 and 4,718,592 at 1K and 16K, n0 = 128 k), so 4 n0 leaves
// twice the room the paper needed, and a component then asks only if it
// explains at least 16 of the first n0 photons.
//
// Temporal coherence (§5.4). With the optional input `previous` (the
// previous frame's mixture, imported from a file saved by the last frame)
// the previous frame's converged parameters replace the k-cell guess. §5.4
// says only that EM is seeded with them; how the cut and the iterations
// start is ours. The coarse initial cut (§5.1) and the long first inner loop
// are there to bring a poor guess near a solution cheaply; refitting a
// converged mixture on 8 k cells first would blur it towards the coarse
// cells (their covariances add to the components') and the expansions would
// then have to recover what the previous frame had already found. A seeded
// fit therefore starts on a cut of seeded_cut (31) cells per component,
// where the outer loop of a seeded fit stops, and treats the seed as the
// warm start it is: its first inner loop, like a refit, runs at most
// max_refit_iterations. The outer loop is Alg. 2's unchanged: maps while a
// component is short, expansions while one gains outer_epsilon. Seeded on
// 16 cells per component with the first loop's 8 iterations, the fit took
// as long as an independent one (spot-fog, k = 1024, a mixture of seed 1
// seeding a fit of seed 2: 3.89 against 3.64 CPU s; the loop used all 8
// iterations without F/n settling). Started on 28 cells per component
// (where an independent fit stops: 0.85 to 0.86 of the leaves, 27.5 cells
// per component at the default n0 and leaf size), seeded fits of spot-fog
// ended on 31 (7,936 cells at k = 256, 31,744 at k = 1024, of 32 leaves per
// component) after two expansions, the first gaining more than
// outer_epsilon and the second less, each with an E-step over the whole
// cut and a map before it. Started on 31, the first expansion's gain is
// already below outer_epsilon (0.0040 and 0.0027 nats per photon against
// 0.008) and line 11 ends the fit after one expansion and one map: at
// k = 256 and 1024, 0.065 and 0.49 CPU s against 0.10 and 0.75 (frame 1
// of tools/pem_animation.py seeded by frame 0, one run each); 30 is the
// smallest that ended after one expansion there, at k = 256 with a gain of
// 0.0071, too near the threshold to count on.
// A seed of fewer than k components (the previous fit dropped some, n_eff <
// min_n_eff) is completed to k before the fit by moment-preserving splits
// (splitToCount in pem_common.cpp; counted: restored_components), so that a
// drop lasts one frame instead of the rest of the sequence. A seed of k
// components is used as it is.
//
// Powers: the first map's powers are normalised to its paths (`emitted`), a
// later map's to the paths up to its last photon. The tree holds every
// photon's power times its map's emitted / the first map's, and the mixture's
// powers are rescaled by the first map's emitted / the last one's at the end:
// Phi_s = sum_A q_A(s) Phi_A / N_paths over all photons the fit used.
//
// Determinism: maps arrive in emission order and their photons are the first
// N of one sequence (photon pass), tree updates and EM reduce in fixed blocks,
// so the mixture is bit-identical for any thread count.
#include "passes/passes.h"

#include "engine/buffers/photon_buffers.h"
#include "engine/core/error.h"
#include "passes/pem/pem_common.h"
#include "jobs/work_context.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>

namespace fg {

namespace {

class PemFitPass final : public Pass {
public:
    void consumeBatch(PassContext& ctx, const std::string& slot) override {
        const VolumePhotonMap& map = ctx.input<VolumePhotonMap>(slot);
        const std::int64_t start = jobs::wallNanos();
        if (!started_) {
            begin(ctx, map);
        } else if (!map.photons.empty() && !done_) {
            const double scale = static_cast<double>(map.emitted) / static_cast<double>(firstEmitted_);
            tree_.update(map.photons.column<PhotonPosition>(), map.photons.column<PhotonPower>(), scale);
            lastInnerCurrent_ = false;
            photons_ += map.photons.size();
            lastEmitted_ = map.emitted;
            ++batches_;
        }
        if (started_ && !done_) advance(true);
        fitNs_ += jobs::wallNanos() - start;
        if (done_ || !needPhotons_) ctx.wantNoMoreBatches(slot);
    }

    void run(PassContext& ctx) override {
        const std::int64_t start = jobs::wallNanos();
        if (started_ && !done_) advance(false);
        if (started_) finish();
        fitNs_ += jobs::wallNanos() - start;
        GaussianMixture& mixture = ctx.createOutput<GaussianMixture>("gmm");
        if (!started_) return;
        // Powers over all paths the used photons came from (see the file comment).
        const double powerScale = static_cast<double>(firstEmitted_) / static_cast<double>(lastEmitted_);
        storeMixture(components_, photons_, mixture, powerScale);
        ctx.addItems(static_cast<std::int64_t>(photons_));
        ctx.addCounter("photons", static_cast<std::int64_t>(photons_));
        ctx.addCounter("batches", batches_);
        ctx.addCounter("inner_iterations", inner_);
        ctx.addCounter("outer_iterations", outer_);
        ctx.addCounter("cells", static_cast<std::int64_t>(cells_.size()));
        std::int64_t leaves = 0;
        for (const std::uint32_t node : cut_) leaves += tree_.isLeaf(node) ? 1 : 0;
        ctx.addCounter("cut_leaves", leaves);
        ctx.addCounter("tree_leaves", static_cast<std::int64_t>(treeLeaves_));
        const ShortComponents shortOnes = shortComponents();
        ctx.addCounter("short_components", shortOnes.reachable + shortOnes.sparse);
        ctx.addCounter("sparse_components", shortOnes.sparse);
        ctx.addCounter("fit_us", fitNs_ / 1000);
        ctx.addCounter("seeded", seeded_ ? 1 : 0);
        ctx.addCounter("restored_components", static_cast<std::int64_t>(restored_));
        ctx.addCounter("expansions_reusing_inner_estep", reusedExpansions_);
        // The last expansion's gain in F/n, in millionths of a nat (counters are integers).
        ctx.addCounter("expansion_gain_e6", static_cast<std::int64_t>(std::llround(lastGain_ * 1e6)));
        gmm::EmRun summary;
        summary.dropped = dropped_;
        summary.responsibilities.pairsKept = responsibilities_.pairsKept;
        summary.responsibilities.pairsPruned = responsibilities_.pairsPruned;
        summary.bounds = {boundPerPhoton_ * cells_.totalCount()};
        reportFit(ctx, summary, components_, cells_.totalCount());
    }

private:
    void begin(PassContext& ctx, const VolumePhotonMap& map) {
        const PassParams& params = ctx.params();
        const auto k = static_cast<std::size_t>(params.getInt("k"));
        cellsPerComponent_ = static_cast<std::size_t>(params.getInt("cut"));
        options_.tau = params.getFloat("tau");
        options_.epsilon = params.getFloat("epsilon");
        outerEpsilon_ = params.getFloat("outer_epsilon");
        options_.maxIterations = static_cast<int>(params.getInt("max_iterations"));
        maxRefitIterations_ = static_cast<int>(params.getInt("max_refit_iterations"));
        options_.minEffectiveCount = params.getFloat("min_n_eff");
        threshold_ = params.getFloat("n_eff_threshold");
        expandFraction_ = params.getFloat("expand_fraction");
        maxOuter_ = static_cast<int>(params.getInt("max_outer"));
        started_ = true;
        if (map.photons.empty()) {
            done_ = true;
            return;
        }
        tree_.build(map.photons.column<PhotonPosition>(), map.photons.column<PhotonPower>(),
                    static_cast<std::uint32_t>(params.getInt("leaf_size")));
        photons_ = map.photons.size();
        firstEmitted_ = lastEmitted_ = std::max<std::uint64_t>(map.emitted, 1);
        const auto maxPhotons = static_cast<std::uint64_t>(params.getInt("max_photons"));
        maxPhotons_ = maxPhotons > 0 ? maxPhotons : 4 * photons_;
        for (std::uint32_t node = 0; node < tree_.size(); ++node) treeLeaves_ += tree_.isLeaf(node) ? 1 : 0;
        options_.regCovar = ridgeInSceneUnits(tree_, params.getFloat("reg_covar"));
        if (ctx.hasInput("previous")) components_ = seedComponents(ctx.input<GaussianMixture>("previous"));
        seeded_ = !components_.empty();
        if (seeded_) {
            restored_ = splitToCount(components_, k);
            cut_ = tree_.cut(components_.size() * static_cast<std::size_t>(params.getInt("seeded_cut")));
        } else {
            components_ = gmm::componentsFromCells(cellsOf(tree_, tree_.cut(k)), options_.regCovar);
            cut_ = tree_.cut(k * cellsPerComponent_);
        }
    }

    // §5.4: the previous frame's converged parameters as the initial guess.
    // Weights are renormalised over the usable components (a component the
    // previous fit kept has weight > 0); n_eff and powers are the E-step's.
    static std::vector<gmm::EmComponent> seedComponents(const GaussianMixture& previous) {
        const GmmBuffer& buffer = previous.components;
        std::vector<gmm::EmComponent> seed;
        double total = 0.0;
        for (std::size_t s = 0; s < buffer.size(); ++s) {
            const double weight = buffer.column<GmmWeight>()[s];
            if (!(weight > 0.0)) continue;
            gmm::EmComponent c;
            c.weight = weight;
            c.gaussian = gaussianAt(buffer, s);
            seed.push_back(c);
            total += weight;
        }
        for (gmm::EmComponent& c : seed) c.weight /= total;
        return seed;
    }

    // Runs Alg. 2 until it ends or (streamOpen) needs the next map of photons.
    void advance(bool streamOpen) {
        while (!done_) {
            if (!expandNext_) {
                cells_ = cellsOf(tree_, cut_);
                gmm::EmOptions innerOptions = options_;
                if (outer_ > 0 || seeded_) innerOptions.maxIterations = maxRefitIterations_;
                // A loop that ends at its cap right before a map leaves out its
                // last E-step: the map changes the statistics, so the expansion
                // after it recomputes that E-step anyway (see the file comment).
                innerOptions.skipLastEStep = [&](const std::vector<gmm::EmComponent>&) {
                    return streamOpen && photons_ < maxPhotons_ && shortComponents().reachable > 0;
                };
                gmm::EmRun inner = gmm::runEm(cells_, components_, innerOptions, haveWarm_ ? &warm_ : nullptr);
                haveWarm_ = false;
                lastInner_ = std::move(inner.responsibilities);
                lastInnerCurrent_ = !inner.lastEStepSkipped;
                inner_ += inner.iterations;
                ++outer_;
                dropped_ += inner.dropped;
                expandNext_ = true;
                if (components_.empty()) {
                    done_ = true;
                    break;
                }
                if (streamOpen && photons_ < maxPhotons_ && shortComponents().reachable > 0) {
                    needPhotons_ = true;
                    return;
                }
            }
            expandNext_ = false;
            needPhotons_ = false;
            double gain = 0.0;
            if (outer_ >= maxOuter_ || !expandCut(gain)) {
                done_ = true;
                break;
            }
            // Per photon of the statistics the gain was computed on, in nats
            // (see the file comment).
            lastGain_ = gain / static_cast<double>(photons_);
            if (lastGain_ < outerEpsilon_) done_ = true;
        }
    }

    // The components below the n_eff threshold: those that would reach it
    // within max_photons at their present share of the photons, and the
    // sparse rest (see the file comment).
    struct ShortComponents {
        std::int64_t reachable = 0, sparse = 0;
    };
    ShortComponents shortComponents() const {
        const double photons = static_cast<double>(photons_);
        const double budget = static_cast<double>(maxPhotons_);
        ShortComponents count;
        for (const gmm::EmComponent& c : components_) {
            if (c.effectiveCount >= threshold_) continue;
            if (c.effectiveCount * budget >= threshold_ * photons) {
                ++count.reachable;
            } else {
                ++count.sparse;
            }
        }
        return count;
    }

    // Replaces the expand_fraction of the cut's expandable nodes with the
    // largest gain in F by their children and sets gain to the sum of the
    // chosen ones' (the change in F the expansion makes); false when none can
    // be expanded.
    bool expandCut(double& gain) {
        std::vector<std::uint32_t> expandable;
        for (const std::uint32_t node : cut_)
            if (!tree_.isLeaf(node) && tree_.statistics(node).count > 0) expandable.push_back(node);
        if (expandable.empty()) return false;
        std::vector<std::uint32_t> children;
        for (const std::uint32_t node : expandable) {
            children.push_back(tree_.left(node));
            children.push_back(tree_.right(node));
        }
        // One E-step over the cut and the children of its expandable nodes
        // gives both sides of every ΔF and, since each cell's terms depend on
        // that cell and the components only, also the first E-step of the
        // next inner loop on the expanded cut (and of finish()). The cut's
        // part is the last inner loop's final E-step unless a map has changed
        // the statistics since.
        std::vector<std::uint32_t> evaluated;
        for (const std::uint32_t node : cut_)
            if (tree_.statistics(node).count > 0) evaluated.push_back(node);
        const std::size_t cutRows = evaluated.size();
        for (const std::uint32_t node : children)
            if (tree_.statistics(node).count > 0) evaluated.push_back(node);
        gmm::Responsibilities cutPart, childPart;
        if (lastInnerCurrent_ && lastInner_.logZ.size() == cutRows) {
            cutPart = std::move(lastInner_);
            ++reusedExpansions_;
        } else {
            const std::vector<std::uint32_t> cutNodes(evaluated.begin(), evaluated.begin() + cutRows);
            gmm::eStep(cellsOf(tree_, cutNodes), components_, options_.tau, cutPart);
        }
        lastInnerCurrent_ = false;
        const std::vector<std::uint32_t> childNodes(evaluated.begin() + cutRows, evaluated.end());
        gmm::eStep(cellsOf(tree_, childNodes), components_, options_.tau, childPart);
        const gmm::Responsibilities r = gmm::concatenate(cutPart, childPart);
        std::vector<std::pair<std::uint32_t, std::size_t>> rowByNode(evaluated.size());
        for (std::size_t i = 0; i < evaluated.size(); ++i) rowByNode[i] = {evaluated[i], i};
        std::sort(rowByNode.begin(), rowByNode.end());
        const auto rowOf = [&](std::uint32_t node) {
            return std::lower_bound(rowByNode.begin(), rowByNode.end(), std::make_pair(node, std::size_t{0}))->second;
        };
        // log Z of an empty node is not needed (n = 0).
        const auto logZOf = [&](const std::vector<std::uint32_t>& nodes) {
            std::vector<double> logZ(nodes.size(), 0.0);
            for (std::size_t i = 0; i < nodes.size(); ++i)
                if (tree_.statistics(nodes[i]).count > 0) logZ[i] = r.logZ[rowOf(nodes[i])];
            return logZ;
        };
        const std::vector<double> parentLogZ = logZOf(expandable);
        const std::vector<double> childLogZ = logZOf(children);
        const auto n = [&](std::uint32_t node) { return static_cast<double>(tree_.statistics(node).count); };
        std::vector<double> nodeGain(expandable.size());
        for (std::size_t i = 0; i < expandable.size(); ++i) {
            nodeGain[i] = n(children[2 * i]) * childLogZ[2 * i] + n(children[2 * i + 1]) * childLogZ[2 * i + 1] -
                      n(expandable[i]) * parentLogZ[i];
        }
        std::vector<std::size_t> order(expandable.size());
        std::iota(order.begin(), order.end(), std::size_t{0});
        std::sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) {
            return nodeGain[a] > nodeGain[b] || (nodeGain[a] == nodeGain[b] && expandable[a] < expandable[b]);
        });
        const auto take = std::max<std::size_t>(
            1, static_cast<std::size_t>(std::ceil(expandFraction_ * static_cast<double>(expandable.size()))));
        std::vector<std::uint32_t> chosen;
        gain = 0.0;
        for (std::size_t i = 0; i < std::min(take, order.size()); ++i) {
            chosen.push_back(expandable[order[i]]);
            gain += nodeGain[order[i]];
        }
        std::sort(chosen.begin(), chosen.end());
        std::vector<std::uint32_t> next;
        next.reserve(cut_.size() + chosen.size());
        for (const std::uint32_t node : cut_) {
            if (std::binary_search(chosen.begin(), chosen.end(), node)) {
                next.push_back(tree_.left(node));
                next.push_back(tree_.right(node));
            } else {
                next.push_back(node);
            }
        }
        std::sort(next.begin(), next.end());
        cut_ = std::move(next);
        std::vector<std::size_t> rows;
        rows.reserve(cut_.size());
        for (const std::uint32_t node : cut_)
            if (tree_.statistics(node).count > 0) rows.push_back(rowOf(node));
        warm_ = gmm::selectCells(r, rows);
        haveWarm_ = true;
        return true;
    }

    // n_eff and powers of the final components on the final cut.
    void finish() {
        if (components_.empty() || tree_.nodes.empty()) return;
        cells_ = cellsOf(tree_, cut_);
        if (haveWarm_) {
            responsibilities_ = std::move(warm_);
            haveWarm_ = false;
            boundPerPhoton_ = gmm::boundOf(cells_, responsibilities_) / cells_.totalCount();
        } else if (lastInnerCurrent_ && lastInner_.logZ.size() == cells_.size()) {
            responsibilities_ = std::move(lastInner_);
            lastInnerCurrent_ = false;
            boundPerPhoton_ = gmm::boundOf(cells_, responsibilities_) / cells_.totalCount();
        } else {
            boundPerPhoton_ = gmm::eStep(cells_, components_, options_.tau, responsibilities_) / cells_.totalCount();
        }
        gmm::mStep(cells_, responsibilities_, options_.regCovar, components_, false);
    }

    gmm::EmOptions options_;
    std::size_t cellsPerComponent_ = 8;
    double threshold_ = 64.0, expandFraction_ = 0.5, outerEpsilon_ = 8e-3;
    int maxOuter_ = 64, maxRefitIterations_ = 1;
    EmTree tree_;
    std::vector<std::uint32_t> cut_;
    std::vector<gmm::EmComponent> components_;
    gmm::EmCells cells_;
    gmm::Responsibilities responsibilities_;
    gmm::Responsibilities warm_;  // the expansion's E-step on the new cut (see expandCut)
    gmm::Responsibilities lastInner_;  // the last inner loop's final E-step on cut_
    bool lastInnerCurrent_ = false;    // ... and no map has been blended in since
    bool haveWarm_ = false;
    bool started_ = false, done_ = false, needPhotons_ = false, expandNext_ = false, seeded_ = false;
    double boundPerPhoton_ = 0.0, lastGain_ = 0.0;
    std::uint64_t photons_ = 0, maxPhotons_ = 0, firstEmitted_ = 1, lastEmitted_ = 1;
    std::int64_t batches_ = 0, reusedExpansions_ = 0, inner_ = 0, outer_ = 0, treeLeaves_ = 0, fitNs_ = 0;
    std::size_t dropped_ = 0, restored_ = 0;
};

}  // namespace

PassRegistration pemFitPass() {
    PassSpec spec;
    spec.name = "pem_fit";
    spec.doc = "Progressive EM (Jakob et al. 2011 Alg. 2): a k-term Gaussian mixture fitted on a refined kd-tree cut, "
               "taking further volume photons from the stream while a component has too few";
    spec.inputs = {{"photons", "VolumePhotonMap",
                    "volume photons, streamed: the photon pass's volume_photons target (n0 = 128 k), then maps of "
                    "volume_batch (32 k) while wanted",
                    true},
                   {"previous", "GaussianMixture",
                    "the previous frame's fitted mixture (import it), which replaces the initial guess (a seed of "
                    "fewer than k components is completed to k by splitting its widest heavy ones) and starts the fit on a cut of seeded_cut cells per component (§5.4, temporal "
                    "coherence)",
                    false, true}};
    spec.outputs = {{"gmm", "GaussianMixture",
                     "the fitted mixture: weight, power, mean, covariance and factors, n_eff (parameters rounded "
                     "to the floats it is saved in)"}};
    spec.params = {
        {"k", ParamType::Int, std::int64_t{4096}, 1, 1 << 22, {}, "Gaussian components (initial guess: a k-cell cut)"},
        {"cut", ParamType::Int, std::int64_t{8}, 1, 1 << 10, {}, "cells of the initial cut per component (§5.1: 8)"},
        {"seeded_cut", ParamType::Int, std::int64_t{31}, 1, 1 << 10, {},
         "cells of the initial cut per component when a previous mixture seeds the fit (§5.4)"},
        {"tau", ParamType::Float, 1e-4, 0.0, 1.0, {},
         "sparsity: pruned responsibility mass per cell <= tau Z_A (0: all cell-component pairs)"},
        {"epsilon", ParamType::Float, 1e-4, 0.0, 1.0, {},
         "inner convergence: F/n changes by less than this between EM iterations (relative above |F/n| = 1)"},
        {"outer_epsilon", ParamType::Float, 8e-3, 0.0, 10.0, {},
         "outer convergence (Alg. 2 line 11): a cut expansion raises F/n by less than this many nats per photon "
         "(1e-4 refines to about 0.99 of the tree's leaves; Table 2's cuts hold 0.67 to 0.94 of them)"},
        {"max_iterations", ParamType::Int, std::int64_t{8}, 1, 100000, {},
         "most EM iterations of the first inner loop (from the initial guess; Table 2's fits took 10 to 20 in all)"},
        {"max_refit_iterations", ParamType::Int, std::int64_t{1}, 1, 100000, {},
         "most EM iterations of each later inner loop (after a cut expansion or a map; the previous solution is a "
         "warm start)"},
        {"max_outer", ParamType::Int, std::int64_t{64}, 1, 100000, {}, "most outer iterations (cut expansions)"},
        {"n_eff_threshold", ParamType::Float, 64.0, 0.0, 1e12, {},
         "more photons are taken while a live component explains fewer than this (§5.2: 64) and would reach it "
         "within max_photons at its present share of the photons"},
        {"expand_fraction", ParamType::Float, 0.5, 1e-6, 1.0, {},
         "share of the expandable cut nodes replaced by their children per outer iteration (§5.2: 50 %)"},
        {"max_photons", ParamType::Int, std::int64_t{0}, 0, 1e15, {},
         "no more photons are taken beyond this many (0 = 4 times the first map's; Table 2 used up to 2.25)"},
        {"leaf_size", ParamType::Int, std::int64_t{4}, 1, 64, {},
         "largest photon count of a statistics-tree leaf (§5.1: a leaf below 5 photons)"},
        {"reg_covar", ParamType::Float, 1e-6, 0.0, 1.0, {},
         "ridge added to covariance diagonals, in unit-box coordinates (the photons' longest side = 1)"},
        {"min_n_eff", ParamType::Float, 1.0, 0.0, 1e12, {}, "components explaining fewer photons are dropped"},
    };
    const auto preflight = [](const PreflightContext& pf) {
        refuseAnisotropicMedia(pf);
        // Powers are rescaled by the maps' path counts, which only a volume-photon target gives.
        const PassParams* producer = pf.producerParams ? pf.producerParams("photons") : nullptr;
        if (producer && pf.producerPass && pf.producerPass("photons") == "photon" &&
            producer->getInt("volume_photons") == 0) {
            throw InputError(pf.source + ": pass '" + pf.instance +
                             "': the photon pass feeding pem_fit needs volume_photons > 0 (the first n0 photons; "
                             "volume_batch sets the later maps)");
        }
    };
    return {spec, [] { return std::make_unique<PemFitPass>(); }, preflight};
}

}  // namespace fg
