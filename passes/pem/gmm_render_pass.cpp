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
// (query_cost = nodes + Gaussians, query_nodes, query_gaussians,
// query_time_ns); segments run in parallel and are summed into pixels in
// segment order, so the image does not depend on the thread count.
#include "passes/passes.h"

#include "passes/pem/pem_common.h"
#include "engine/buffers/beam_buffers.h"
#include "engine/image/film.h"
#include "engine/scene/scene.h"
#include "jobs/parallel.h"
#include "jobs/work_context.h"

#include <cmath>
#include <limits>
#include <stdexcept>

namespace fg {

namespace {

constexpr std::size_t kSegmentGrain = 64;

enum class Mode { Hierarchical, Flat, Level };

struct SegmentResult {
    Rgb radiance{0.0f};
    std::int64_t nodes = 0, gaussians = 0;
    float timeNs = 0.0f;
};

// Slab test of the ray x + t w (inverseW = 1 / w per axis) against a box,
// clipped to [0, len]: the entry distance, or a negative value when missed.
double boxEntry(const Vec3& lo, const Vec3& hi, const glm::dvec3& x, const glm::dvec3& inverseW, double len) {
    double t0 = 0.0, t1 = len;
    for (int a = 0; a < 3; ++a) {
        const double inv = inverseW[a];
        double ta = (lo[a] - x[a]) * inv, tb = (hi[a] - x[a]) * inv;
        if (ta > tb) std::swap(ta, tb);
        if (std::isnan(ta) || std::isnan(tb)) {  // parallel to the slab and on its boundary
            if (x[a] < lo[a] || x[a] > hi[a]) return -1.0;
            continue;
        }
        t0 = std::max(t0, ta);
        t1 = std::min(t1, tb);
        if (t0 > t1) return -1.0;
    }
    return t0;
}

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
        if (bbh.nodes.size() != pyramid.nodes.size())
            throw std::logic_error("gmm_render: the BBH and the pyramid differ in size");
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
        std::vector<gmm::SegmentGaussian> gaussians(nodeCount);
        for (std::size_t j = 0; j < nodeCount; ++j) gaussians[j] = gmm::SegmentGaussian(gaussianAt(pyramid.nodes, j));
        const auto power = pyramid.nodes.column<GmmPower>();
        const auto right = pyramid.nodes.column<GmmRight>();
        const auto nodeLevel = pyramid.nodes.column<GmmLevel>();
        const auto lo = bbh.nodes.column<BbhLo>();
        const auto hi = bbh.nodes.column<BbhHi>();
        const auto sphere = bbh.nodes.column<BbhSphere>();

        const SegmentBuffer& segments = eyeSegments.segments;
        const auto origin = segments.column<SegmentOrigin>();
        const auto direction = segments.column<SegmentDirection>();
        const auto tNear = segments.column<SegmentTNear>();
        const auto tFar = segments.column<SegmentTFar>();
        const auto mediumOf = segments.column<SegmentMedium>();
        const auto pixelOf = segments.column<SegmentPixel>();
        const auto throughput = segments.column<SegmentThroughput>();
        const std::size_t segmentCount = segments.size();
        std::vector<SegmentResult> results(segmentCount);

        jobs::parallelForChunks(segmentCount, kSegmentGrain, [&](jobs::IndexRange range) {
            std::vector<std::uint32_t> stack;
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
                const glm::dvec3 inverseW = 1.0 / w;
                const glm::dvec3 eye(origin[i]);
                const glm::dvec3 x = eye + static_cast<double>(tNear[i]) * w;
                const double len = tFar[i] >= 0.5f * kInfinity ? std::numeric_limits<double>::infinity()
                                                                 : static_cast<double>(tFar[i] - tNear[i]);
                const double boxLen = std::isinf(len) ? 1e300 : len;
                SegmentResult& result = results[i];
                glm::dvec3 sum(0.0);
                const auto evaluate = [&](std::uint32_t j) {
                    ++result.gaussians;
                    sum += power[j] * gmm::segmentIntegralRgb(gaussians[j], x, w, sigmaT, 0.0, len);
                };
                if (mode == Mode::Flat) {
                    for (std::uint32_t j = 0; j < nodeCount; ++j) {
                        if (right[j] != kNoGmmNode) continue;
                        ++result.nodes;
                        if (boxEntry(lo[j], hi[j], x, inverseW, boxLen) >= 0.0) evaluate(j);
                    }
                } else {
                    stack.assign(1, 0);
                    while (!stack.empty()) {
                        const std::uint32_t j = stack.back();
                        stack.pop_back();
                        ++result.nodes;
                        const double entry = boxEntry(lo[j], hi[j], x, inverseW, boxLen);
                        if (entry < 0.0) continue;
                        bool stop = right[j] == kNoGmmNode;
                        if (!stop && mode == Mode::Level) stop = nodeLevel[j] <= level;
                        if (!stop && mode == Mode::Hierarchical) {
                            // Alg. 4 line 3: the bounding sphere's solid angle seen from the
                            // camera-path vertex, and the transmittance up to the box.
                            const glm::dvec3 centre(sphere[j].x, sphere[j].y, sphere[j].z);
                            const double radius = sphere[j].w;
                            const glm::dvec3 toCentre = centre - eye;
                            const double distanceSquared = glm::dot(toCentre, toCentre);
                            const double radiusSquared = radius * radius;
                            if (distanceSquared > radiusSquared)
                                stop = radiusSquared < sinSquaredLimit * distanceSquared;
                            if (!stop) stop = entry > opaqueBeyond;
                        }
                        if (stop) {
                            evaluate(j);
                            continue;
                        }
                        stack.push_back(right[j]);
                        stack.push_back(j + 1);
                    }
                }
                const Rgb value = Rgb(sum * (1.0 / (4.0 * M_PI))) * throughput[i];
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
        std::int64_t totalNodes = 0, totalGaussians = 0;
        for (std::size_t i = 0; i < segmentCount; ++i) {
            const std::uint32_t p = pixelOf[i];
            if (p >= perPixel.size()) throw std::logic_error("gmm_render: segment outside the film");
            const SegmentResult& r = results[i];
            perPixel[p] += r.radiance;
            nodesAov[p] += static_cast<float>(r.nodes);
            gaussiansAov[p] += static_cast<float>(r.gaussians);
            cost[p] += static_cast<float>(r.nodes + r.gaussians);
            time[p] += r.timeNs;
            totalNodes += r.nodes;
            totalGaussians += r.gaussians;
        }
        image.addToPixels(perPixel, 1.0f);
        ctx.addItems(static_cast<std::int64_t>(segmentCount));
        ctx.addCounter("segments", static_cast<std::int64_t>(segmentCount));
        ctx.addCounter("nodes_visited", totalNodes);
        ctx.addCounter("gaussians_evaluated", totalGaussians);
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
    };
    const auto memory = [](const PreflightContext& pf) {
        return MemoryEstimate{filmBytes(pf.film),
                              "film " + std::to_string(pf.film.width) + " x " + std::to_string(pf.film.height), {}};
    };
    return {spec, [] { return std::make_unique<GmmRenderPass>(); }, refuseAnisotropicMedia, memory};
}

}  // namespace fg
