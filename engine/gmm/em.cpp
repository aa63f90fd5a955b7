// Accelerated EM with sparsity (Jakob et al. 2011 §3.6, §5.3); see em.h.
#include "engine/gmm/em.h"

#include "engine/gmm/fast_math.h"
#include "jobs/parallel.h"

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <limits>
#include <numeric>

namespace fg::gmm {

namespace {

// Fixed block counts: reductions merge in block order, independent of threads.
constexpr std::size_t kEStepBlocks = 64;
constexpr std::size_t kMStepBlocks = 32;
// With a leaf's terms computed in one vectorised loop and gathered without
// a branch, opening fewer, larger leaves is cheaper than walking further
// (pem_fit at k = 1024 and 4096: 32 -> 64 about 10 % faster, 128 no faster).
constexpr std::uint32_t kComponentLeafSize = 64;

// A hierarchy over the components' means for the sparse E-step. For a cell
// (mean m, covariance C) and a component s whose mean lies in a node's box,
//   log w_s + <log g_s>_A = log w_s + log N_s - 1/2 [(m - mu_s)^T Sigma_s^-1 (m - mu_s) + tr(Sigma_s^-1 C)]
//                        <= a_s - b_s x,   a_s = log w_s + log N_s,  b_s = 1 / (2 lambda_max(Sigma_s)),
// with x = dist(m, box)^2 + tr(C), since a quadratic form is at least
// lambda_max^-1 times the squared length and tr(Sigma^-1 C) >= tr(C) / lambda_max.
// Each component gives a line in x, so the tightest such bound of a node is
// the upper envelope of its components' lines over x >= 0, which each node
// keeps (a few lines). Combining the node's largest a with its largest
// lambda_max instead (one line) pairs the normaliser of the thinnest Gaussian
// with the reach of the widest, and prunes little.
struct ComponentTree {
    struct Node {
        Vec3d lo, hi;
        std::uint32_t begin = 0, end = 0, left = 0, right = 0;
        std::uint32_t lineBegin = 0, lineEnd = 0;  // its envelope in `lines`
        bool leaf = true;
    };
    // a - b x, optimal on [from, next line's from).
    struct Line {
        double a = 0.0, b = 0.0, from = 0.0;
    };
    // What a cell's term reads of a component, in leaf order so that a leaf's
    // components are adjacent, one column per scalar so that a leaf's terms
    // are computed in one loop the compiler vectorises:
    // log w_s + <log g_s>_A = offset - 1/2 tr(P_s (C_A + d d^T)), d = m_A - mu_s,
    // offset = log w_s + log N_s, P_s = Sigma_s^-1 (upper triangle xx, xy, xz, yy, yz, zz).
    struct PackedColumns {
        std::vector<double> meanX, meanY, meanZ;
        std::array<std::vector<double>, 6> precision;
        std::vector<double> offset;
    };
    // The same columns in single precision, only to decide which of a leaf's
    // terms can pass the walk's skip bound (four terms per SSE2 register
    // instead of two); terms that can are then computed in double as above.
    struct FloatColumns {
        std::vector<float> meanX, meanY, meanZ;
        std::array<std::vector<float>, 6> precision;
        std::vector<float> offset;
    };
    // Per leaf, what bounds the single-precision terms' error (see candidates()).
    struct LeafScale {
        Vec3d maxAbsMean{0.0}, maxDiagonalPrecision{0.0};
        double maxAbsOffset = 0.0;
    };
    std::vector<Node> nodes;
    std::vector<Line> lines;
    std::vector<std::uint32_t> order;
    std::vector<double> logWeight;
    PackedColumns packed;  // by position in `order`
    FloatColumns single;   // by position in `order`
    std::vector<LeafScale> leafScale;  // by node index; set for leaves

    explicit ComponentTree(const std::vector<EmComponent>& components) {
        const std::size_t k = components.size();
        order.resize(k);
        std::iota(order.begin(), order.end(), 0u);
        logWeight.resize(k);
        std::vector<Line> own(k);
        for (std::size_t s = 0; s < k; ++s) {
            logWeight[s] = std::log(components[s].weight);
            own[s].a = logWeight[s] + components[s].gaussian.factors.logNormaliser;
            own[s].b = 0.5 / components[s].gaussian.covariance.largestEigenvalue();
        }
        if (k == 0) return;
        nodes.reserve(2 * k / kComponentLeafSize + 2);
        build(0, static_cast<std::uint32_t>(k), components, own);
        packed.meanX.resize(k);
        packed.meanY.resize(k);
        packed.meanZ.resize(k);
        for (std::vector<double>& column : packed.precision) column.resize(k);
        packed.offset.resize(k);
        for (std::size_t i = 0; i < k; ++i) {
            const EmComponent& c = components[order[i]];
            packed.meanX[i] = c.gaussian.mean.x;
            packed.meanY[i] = c.gaussian.mean.y;
            packed.meanZ[i] = c.gaussian.mean.z;
            for (std::size_t e = 0; e < 6; ++e) packed.precision[e][i] = c.gaussian.factors.precision.v[e];
            packed.offset[i] = own[order[i]].a;
        }
        single.meanX.assign(packed.meanX.begin(), packed.meanX.end());
        single.meanY.assign(packed.meanY.begin(), packed.meanY.end());
        single.meanZ.assign(packed.meanZ.begin(), packed.meanZ.end());
        for (std::size_t e = 0; e < 6; ++e)
            single.precision[e].assign(packed.precision[e].begin(), packed.precision[e].end());
        single.offset.assign(packed.offset.begin(), packed.offset.end());
        leafScale.resize(nodes.size());
        for (std::size_t n = 0; n < nodes.size(); ++n) {
            if (!nodes[n].leaf) continue;
            LeafScale& scale = leafScale[n];
            for (std::uint32_t i = nodes[n].begin; i < nodes[n].end; ++i) {
                scale.maxAbsMean = glm::max(scale.maxAbsMean, glm::abs(Vec3d(packed.meanX[i], packed.meanY[i], packed.meanZ[i])));
                scale.maxDiagonalPrecision = glm::max(
                    scale.maxDiagonalPrecision, Vec3d(packed.precision[0][i], packed.precision[3][i], packed.precision[5][i]));
                scale.maxAbsOffset = std::max(scale.maxAbsOffset, std::abs(packed.offset[i]));
            }
        }
    }

    // log w_s + <log g_s>_A of the component at position i: the arithmetic of
    // logits() for one term, so that both give the same bits.
    double logit(std::uint32_t i, const Vec3d& mean, const Sym3& covariance) const {
        const std::array<double, 6>& c = covariance.v;
        const double dx = mean.x - packed.meanX[i], dy = mean.y - packed.meanY[i], dz = mean.z - packed.meanZ[i];
        const double n0 = c[0] + dx * dx, n1 = c[1] + dx * dy, n2 = c[2] + dx * dz;
        const double n3 = c[3] + dy * dy, n4 = c[4] + dy * dz, n5 = c[5] + dz * dz;
        const double trace = packed.precision[0][i] * n0 + packed.precision[3][i] * n3 + packed.precision[5][i] * n5 +
                             2.0 * (packed.precision[1][i] * n1 + packed.precision[2][i] * n2 +
                                    packed.precision[4][i] * n4);
        return packed.offset[i] - 0.5 * trace;
    }

    // The positions (relative to the leaf's begin) of the leaf's terms whose
    // logit may be at least `threshold`, a superset of those that are: each
    // term is computed in single precision and raised by a bound on its
    // error. With P = Sigma_s^-1 and N = C_A + d d^T both positive
    // semidefinite, |p_ij n_ij| <= sqrt(p_ii p_jj n_ii n_jj), so the sum of
    // the trace's products in absolute value is at most 3 D, D = sum_i p_ii
    // n_ii, and the rounding of the inputs and of the ten operations moves
    // the trace by at most about 36 u D (u = 2^-24). The difference d is
    // rounded by delta_i <= 4 u (|m_i| + |mu_i|); that moves d^T P d by
    // 2 delta^T P d + delta^T P delta <= eta tr(P N) + (1/eta + 1) E, with
    // E = 3 sum_i p_ii delta_i^2 >= delta^T P delta and tr(P N) <= 3 D, and
    // D itself by at most eta D + E / (3 eta). With eta = 2e-4 the trace is
    // off by less than 7e-4 D + 5004 E, so the logit (half of it, plus 4 u
    // of the offset and of the threshold) is raised by 1e-3 D / 2 per term,
    // in single precision, and by 5001 E (twice what is needed) + 4 u
    // (|offset| + |threshold|) + 1e-3 per leaf, in double, with the leaf's
    // largest p_ii, |mu_i| and |offset|.
    std::uint32_t candidates(std::uint32_t n, const Vec3d& mean, const Sym3& covariance, double threshold,
                             std::uint32_t* position) const {
        const Node& node = nodes[n];
        const LeafScale& scale = leafScale[n];
        constexpr double u = 0x1p-24;
        double e = 0.0;
        for (int axis = 0; axis < 3; ++axis) {
            const double delta = 4.0 * u * (std::abs(mean[axis]) + scale.maxAbsMean[axis]);
            e += scale.maxDiagonalPrecision[axis] * delta * delta;
        }
        e *= 3.0;
        const double slack = 5001.0 * e + 4.0 * u * (scale.maxAbsOffset + std::abs(threshold)) + 1e-3;
        const float lowest = static_cast<float>(threshold - slack);
        const float mx = static_cast<float>(mean.x), my = static_cast<float>(mean.y), mz = static_cast<float>(mean.z);
        const std::array<double, 6>& cd = covariance.v;
        const float c0 = static_cast<float>(cd[0]), c1 = static_cast<float>(cd[1]), c2 = static_cast<float>(cd[2]);
        const float c3 = static_cast<float>(cd[3]), c4 = static_cast<float>(cd[4]), c5 = static_cast<float>(cd[5]);
        const float* fx = single.meanX.data() + node.begin;
        const float* fy = single.meanY.data() + node.begin;
        const float* fz = single.meanZ.data() + node.begin;
        const float* p0 = single.precision[0].data() + node.begin;
        const float* p1 = single.precision[1].data() + node.begin;
        const float* p2 = single.precision[2].data() + node.begin;
        const float* p3 = single.precision[3].data() + node.begin;
        const float* p4 = single.precision[4].data() + node.begin;
        const float* p5 = single.precision[5].data() + node.begin;
        const float* offset = single.offset.data() + node.begin;
        const std::uint32_t count = node.end - node.begin;
        alignas(16) std::array<float, kComponentLeafSize + 3> upper;
        for (std::uint32_t i = 0; i < count; ++i) {
            const float dx = mx - fx[i], dy = my - fy[i], dz = mz - fz[i];
            const float n0 = c0 + dx * dx, n1 = c1 + dx * dy, n2 = c2 + dx * dz;
            const float n3 = c3 + dy * dy, n4 = c4 + dy * dz, n5 = c5 + dz * dz;
            const float diagonal = p0[i] * n0 + p3[i] * n3 + p5[i] * n5;
            const float offDiagonal = p1[i] * n1 + p2[i] * n2 + p4[i] * n4;
            upper[i] = offset[i] - 0.5f * (diagonal * (1.0f - 1e-3f) + 2.0f * offDiagonal);
        }
        // Few terms pass: four compared at once, and only the passing ones
        // visited (in order). "Not below" lets a NaN through, as the double
        // test does.
        upper[count] = upper[count + 1] = upper[count + 2] = 0.0f;  // read below, masked off
        std::uint32_t passing = 0;
        const __m128 low = _mm_set1_ps(lowest);
        for (std::uint32_t i = 0; i < count; i += 4) {
            const unsigned valid = count - i >= 4 ? 0xFu : (1u << (count - i)) - 1u;
            unsigned mask = static_cast<unsigned>(_mm_movemask_ps(_mm_cmpnlt_ps(_mm_load_ps(upper.data() + i), low))) & valid;
            while (mask != 0u) {
                position[passing++] = i + static_cast<std::uint32_t>(std::countr_zero(mask));
                mask &= mask - 1u;
            }
        }
        return passing;
    }

    // The terms of components [begin, end) for one cell, into `out`; the same
    // arithmetic, in the same order, as Sym3::traceProduct(C + outer(d)).
    void logits(std::uint32_t begin, std::uint32_t end, const Vec3d& mean, const Sym3& covariance,
                double* out) const {
        const double* mx = packed.meanX.data() + begin;
        const double* my = packed.meanY.data() + begin;
        const double* mz = packed.meanZ.data() + begin;
        const double* p0 = packed.precision[0].data() + begin;
        const double* p1 = packed.precision[1].data() + begin;
        const double* p2 = packed.precision[2].data() + begin;
        const double* p3 = packed.precision[3].data() + begin;
        const double* p4 = packed.precision[4].data() + begin;
        const double* p5 = packed.precision[5].data() + begin;
        const double* offset = packed.offset.data() + begin;
        const std::uint32_t count = end - begin;
        const std::array<double, 6>& c = covariance.v;
        for (std::uint32_t i = 0; i < count; ++i) {
            const double dx = mean.x - mx[i], dy = mean.y - my[i], dz = mean.z - mz[i];
            const double n0 = c[0] + dx * dx, n1 = c[1] + dx * dy, n2 = c[2] + dx * dz;
            const double n3 = c[3] + dy * dy, n4 = c[4] + dy * dz, n5 = c[5] + dz * dz;
            const double trace = p0[i] * n0 + p3[i] * n3 + p5[i] * n5 + 2.0 * (p1[i] * n1 + p2[i] * n2 + p4[i] * n4);
            out[i] = offset[i] - 0.5 * trace;
        }
    }

    // Upper envelope over x >= 0 of the lines a - b x of components [begin, end).
    void envelope(std::uint32_t begin, std::uint32_t end, const std::vector<Line>& own, Node& node) {
        std::vector<Line> candidates;
        candidates.reserve(end - begin);
        for (std::uint32_t i = begin; i < end; ++i) candidates.push_back(own[order[i]]);
        // By slope -b ascending (b descending); for equal b only the largest a matters.
        std::sort(candidates.begin(), candidates.end(), [](const Line& p, const Line& q) {
            return p.b > q.b || (p.b == q.b && p.a > q.a);
        });
        std::vector<Line> hull;
        const auto crossing = [](const Line& p, const Line& q) { return (p.a - q.a) / (p.b - q.b); };  // p.b > q.b
        for (const Line& line : candidates) {
            if (!hull.empty() && hull.back().b == line.b) continue;
            // Steeper lines win for small x; a line optimal nowhere in [0, inf) is dropped.
            while (!hull.empty()) {
                const double from = crossing(hull.back(), line);
                if (from <= hull.back().from) {
                    hull.pop_back();
                    continue;
                }
                break;
            }
            Line next = line;
            next.from = hull.empty() ? 0.0 : std::max(0.0, crossing(hull.back(), line));
            if (!hull.empty() && next.from <= 0.0) hull.clear();
            hull.push_back(next);
        }
        hull.front().from = 0.0;
        node.lineBegin = static_cast<std::uint32_t>(lines.size());
        lines.insert(lines.end(), hull.begin(), hull.end());
        node.lineEnd = static_cast<std::uint32_t>(lines.size());
    }

    std::uint32_t build(std::uint32_t begin, std::uint32_t end, const std::vector<EmComponent>& components,
                        const std::vector<Line>& own) {
        const auto index = static_cast<std::uint32_t>(nodes.size());
        nodes.emplace_back();
        Node node;
        node.begin = begin;
        node.end = end;
        node.lo = Vec3d(std::numeric_limits<double>::max());
        node.hi = Vec3d(-std::numeric_limits<double>::max());
        for (std::uint32_t i = begin; i < end; ++i) {
            const std::uint32_t s = order[i];
            node.lo = glm::min(node.lo, components[s].gaussian.mean);
            node.hi = glm::max(node.hi, components[s].gaussian.mean);
        }
        if (end - begin > kComponentLeafSize) {
            const Vec3d extent = node.hi - node.lo;
            const int axis = extent.x >= extent.y && extent.x >= extent.z ? 0 : (extent.y >= extent.z ? 1 : 2);
            const std::uint32_t mid = begin + (end - begin) / 2;
            std::nth_element(order.begin() + begin, order.begin() + mid, order.begin() + end,
                             [&](std::uint32_t a, std::uint32_t b) {
                                 const double xa = components[a].gaussian.mean[axis];
                                 const double xb = components[b].gaussian.mean[axis];
                                 return xa < xb || (xa == xb && a < b);
                             });
            node.leaf = false;
            node.left = build(begin, mid, components, own);
            node.right = build(mid, end, components, own);
        }
        envelope(begin, end, own, node);
        nodes[index] = node;
        return index;
    }

    // Bound on log w_s + <log g_s>_A over the node's components; `spread` = tr(C_A).
    double logBound(std::uint32_t n, const Vec3d& m, double spread) const {
        const Node& node = nodes[n];
        const Vec3d gap = glm::max(Vec3d(0.0), glm::max(node.lo - m, m - node.hi));
        const double x = glm::dot(gap, gap) + spread;
        const Line* first = lines.data() + node.lineBegin;
        const Line* last = lines.data() + node.lineEnd;
        // Linear from the steepest line: most bounds are asked of nodes near
        // the cell (small x), where the first lines hold.
        const Line* line = first;
        while (line + 1 != last && line[1].from <= x) ++line;
        return line->a - line->b * x;
    }
};

// An open node of the walk: its bound, that bound times its component count
// relative to the root's (its share of the queued mass), and its index.
struct OpenNode {
    double logBound = 0.0, mass = 0.0;
    std::uint32_t node = 0;
    // Best first; ties by the larger node index first.
    bool operator<(const OpenNode& o) const { return logBound < o.logBound || (logBound == o.logBound && node < o.node); }
};

struct CellTerms {
    std::vector<OpenNode> open;  // the walk's heap, kept between cells
    std::vector<std::uint32_t> component;
    std::vector<double> logit;  // log w_s + <log g_s>_A
    // exp(logit - reference), kept from the walk's running sum so that the
    // responsibilities need no second exponential per term: q = scaled *
    // exp(reference - log Z_A). Empty when the terms came from allTerms.
    std::vector<double> scaled;
    double reference = 0.0;
    std::uint64_t pruned = 0;
    double prunedShare = 0.0;
};

void allTerms(const std::vector<EmComponent>& components, const std::vector<double>& logWeight, const Vec3d& mean,
              const Sym3& covariance, CellTerms& terms) {
    for (std::size_t s = 0; s < components.size(); ++s) {
        terms.component.push_back(static_cast<std::uint32_t>(s));
        terms.logit.push_back(logWeight[s] + components[s].gaussian.expectedLogDensity(mean, covariance));
    }
}

// Best-first walk of the component tree for one cell (§5.3).
void sparseTerms(const ComponentTree& tree, const Vec3d& mean, const Sym3& covariance, double tau,
                 bool singlePrecisionFilter, CellTerms& terms) {
    const double spread = covariance.trace();
    const double reference = tree.logBound(0, mean, spread);
    terms.reference = reference;
    std::vector<OpenNode>& open = terms.open;
    open.clear();
    const auto countOf = [&](std::uint32_t n) { return static_cast<double>(tree.nodes[n].end - tree.nodes[n].begin); };
    open.push_back(OpenNode{reference, countOf(0), 0});
    double queued = open.front().mass;
    double found = 0.0;
    const auto push = [&](const OpenNode& n) {
        open.push_back(n);
        std::push_heap(open.begin(), open.end());
    };
    bool stopped = false;
    while (!open.empty() && !stopped) {
        if (found > 0.0 && queued <= tau * found) break;
        std::pop_heap(open.begin(), open.end());
        OpenNode current = open.back();
        open.pop_back();
        // Descends while the better child would be the next node popped
        // anyway (its bound at least the heap's largest), without queueing
        // it: the same order of visits and the same stop as push and pop.
        for (;;) {
            queued -= current.mass;
            const ComponentTree::Node& node = tree.nodes[current.node];
            if (node.leaf) {
                // A term below tau found / (10 k) is not exponentiated: it is
                // counted as pruned and that bound added to the queued mass,
                // so the terms skipped over the whole walk add at most tau / 10
                // of Z_A to the budget the stop and the drop below respect.
                const double skipMass = tau * found / (10.0 * static_cast<double>(tree.order.size()));
                const double skipBelow = found > 0.0 ? std::log(skipMass) : -std::numeric_limits<double>::infinity();
                std::array<double, kComponentLeafSize> leafLogits;
                const std::uint32_t leafCount = node.end - node.begin;
                // The terms above the skip bound are gathered without a branch
                // (which of a leaf's terms pass is unpredictable) and
                // exponentiated two at a time (fast_math.h, 1e-9 relative).
                alignas(16) std::array<double, kComponentLeafSize + 1> relative;
                std::array<std::uint32_t, kComponentLeafSize> position;
                std::uint32_t passing = 0;
                const double threshold = reference + skipBelow;
                if (singlePrecisionFilter && std::isfinite(threshold)) {
                    // Most of a leaf's terms fall below the skip bound: a
                    // single-precision pass with a bound on its error finds
                    // those that may not, and only they are computed in
                    // double, with the same arithmetic and the same test as
                    // the loop below, so the same terms pass with the same
                    // bits.
                    std::array<std::uint32_t, kComponentLeafSize> candidate;
                    const std::uint32_t candidates =
                        tree.candidates(current.node, mean, covariance, threshold, candidate.data());
                    for (std::uint32_t j = 0; j < candidates; ++j) {
                        const std::uint32_t i = candidate[j];
                        leafLogits[i] = tree.logit(node.begin + i, mean, covariance);
                        relative[passing] = leafLogits[i] - reference;
                        position[passing] = i;
                        passing += relative[passing] < skipBelow ? 0u : 1u;
                    }
                } else {
                    tree.logits(node.begin, node.end, mean, covariance, leafLogits.data());
                    for (std::uint32_t i = 0; i < leafCount; ++i) {
                        relative[passing] = leafLogits[i] - reference;
                        position[passing] = i;
                        passing += relative[passing] < skipBelow ? 0u : 1u;
                    }
                }
                const std::uint32_t skipped = leafCount - passing;
                queued += skipMass * static_cast<double>(skipped);
                terms.pruned += skipped;
                relative[passing] = 0.0;
                alignas(16) std::array<double, kComponentLeafSize + 1> scaled;
                for (std::uint32_t j = 0; j < passing; j += 2)
                    _mm_store_pd(scaled.data() + j, simd::exp(_mm_load_pd(relative.data() + j)));
                for (std::uint32_t j = 0; j < passing; ++j) {
                    const std::uint32_t i = position[j];
                    terms.component.push_back(tree.order[node.begin + i]);
                    terms.logit.push_back(leafLogits[i]);
                    terms.scaled.push_back(scaled[j]);
                    found += scaled[j];
                }
                break;
            }
            const double leftBound = tree.logBound(node.left, mean, spread);
            const double rightBound = tree.logBound(node.right, mean, spread);
            alignas(16) std::array<double, 2> share;
            _mm_store_pd(share.data(), simd::exp(_mm_set_pd(rightBound - reference, leftBound - reference)));
            const OpenNode left{leftBound, countOf(node.left) * share[0], node.left};
            const OpenNode right{rightBound, countOf(node.right) * share[1], node.right};
            queued += left.mass;
            queued += right.mass;
            const bool leftBetter = right < left;
            const OpenNode& better = leftBetter ? left : right;
            push(leftBetter ? right : left);
            if (open.front() < better) {
                if (found > 0.0 && queued <= tau * found) {
                    push(better);
                    stopped = true;
                    break;
                }
                current = better;
                continue;
            }
            push(better);
            break;
        }
    }
    for (const OpenNode& left : open) terms.pruned += tree.nodes[left.node].end - tree.nodes[left.node].begin;
    // The walk stops with queued <= tau found, and what is left of that
    // budget is spent on the kept terms themselves (§5.3: pairs are dropped
    // while the error stays within tau): terms each at most
    // (tau found - queued) / ((1 + tau) kept) are dropped, so that the
    // dropped and queued mass together stay within tau of the Z_A that
    // remains, and the M-step and the lists carry only terms that matter.
    // The largest term always stays (the kept terms sum to found).
    queued = std::max(0.0, queued);
    double dropped = 0.0;
    const double budget = (tau * found - queued) / (1.0 + tau);
    if (found > 0.0 && budget > 0.0 && !terms.scaled.empty()) {
        const double each = budget / static_cast<double>(terms.scaled.size());
        std::size_t kept = 0;
        for (std::size_t t = 0; t < terms.scaled.size(); ++t) {
            if (terms.scaled[t] <= each) {
                dropped += terms.scaled[t];
                ++terms.pruned;
                continue;
            }
            terms.component[kept] = terms.component[t];
            terms.logit[kept] = terms.logit[t];
            terms.scaled[kept] = terms.scaled[t];
            ++kept;
        }
        terms.component.resize(kept);
        terms.logit.resize(kept);
        terms.scaled.resize(kept);
    }
    terms.prunedShare = found > 0.0 ? (queued + dropped) / (found - dropped) : 0.0;
}

}  // namespace

double EmCells::totalCount() const { return std::accumulate(count.begin(), count.end(), 0.0); }

double eStep(const EmCells& cells, const std::vector<EmComponent>& components, double tau, Responsibilities& out,
             bool singlePrecisionFilter) {
    const std::size_t cellCount = cells.size();
    const ComponentTree tree(components);
    struct Block {
        std::vector<std::uint32_t> cellEntries;  // entries per cell of the block
        std::vector<std::uint32_t> component;
        std::vector<double> q;
        std::vector<double> logZ;
        std::vector<std::uint32_t> prunedPerCell;
        std::uint64_t pruned = 0;
        double maxPrunedShare = 0.0;
    };
    const std::size_t blocks = std::min(kEStepBlocks, std::max<std::size_t>(cellCount, 1));
    std::vector<Block> parts(blocks);
    jobs::parallelForBlocks(cellCount, blocks, [&](std::size_t b, jobs::IndexRange range) {
        Block& block = parts[b];
        CellTerms terms;
        for (std::size_t a = range.begin; a != range.end; ++a) {
            terms.component.clear();
            terms.logit.clear();
            terms.scaled.clear();
            terms.pruned = 0;
            terms.prunedShare = 0.0;
            if (tau > 0.0) sparseTerms(tree, cells.mean[a], cells.covariance[a], tau, singlePrecisionFilter, terms);
            if (terms.component.empty()) allTerms(components, tree.logWeight, cells.mean[a], cells.covariance[a], terms);
            double top = -std::numeric_limits<double>::infinity();
            for (const double l : terms.logit) top = std::max(top, l);
            block.cellEntries.push_back(static_cast<std::uint32_t>(terms.component.size()));
            // The walk's terms are relative to the root's bound, which is at
            // least the largest term; they may underflow only where the
            // largest itself is below exp(-400) of the bound (then the
            // terms are summed again relative to the largest; above it, terms
            // that lose precision are below exp(-300) of Z_A).
            const bool walked = !terms.scaled.empty() && top - terms.reference > -400.0;
            if (walked) {
                double sum = 0.0;
                for (const double e : terms.scaled) sum += e;
                const double logZ = terms.reference + std::log(sum);
                const double toQ = std::exp(terms.reference - logZ);
                block.logZ.push_back(logZ);
                for (std::size_t t = 0; t < terms.component.size(); ++t) {
                    block.component.push_back(terms.component[t]);
                    block.q.push_back(terms.scaled[t] * toQ);
                }
            } else {
                double sum = 0.0;
                for (const double l : terms.logit) sum += std::exp(l - top);
                const double logZ = top + std::log(sum);
                block.logZ.push_back(logZ);
                for (std::size_t t = 0; t < terms.component.size(); ++t) {
                    block.component.push_back(terms.component[t]);
                    block.q.push_back(std::exp(terms.logit[t] - logZ));
                }
            }
            block.pruned += terms.pruned;
            block.prunedPerCell.push_back(static_cast<std::uint32_t>(terms.pruned));
            block.maxPrunedShare = std::max(block.maxPrunedShare, terms.prunedShare);
        }
    });
    out.offset.assign(1, 0);
    out.offset.reserve(cellCount + 1);
    out.component.clear();
    out.q.clear();
    out.logZ.clear();
    out.prunedPerCell.clear();
    out.pairsPruned = 0;
    out.maxPrunedShare = 0.0;
    for (const Block& block : parts) {
        for (const std::uint32_t entries : block.cellEntries) out.offset.push_back(out.offset.back() + entries);
        out.component.insert(out.component.end(), block.component.begin(), block.component.end());
        out.q.insert(out.q.end(), block.q.begin(), block.q.end());
        out.logZ.insert(out.logZ.end(), block.logZ.begin(), block.logZ.end());
        out.prunedPerCell.insert(out.prunedPerCell.end(), block.prunedPerCell.begin(), block.prunedPerCell.end());
        out.pairsPruned += block.pruned;
        out.maxPrunedShare = std::max(out.maxPrunedShare, block.maxPrunedShare);
    }
    out.pairsKept = out.component.size();
    return boundOf(cells, out);
}

double boundOf(const EmCells& cells, const Responsibilities& q) {
    double bound = 0.0;
    for (std::size_t a = 0; a < cells.size(); ++a) bound += cells.count[a] * q.logZ[a];
    return bound;
}

Responsibilities concatenate(const Responsibilities& a, const Responsibilities& b) {
    Responsibilities out = a;
    const std::uint64_t base = out.offset.empty() ? 0 : out.offset.back();
    if (out.offset.empty()) out.offset.push_back(0);
    for (std::size_t i = 1; i < b.offset.size(); ++i) out.offset.push_back(base + b.offset[i]);
    out.component.insert(out.component.end(), b.component.begin(), b.component.end());
    out.q.insert(out.q.end(), b.q.begin(), b.q.end());
    out.logZ.insert(out.logZ.end(), b.logZ.begin(), b.logZ.end());
    out.prunedPerCell.insert(out.prunedPerCell.end(), b.prunedPerCell.begin(), b.prunedPerCell.end());
    out.pairsKept += b.pairsKept;
    out.pairsPruned += b.pairsPruned;
    out.maxPrunedShare = std::max(a.maxPrunedShare, b.maxPrunedShare);
    return out;
}

Responsibilities selectCells(const Responsibilities& from, const std::vector<std::size_t>& rows) {
    Responsibilities out;
    out.offset.reserve(rows.size() + 1);
    out.offset.push_back(0);
    for (const std::size_t row : rows) {
        for (std::uint64_t e = from.offset[row]; e < from.offset[row + 1]; ++e) {
            out.component.push_back(from.component[e]);
            out.q.push_back(from.q[e]);
        }
        out.offset.push_back(out.component.size());
        out.logZ.push_back(from.logZ[row]);
        out.prunedPerCell.push_back(from.prunedPerCell[row]);
        out.pairsPruned += from.prunedPerCell[row];
    }
    out.pairsKept = out.component.size();
    out.maxPrunedShare = from.maxPrunedShare;
    return out;
}

void mStep(const EmCells& cells, const Responsibilities& q, double regCovar, std::vector<EmComponent>& components,
           bool updateParameters) {
    const std::size_t k = components.size();
    const std::size_t cellCount = cells.size();
    struct First {
        std::vector<double> nq;
        std::vector<Vec3d> moment, power;
    };
    const First first = jobs::deterministicReduce<First>(
        cellCount, kMStepBlocks, [k] { return First{std::vector<double>(k, 0.0), std::vector<Vec3d>(k, Vec3d(0.0)), std::vector<Vec3d>(k, Vec3d(0.0))}; },
        [&](First& acc, jobs::IndexRange range) {
            for (std::size_t a = range.begin; a != range.end; ++a) {
                for (std::uint64_t e = q.offset[a]; e < q.offset[a + 1]; ++e) {
                    const std::uint32_t s = q.component[e];
                    const double nq = cells.count[a] * q.q[e];
                    acc.nq[s] += nq;
                    acc.moment[s] += nq * cells.mean[a];
                    acc.power[s] += q.q[e] * cells.power[a];
                }
            }
        },
        [k](First& total, const First& part) {
            for (std::size_t s = 0; s < k; ++s) {
                total.nq[s] += part.nq[s];
                total.moment[s] += part.moment[s];
                total.power[s] += part.power[s];
            }
        });
    const double n = cells.totalCount();
    for (std::size_t s = 0; s < k; ++s) {
        components[s].effectiveCount = first.nq[s];
        components[s].power = first.power[s];
        if (updateParameters) {
            components[s].weight = first.nq[s] / n;
            if (first.nq[s] > 0.0) components[s].gaussian.mean = first.moment[s] / first.nq[s];
        }
    }
    if (!updateParameters) return;
    const std::vector<Sym3> scatter = jobs::deterministicReduce<std::vector<Sym3>>(
        cellCount, kMStepBlocks, [k] { return std::vector<Sym3>(k); },
        [&](std::vector<Sym3>& acc, jobs::IndexRange range) {
            for (std::size_t a = range.begin; a != range.end; ++a) {
                for (std::uint64_t e = q.offset[a]; e < q.offset[a + 1]; ++e) {
                    const std::uint32_t s = q.component[e];
                    const double nq = cells.count[a] * q.q[e];
                    acc[s] += (cells.covariance[a] + Sym3::outer(cells.mean[a] - components[s].gaussian.mean)) * nq;
                }
            }
        },
        [k](std::vector<Sym3>& total, const std::vector<Sym3>& part) {
            for (std::size_t s = 0; s < k; ++s) total[s] += part[s];
        });
    for (std::size_t s = 0; s < k; ++s) {
        if (!(first.nq[s] > 0.0)) continue;
        const Sym3 covariance = scatter[s] * (1.0 / first.nq[s]) + Sym3::identity(regCovar);
        components[s].gaussian = Gaussian(components[s].gaussian.mean, covariance);
    }
}

std::size_t dropWeakComponents(std::vector<EmComponent>& components, double minEffectiveCount) {
    const std::size_t before = components.size();
    std::erase_if(components, [&](const EmComponent& c) {
        return !(c.effectiveCount >= minEffectiveCount) || !(c.weight > 0.0) || !c.gaussian.factors.valid;
    });
    return before - components.size();
}

EmRun runEm(const EmCells& cells, std::vector<EmComponent>& components, const EmOptions& options,
            Responsibilities* initial) {
    EmRun run;
    const double n = cells.totalCount();
    double bound = 0.0;
    if (initial != nullptr) {
        run.responsibilities = std::move(*initial);
        bound = boundOf(cells, run.responsibilities);
    } else {
        bound = eStep(cells, components, options.tau, run.responsibilities);
    }
    run.bounds.push_back(bound);
    while (run.iterations < options.maxIterations) {
        mStep(cells, run.responsibilities, options.regCovar, components);
        ++run.iterations;
        const std::size_t dropped = dropWeakComponents(components, options.minEffectiveCount);
        run.dropped += dropped;
        if (run.iterations == options.maxIterations && options.skipLastEStep && options.skipLastEStep(components)) {
            run.lastEStepSkipped = true;
            return run;
        }
        const double next = eStep(cells, components, options.tau, run.responsibilities);
        run.bounds.push_back(next);
        const double change = std::abs(next - bound) / n;
        bound = next;
        // Per photon, so that a larger sample is no progress in itself; relative
        // to |F/n| where that exceeds 1 (Verbeek & Nunnink's test), absolute below.
        if (dropped == 0 && change <= options.epsilon * std::max(1.0, std::abs(bound / n))) {
            run.converged = true;
            break;
        }
    }
    mStep(cells, run.responsibilities, options.regCovar, components, false);
    return run;
}

std::vector<EmComponent> componentsFromCells(const EmCells& cells, double regCovar) {
    const double n = cells.totalCount();
    std::vector<EmComponent> components;
    components.reserve(cells.size());
    for (std::size_t a = 0; a < cells.size(); ++a) {
        EmComponent c;
        c.weight = cells.count[a] / n;
        c.power = cells.power[a];
        c.effectiveCount = cells.count[a];
        c.gaussian = Gaussian(cells.mean[a], cells.covariance[a] + Sym3::identity(regCovar));
        components.push_back(c);
    }
    return components;
}

}  // namespace fg::gmm
