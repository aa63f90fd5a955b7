// Gaussian mixture render pass (`gmm_render`): Jakob et al. 2011 §7.2, Alg. 4
// and Eq. 15 — the media radiance along every camera-ray segment from the
// Gaussian pyramid instead of the photons. Per segment, top down from the root:
// a node whose box the segment misses is skipped; a node whose bounding
// sphere subtends less than eps_Omega times the pixel's solid angle, or whose
// box lies behind transmittance below eps_Tr (from the segment's start), is
// evaluated in place of its subtree; otherwise its children are visited;
// leaves are always evaluated. A node contributes Eq. 15,
//   1/4 pi Phi_j int_0^len g_j(x + t w) e^{-sigma_t t} dt,
// per RGB channel with the closed form of Eqs. 16-17 in corrected form
// (engine/gmm/gaussian.h; the channels share everything but sigma_t, and grey
// media evaluate the erf/exp part once), times the segment's throughput; Phi_j, the node's
// power, is the paper's w-bar_j (our fit keeps weights and powers apart, see
// em_fit). `mode = flat` evaluates every leaf whose box the segment meets (so
// hierarchical with eps_Omega = eps_Tr = 0 equals it), `level` the nodes of
// one pyramid level (those at or below it whose parent is above). Isotropic
// media only (§9). Writes the `volume` layer and the cost AOVs of beam_query
// (query_cost = box tests + Gaussians tested, query_nodes, query_gaussians =
// Eq. 16 evaluations, query_time_ns); segments run in parallel and are summed
// into pixels in segment order, so the image does not depend on the thread
// count.
// Departures that keep the flat image within the truncation (§7.1's delta):
// the descent tests the boxes of a node's leaves' truncated ellipsoids rather
// than the BBH's box, which also holds the node's own, wider ellipsoid; it
// tests four boxes per SSE register, on the pyramid collapsed to nodes of up
// to sixteen entries (narrower, deeper nodes cost more in stack traffic and
// branches than the boxes they spare; a segment whose transmittance test
// could fire takes the binary descent);
// and a Gaussian whose truncated ellipsoid the segment misses is skipped
// before Eq. 16 (`cull_ellipsoids`). The descent only lists a segment's
// Gaussians; their ellipsoid tests and Eq. 16 are evaluated after it, two at
// a time in SSE2 lanes (engine/gmm/segment_batch.h,
// with polynomial exp and erfc within about 1e-7 of the C library's, far
// below the truncation's delta), summed in the descent's order.
#include "passes/passes.h"
#include "engine/core/error.h"

#include "passes/pem/pem_common.h"
#include "engine/buffers/beam_buffers.h"
#include "engine/gmm/segment_batch.h"
#include "engine/image/film.h"
#include "engine/scene/scene.h"
#include "jobs/parallel.h"
#include "jobs/work_context.h"

#include <array>
#include <cmath>
#include <limits>
#include <span>
#include <stdexcept>
#include <vector>
#include <xmmintrin.h>

namespace fg {

namespace {

constexpr std::size_t kSegmentGrain = 64;
constexpr std::size_t kWide = 16;
constexpr std::uint32_t kNoWideNode = std::numeric_limits<std::uint32_t>::max();

enum class Mode { Hierarchical, Flat, Level };

struct SegmentResult {
    Rgb radiance{0.0f};
    std::int64_t nodes = 0, gaussians = 0, culled = 0;
    bool binary = false;
    float timeNs = 0.0f;
};

// A segment x + t w, t in [0, length], prepared for slab tests against the
// single-precision boxes. The inverse direction is kept finite (a zero
// component gives +-1e30), so no product is 0 * inf and a box nested in
// another never gets the larger interval: rounding is monotone, so the
// interval of a box contained in another is contained in the other's. A
// segment that meets a node's box therefore meets all its ancestors' boxes,
// which is what lets the wide traversal below skip levels.
struct SlabRay {
    std::array<float, 3> origin{}, inverse{};
    std::array<bool, 3> negative{};
    float length = 0.0f;
};

SlabRay slabRay(const glm::dvec3& x, const glm::dvec3& w, double length) {
    SlabRay ray;
    for (int a = 0; a < 3; ++a) {
        const auto i = static_cast<std::size_t>(a);
        ray.origin[i] = static_cast<float>(x[a]);
        const float direction = static_cast<float>(w[a]);
        float inverse = 1.0f / direction;
        if (!(std::abs(inverse) < 1e30f)) inverse = std::signbit(direction) ? -1e30f : 1e30f;
        ray.inverse[i] = inverse;
        ray.negative[i] = inverse < 0.0f;
    }
    ray.length = static_cast<float>(std::min(length, 1e30));
    return ray;
}

// [entry, exit] of the segment in a box; entry > exit when it misses.
struct SlabInterval {
    float entry, exit;
    bool hit() const { return entry <= exit; }
};

SlabInterval slabInterval(const SlabRay& ray, const Vec3& lo, const Vec3& hi) {
    float t0 = 0.0f, t1 = ray.length;
    for (int a = 0; a < 3; ++a) {
        const auto i = static_cast<std::size_t>(a);
        const float nearPlane = ray.negative[i] ? hi[a] : lo[a];
        const float farPlane = ray.negative[i] ? lo[a] : hi[a];
        t0 = std::max(t0, (nearPlane - ray.origin[i]) * ray.inverse[i]);
        t1 = std::min(t1, (farPlane - ray.origin[i]) * ray.inverse[i]);
    }
    return {t0, t1};
}

// Up to kWide pyramid nodes whose boxes are tested together. The binary
// pyramid is collapsed: a node that is descended into hands its entries'
// places to its children, widest box first, until kWide are filled, except
// that a node the level-of-detail test may stop stays an entry, so that its
// test is made as in the binary descent. Entries keep the pyramid's depth-
// first order, and so does the traversal, so the Gaussians are summed in the
// same order as by the binary descent. Unused entries have empty boxes.
static_assert(kWide % 4 == 0 && kWide <= 32, "the wide traversal tests four boxes per SSE register");
struct WideNode {
    std::array<std::array<float, kWide>, 3> lo{}, hi{};
    std::array<std::uint32_t, kWide> node{};
    std::array<std::uint32_t, kWide> children{};  // the wide node of the entry's children; kNoWideNode at leaves
    std::uint32_t count = 0;
    std::uint32_t mayStop = 0;  // bit per entry: the level-of-detail test can stop there
};

class WideTree {
public:
    WideTree(const std::vector<Vec3>& lo, const std::vector<Vec3>& hi, std::span<const std::uint32_t> right,
             const std::vector<bool>& mayStop)
        : lo_(lo), hi_(hi), right_(right), mayStop_(mayStop) {
        if (!right.empty()) build({0});
    }
    const std::vector<WideNode>& nodes() const { return nodes_; }

private:
    bool isLeaf(std::uint32_t j) const { return right_[j] == kNoGmmNode; }
    double area(std::uint32_t j) const {
        const glm::dvec3 e = glm::max(glm::dvec3(hi_[j] - lo_[j]), glm::dvec3(0.0));
        return e.x * e.y + e.y * e.z + e.z * e.x;
    }

    std::uint32_t build(std::vector<std::uint32_t> entries) {
        while (entries.size() < kWide) {
            std::size_t widest = entries.size();
            for (std::size_t e = 0; e < entries.size(); ++e) {
                const std::uint32_t j = entries[e];
                if (isLeaf(j) || mayStop_[j]) continue;
                if (widest == entries.size() || area(j) > area(entries[widest])) widest = e;
            }
            if (widest == entries.size()) break;
            const std::uint32_t j = entries[widest];
            entries[widest] = j + 1;
            entries.insert(entries.begin() + static_cast<std::ptrdiff_t>(widest) + 1, right_[j]);
        }
        const auto index = static_cast<std::uint32_t>(nodes_.size());
        nodes_.emplace_back();
        WideNode wide;
        wide.count = static_cast<std::uint32_t>(entries.size());
        for (std::size_t e = 0; e < kWide; ++e) {
            for (std::size_t a = 0; a < 3; ++a) {
                wide.lo[a][e] = e < entries.size() ? lo_[entries[e]][static_cast<int>(a)] : kInfinity;
                wide.hi[a][e] = e < entries.size() ? hi_[entries[e]][static_cast<int>(a)] : -kInfinity;
            }
            wide.node[e] = e < entries.size() ? entries[e] : kNoGmmNode;
            wide.children[e] = kNoWideNode;
        }
        for (std::size_t e = 0; e < entries.size(); ++e) {
            const std::uint32_t j = entries[e];
            if (mayStop_[j]) wide.mayStop |= 1u << e;
            if (!isLeaf(j)) wide.children[e] = build({j + 1, right_[j]});
        }
        nodes_[index] = wide;
        return index;
    }

    const std::vector<Vec3>& lo_;
    const std::vector<Vec3>& hi_;
    std::span<const std::uint32_t> right_;
    const std::vector<bool>& mayStop_;
    std::vector<WideNode> nodes_;
};

class GmmRenderPass final : public Pass {
public:
    void run(PassContext& ctx) override {
        const Scene& scene = ctx.scene();
        const EyeSegments& eyeSegments = ctx.input<EyeSegments>("eye_segments");
        const GmmPyramid& pyramid = ctx.input<GmmPyramid>("pyramid");
        const GmmBbh& bbh = ctx.input<GmmBbh>("bbh");
        const PassParams& params = ctx.params();
        const std::string& modeName = params.getString("mode");
        const Mode mode = modeName == "flat" ? Mode::Flat : modeName == "level" ? Mode::Level : Mode::Hierarchical;
        const auto level = static_cast<std::uint32_t>(params.getInt("level"));
        const double epsOmega = params.getFloat("eps_omega");
        const double epsTr = params.getFloat("eps_tr");
        const bool cullEllipsoids = params.getBool("cull_ellipsoids");
        if (bbh.nodes.size() != pyramid.nodes.size())
            throw InputError("pass '" + ctx.instanceName() + "': the BBH has " + std::to_string(bbh.nodes.size()) +
                             " nodes but the pyramid " + std::to_string(pyramid.nodes.size()) +
                             " (were they saved from different runs?)");
        const FilmSettings& film = ctx.filmSettings();
        // A pixel's solid angle at the image centre (the paper's Omega(r)).
        const double pixelAngle = 2.0 * std::tan(0.5 * static_cast<double>(scene.camera.fovYDegrees) * M_PI / 180.0) /
                                  std::max(1, film.height);
        const double pixelSolidAngle = pixelAngle * pixelAngle;

        // Alg. 4's solid-angle test, omega = 2 pi (1 - sqrt(1 - sin^2 alpha)) <
        // eps_Omega Omega(r) with sin alpha = radius / distance, is monotone in
        // sin^2 alpha: radius^2 < sinSquaredLimit distance^2 tests the same
        // without a square root per node.
        const double omegaShare = epsOmega * pixelSolidAngle / (2.0 * M_PI);
        const double sinSquaredLimit = omegaShare >= 1.0 ? 1.0 : 1.0 - (1.0 - omegaShare) * (1.0 - omegaShare);

        const std::size_t nodeCount = pyramid.nodes.size();
        const auto power = pyramid.nodes.column<GmmPower>();
        const auto right = pyramid.nodes.column<GmmRight>();
        const auto nodeLevel = pyramid.nodes.column<GmmLevel>();
        const auto sphere = bbh.nodes.column<BbhSphere>();
        const auto truncation = bbh.nodes.column<BbhRadius>();
        std::vector<gmm::PackedGaussian> gaussians(nodeCount);
        for (std::size_t j = 0; j < nodeCount; ++j)
            gaussians[j] = gmm::PackedGaussian(gmm::SegmentGaussian(gaussianAt(pyramid.nodes, j)),
                                               truncation[j] * truncation[j], power[j]);

        // The descent's boxes bound the truncated ellipsoids of a node's leaves,
        // not the node's own: the BBH's box of an inner node also holds that
        // node's ellipsoid, wider than its children's (a merged covariance, a
        // larger power and so a larger r_j), and a descent that hardly ever
        // stops above the leaves (the pixel is small against the nodes' spheres)
        // tests mostly those loose boxes. A node the level-of-detail test stops
        // is evaluated where its leaves' boxes are met.
        // The level mode evaluates inner nodes wherever their own ellipsoids
        // reach, so it descends the BBH's boxes themselves.
        const auto bbhLo = bbh.nodes.column<BbhLo>();
        const auto bbhHi = bbh.nodes.column<BbhHi>();
        std::vector<Vec3> lo(nodeCount), hi(nodeCount);
        {
            for (std::size_t j = nodeCount; j-- > 0;) {
                if (right[j] == kNoGmmNode) {
                    lo[j] = bbhLo[j];
                    hi[j] = bbhHi[j];
                } else {
                    lo[j] = glm::min(lo[j + 1], lo[right[j]]);
                    hi[j] = glm::max(hi[j + 1], hi[right[j]]);
                }
            }
        }

        const SegmentBuffer& segments = eyeSegments.segments;
        const auto origin = segments.column<SegmentOrigin>();
        const auto direction = segments.column<SegmentDirection>();
        const auto tNear = segments.column<SegmentTNear>();
        const auto tFar = segments.column<SegmentTFar>();
        const auto mediumOf = segments.column<SegmentMedium>();
        const auto pixelOf = segments.column<SegmentPixel>();
        const auto throughput = segments.column<SegmentThroughput>();
        const std::size_t segmentCount = segments.size();

        // Alg. 4 line 3's solid-angle test, for an inner node, from the
        // camera-path vertex farthest from its sphere (the test stops more the
        // farther the vertex): where even that does not stop, no segment stops.
        const auto solidAngleStops = [&](std::size_t j, const glm::dvec3& eye) {
            const glm::dvec3 toCentre = glm::dvec3(sphere[j].x, sphere[j].y, sphere[j].z) - eye;
            const double distanceSquared = glm::dot(toCentre, toCentre);
            const double radiusSquared = static_cast<double>(sphere[j].w) * static_cast<double>(sphere[j].w);
            return distanceSquared > radiusSquared && radiusSquared < sinSquaredLimit * distanceSquared;
        };
        std::vector<bool> mayStop(nodeCount, false);
        if (mode == Mode::Hierarchical && segmentCount > 0) {
            glm::dvec3 eyeLo(std::numeric_limits<double>::infinity()), eyeHi(-std::numeric_limits<double>::infinity());
            for (const Vec3& o : origin) {
                eyeLo = glm::min(eyeLo, glm::dvec3(o));
                eyeHi = glm::max(eyeHi, glm::dvec3(o));
            }
            for (std::size_t j = 0; j < nodeCount; ++j) {
                if (right[j] == kNoGmmNode) continue;
                const glm::dvec3 centre(sphere[j].x, sphere[j].y, sphere[j].z);
                const glm::dvec3 farthest(centre.x - eyeLo.x > eyeHi.x - centre.x ? eyeLo.x : eyeHi.x,
                                          centre.y - eyeLo.y > eyeHi.y - centre.y ? eyeLo.y : eyeHi.y,
                                          centre.z - eyeLo.z > eyeHi.z - centre.z ? eyeLo.z : eyeHi.z);
                mayStop[j] = solidAngleStops(j, farthest);
            }
        }
        const WideTree wide(lo, hi, right, mayStop);
        const std::vector<WideNode>& wideNodes = wide.nodes();

        std::vector<SegmentResult> results(segmentCount);
        jobs::parallelForChunks(segmentCount, kSegmentGrain, [&](jobs::IndexRange range) {
            std::vector<std::uint32_t> stack, candidates;
            gmm::SegmentBatch batch;
            for (std::size_t i = range.begin; i != range.end; ++i) {
                if (nodeCount == 0) break;
                const std::int64_t start = jobs::wallNanos();
                const HomogeneousMedium& medium = scene.media.at(static_cast<std::size_t>(mediumOf[i]));
                const glm::dvec3 sigmaT(medium.sigmaT());
                const double minSigmaT = std::min({sigmaT.x, sigmaT.y, sigmaT.z});
                // Alg. 4's transmittance test e^{-sigma_t entry} < eps_Tr as a distance.
                const double opaqueBeyond = minSigmaT > 0.0 ? -std::log(epsTr) / minSigmaT
                                                            : std::numeric_limits<double>::infinity();
                const glm::dvec3 w(direction[i]);
                const glm::dvec3 eye(origin[i]);
                const glm::dvec3 x = eye + static_cast<double>(tNear[i]) * w;
                const double len = tFar[i] >= 0.5f * kInfinity ? std::numeric_limits<double>::infinity()
                                                                 : static_cast<double>(tFar[i] - tNear[i]);
                const SlabRay ray = slabRay(x, w, len);
                SegmentResult& result = results[i];
                batch.begin(x, w, len);
                // The descent lists the nodes to evaluate; their ellipsoid tests
                // and Eq. 16 terms are then computed two at a time.
                candidates.clear();
                const auto evaluate = [&](std::uint32_t j) { candidates.push_back(j); };
                if (mode == Mode::Flat) {
                    for (std::uint32_t j = 0; j < nodeCount; ++j) {
                        if (right[j] != kNoGmmNode) continue;
                        ++result.nodes;
                        if (slabInterval(ray, lo[j], hi[j]).hit()) evaluate(j);
                    }
                } else {
                    // Alg. 4's transmittance test can stop a node only if the
                    // segment reaches past opaqueBeyond inside the root's box
                    // (every node's box lies in it); such segments, and the
                    // level mode, take the binary descent.
                    const SlabInterval root = slabInterval(ray, lo[0], hi[0]);
                    result.binary = mode == Mode::Level || (root.hit() && root.exit > opaqueBeyond);
                    if (result.binary) {
                        stack.assign(1, 0);
                        while (!stack.empty()) {
                            const std::uint32_t j = stack.back();
                            stack.pop_back();
                            ++result.nodes;
                            const SlabInterval box = mode == Mode::Level ? slabInterval(ray, bbhLo[j], bbhHi[j])
                                                                         : slabInterval(ray, lo[j], hi[j]);
                            if (!box.hit()) continue;
                            bool stop = right[j] == kNoGmmNode;
                            if (!stop && mode == Mode::Level) stop = nodeLevel[j] <= level;
                            // Alg. 4 line 3: the bounding sphere's solid angle seen from the
                            // camera-path vertex, and the transmittance up to the box.
                            if (!stop && mode == Mode::Hierarchical)
                                stop = solidAngleStops(j, eye) || box.entry > opaqueBeyond;
                            if (stop) {
                                evaluate(j);
                                continue;
                            }
                            stack.push_back(right[j]);
                            stack.push_back(j + 1);
                        }
                    } else if (root.hit()) {
                        // Items on the stack: a wide node to test (low bit 0) or a
                        // pyramid node to evaluate (low bit 1), popped in the
                        // pyramid's depth-first order.
                        stack.assign(1, 0);
                        while (!stack.empty()) {
                            const std::uint32_t item = stack.back();
                            stack.pop_back();
                            if (item & 1u) {
                                evaluate(item >> 1);
                                continue;
                            }
                            const WideNode& node = wideNodes[item >> 1];
                            // slabInterval on the boxes, four at once.
                            unsigned hits = 0;
                            for (std::size_t group = 0; group < node.count; group += 4) {
                                __m128 t0 = _mm_setzero_ps(), t1 = _mm_set1_ps(ray.length);
                                for (std::size_t a = 0; a < 3; ++a) {
                                    const float* nearPlane =
                                        (ray.negative[a] ? node.hi[a].data() : node.lo[a].data()) + group;
                                    const float* farPlane =
                                        (ray.negative[a] ? node.lo[a].data() : node.hi[a].data()) + group;
                                    const __m128 o = _mm_set1_ps(ray.origin[a]);
                                    const __m128 inverse = _mm_set1_ps(ray.inverse[a]);
                                    t0 = _mm_max_ps(t0, _mm_mul_ps(_mm_sub_ps(_mm_loadu_ps(nearPlane), o), inverse));
                                    t1 = _mm_min_ps(t1, _mm_mul_ps(_mm_sub_ps(_mm_loadu_ps(farPlane), o), inverse));
                                }
                                hits |= static_cast<unsigned>(_mm_movemask_ps(_mm_cmple_ps(t0, t1))) << group;
                            }
                            result.nodes += node.count;
                            const auto evaluateHere = [&](std::size_t e) {
                                return node.children[e] == kNoWideNode ||
                                       ((node.mayStop >> e) & 1u && solidAngleStops(node.node[e], eye));
                            };
                            // Entries to evaluate before the first one descended
                            // into come next in depth-first order anyway: they go
                            // to the list directly, the rest through the stack.
                            bool descends = false;
                            while (hits != 0) {
                                const auto e = static_cast<std::size_t>(__builtin_ctz(hits));
                                descends = !evaluateHere(e);
                                if (descends) break;
                                hits &= hits - 1;
                                evaluate(node.node[e]);
                            }
                            while (hits != 0) {
                                const auto e = static_cast<std::size_t>(31 - __builtin_clz(hits));
                                hits &= ~(1u << e);
                                const std::uint32_t j = node.node[e];
                                const bool here = (hits == 0 && descends) ? false : evaluateHere(e);
                                stack.push_back(here ? (j << 1) | 1u : node.children[e] << 1);
                            }
                        }
                    }
                }
                result.gaussians = static_cast<std::int64_t>(batch.addAll(gaussians, candidates, cullEllipsoids));
                result.culled = static_cast<std::int64_t>(candidates.size()) - result.gaussians;
                const Rgb value = Rgb(batch.sum(sigmaT) * (1.0 / (4.0 * M_PI))) * throughput[i];
                result.radiance = isFinite(value) ? value : Rgb(0.0f);
                result.timeNs = static_cast<float>(jobs::wallNanos() - start);
            }
        });

        Film& image = ctx.createOutput<Film>("volume", ctx.filmSettings());
        image.aov("query_cost");
        image.aov("query_nodes");
        image.aov("query_gaussians");
        image.aov("query_time_ns");
        std::vector<float>& cost = image.aov("query_cost");
        std::vector<float>& nodesAov = image.aov("query_nodes");
        std::vector<float>& gaussiansAov = image.aov("query_gaussians");
        std::vector<float>& time = image.aov("query_time_ns");
        std::vector<Rgb> perPixel(image.pixelCount(), Rgb(0.0f));
        std::int64_t totalNodes = 0, totalGaussians = 0, totalCulled = 0, binarySegments = 0;
        for (std::size_t i = 0; i < segmentCount; ++i) {
            const std::uint32_t p = pixelOf[i];
            if (p >= perPixel.size()) throw std::logic_error("gmm_render: segment outside the film");
            const SegmentResult& r = results[i];
            perPixel[p] += r.radiance;
            nodesAov[p] += static_cast<float>(r.nodes);
            gaussiansAov[p] += static_cast<float>(r.gaussians);
            cost[p] += static_cast<float>(r.nodes + r.gaussians + r.culled);
            time[p] += r.timeNs;
            totalNodes += r.nodes;
            totalGaussians += r.gaussians;
            totalCulled += r.culled;
            binarySegments += r.binary ? 1 : 0;
        }
        image.addToPixels(perPixel, 1.0f);
        ctx.addItems(static_cast<std::int64_t>(segmentCount));
        ctx.addCounter("segments", static_cast<std::int64_t>(segmentCount));
        ctx.addCounter("binary_segments", binarySegments);
        ctx.addCounter("nodes_visited", totalNodes);
        ctx.addCounter("gaussians_evaluated", totalGaussians);
        ctx.addCounter("gaussians_culled", totalCulled);
    }
};

}  // namespace

PassRegistration gmmRenderPass() {
    PassSpec spec;
    spec.name = "gmm_render";
    spec.doc = "Media radiance from a Gaussian pyramid along camera segments (Jakob et al. 2011 Alg. 4, Eq. 15 with "
               "Eqs. 16-17 corrected): hierarchical level of detail, all leaves, or one level; query-cost AOVs";
    spec.inputs = {
        {"eye_segments", "EyeSegments", "camera-ray segments inside media (volume_eye)"},
        {"pyramid", "GmmPyramid", "the Gaussian pyramid (gmm_pyramid)"},
        {"bbh", "GmmBbh", "its bounding boxes (gmm_bbh)"},
    };
    spec.outputs = {{"volume", "Film", "media radiance alone (a film from black); AOVs query_cost, query_nodes, "
                                       "query_gaussians, query_time_ns"}};
    spec.params = {
        {"mode", ParamType::String, std::string("hierarchical"), 0, 0, {"hierarchical", "flat", "level"},
         "hierarchical (Alg. 4), flat (every leaf whose box is hit) or level (one pyramid level)"},
        {"level", ParamType::Int, std::int64_t{0}, 0, 64, {}, "the pyramid level rendered by mode = level (0: leaves)"},
        {"eps_omega", ParamType::Float, 1.0, 0.0, 1e9, {},
         "evaluate a node whose bounding sphere subtends less than eps_omega pixels' solid angle"},
        {"eps_tr", ParamType::Float, 0.01, 0.0, 1.0, {},
         "evaluate a node whose box lies behind transmittance below eps_tr"},
        {"cull_ellipsoids", ParamType::Bool, true, 0, 0, {},
         "skip a Gaussian when the segment misses its truncated ellipsoid (gmm_bbh's r_j), not only its box"},
    };
    const auto memory = [](const PreflightContext& pf) {
        return MemoryEstimate{filmBytes(pf.film),
                              "film " + std::to_string(pf.film.width) + " x " + std::to_string(pf.film.height), {}};
    };
    return {spec, [] { return std::make_unique<GmmRenderPass>(); }, refuseAnisotropicMedia, memory};
}

}  // namespace fg
