// Importon tracing (`importon`), Vorba et al. 2014 §4.1 (Fig. 2a, f): camera
// paths, guided by the radiance cache of the previous training pass when there
// is one (unguided in the first), that store an importon wherever they reach a
// vertex a guided path tracer would look the cache up at (a surface whose BSDF
// has smooth, non-transmissive lobes only). The importons tell `cache_update`
// where radiance records are needed: the paper creates a record wherever a
// guided path queries the cache and finds none (§4.1, §4.3); these are those
// queries, made in a pass of their own so that creation can follow item order.
//
// The paths are the path tracer's (path_vertex.h: same scattering, guiding,
// Russian roulette and depth limit), without resolving its next-event shadow
// rays, which importons do not need. Each path draws from its own stream keyed
// by (seed, instance and iteration, pixel x spp + sample), and the importons
// are gathered per fixed chunk of paths and concatenated in path order, so the
// buffer is the same for any thread count.
//
// Importons leaving the scene (§4.4, Fig. 6a): a path whose ray escapes to
// the environment leaves an exit (the point where the ray crosses the scene's
// bounding sphere, on which the infinite lights' emission disks sit, its
// direction, weight and bounce count) in `exits`, which trains the
// environment sampler. They are recorded only when the scene has an
// environment emitter (a non-delta infinite light), the only case in which a
// photon can come from those directions; otherwise `exits` is empty.
// Recording draws no random number, so the importons are the same either way.
//
// The weight-based Russian roulette of §4.5 is pt's with `rr_threshold` below
// 1 (roulette.h); the importons' weights are stored for the importance cache
// that will train on them.
#include "passes/common/path_vertex.h"
#include "passes/passes.h"

#include "engine/core/error.h"
#include "engine/guiding/environment_guide.h"
#include "engine/guiding/guiding_cache.h"
#include "engine/guiding/importons.h"
#include "engine/accel/ray_query.h"
#include "engine/scene/scene.h"
#include "jobs/parallel.h"
#include "jobs/random.h"

#include <algorithm>
#include <cmath>
#include <span>
#include <vector>

namespace fg {

namespace {

// Paths per chunk: the unit whose importons are gathered together. Fixed, so
// that the concatenation order never depends on scheduling.
constexpr std::size_t kChunk = 256;

// Where a ray from inside the scene's bounding sphere leaves it; a ray from
// outside (by rounding) keeps its origin, which lies on the same line.
Vec3 sphereExit(const Vec3& origin, const Vec3& direction, const Vec3& center, float radius) {
    const Vec3 o = origin - center;
    const float b = glm::dot(o, direction);
    const float c = glm::dot(o, o) - radius * radius;
    if (!(c < 0.0f)) return origin;
    const float t = -b + std::sqrt(std::max(0.0f, b * b - c));
    return origin + t * direction;
}

class ImportonPass final : public Pass {
public:
    void run(PassContext& ctx) override {
        const Scene& scene = ctx.scene();
        const PassParams& params = ctx.params();
        const auto spp = static_cast<std::uint64_t>(params.getInt("spp"));
        PathLimits limits;
        limits.maxDepth = static_cast<int>(params.getInt("max_depth"));
        limits.rrDepth = static_cast<int>(params.getInt("rr_depth"));
        limits.rrThreshold = static_cast<float>(params.getFloat("rr_threshold"));

        const Camera camera = ctx.filmCamera();
        PathTracerScene pts(scene, ctx.rays());
        if (ctx.hasInput("radiance_cache")) {
            guideByRadianceCache(pts, ctx.input<GuidingCache>("radiance_cache"), params);
        }

        const std::uint64_t pixels = static_cast<std::uint64_t>(camera.width) * static_cast<std::uint64_t>(camera.height);
        const std::size_t pathCount = static_cast<std::size_t>(pixels * spp);
        const std::size_t chunks = (pathCount + kChunk - 1) / kChunk;
        std::vector<std::vector<GuidableVertex>> gathered(chunks);
        std::vector<std::vector<ImportonExitBuffer::Record>> exitsGathered(chunks);
        const bool recordExits = hasEnvironmentEmitter(scene);
        const Vec3 boundsCenter = 0.5f * (scene.boundsMin + scene.boundsMax);
        const float boundsRadius = glm::length(scene.boundsMax - boundsCenter);
        std::vector<std::int64_t> segments(chunks, 0);
        const std::uint64_t seed = ctx.seed(), stream = ctx.streamKey();
        jobs::parallelForChunks(pathCount, kChunk, [&](jobs::IndexRange r) {
            const std::size_t chunk = r.begin / kChunk;
            std::vector<GuidableVertex>& out = gathered[chunk];
            for (std::size_t i = r.begin; i != r.end; ++i) {
                jobs::Rng rng(seed, stream, i);
                const auto pixel = static_cast<std::uint32_t>(i / spp);
                const Vec2 raster = Vec2(static_cast<float>(pixel % static_cast<std::uint32_t>(camera.width)),
                                         static_cast<float>(pixel / static_cast<std::uint32_t>(camera.width))) +
                                    rng.uniform2();
                Ray ray = camera.generateRay(raster);
                Rgb beta(1.0f), L(0.0f);
                PathHistory history = PathHistory::atCamera(camera.medium);
                PathVertexState state{ray, beta, L, history, rng, &out};
                bool alive = true;
                while (alive) {
                    const Hit hit = pts.rays.intersect(state.ray);
                    ++segments[chunk];
                    ShadowRequest unused;
                    const Vec3 from = state.ray.origin;
                    alive = advancePath(pts, limits, hit, state, unused);
                    // Escaped: no surface ahead and no medium event on the way
                    // (which would have moved the ray's origin).
                    if (!alive && recordExits && !hit.valid() && state.ray.origin == from) {
                        const float w = (beta.x + beta.y + beta.z) / 3.0f;
                        if (w > 0.0f && std::isfinite(w)) {
                            const Vec3 exit = sphereExit(state.ray.origin, state.ray.direction, boundsCenter,
                                                         boundsRadius);
                            exitsGathered[chunk].push_back(
                                {exit, state.ray.direction, w,
                                 static_cast<std::uint16_t>(std::min(history.depth, 0xFFFF))});
                        }
                    }
                }
            }
        });

        std::size_t total = 0;
        for (const auto& g : gathered) total += g.size();
        ImportonMap& map = ctx.createOutput<ImportonMap>("importons");
        map.paths = pathCount;
        map.importons.resize(total);
        auto position = map.importons.column<ImportonPosition>();
        auto incident = map.importons.column<ImportonIncident>();
        auto weight = map.importons.column<ImportonWeight>();
        auto normal = map.importons.column<ImportonNormal>();
        auto bounces = map.importons.column<ImportonBounces>();
        std::size_t k = 0;
        std::int64_t segmentTotal = 0;
        for (std::size_t c = 0; c < chunks; ++c) {
            for (const GuidableVertex& v : gathered[c]) {
                position[k] = v.position;
                incident[k] = v.incident;
                // Paths start with importance 1 per path; dividing by the path
                // count makes the map an estimate of W_in, as photons carry
                // flux divided by the emitted count.
                weight[k] = v.weight / static_cast<float>(pathCount);
                normal[k] = v.normal;
                bounces[k] = static_cast<std::uint16_t>(std::min(v.bounces, 0xFFFF));
                ++k;
            }
            segmentTotal += segments[c];
        }
        ImportonExits& exits = ctx.createOutput<ImportonExits>("exits");
        exits.paths = pathCount;
        for (auto& g : exitsGathered) {
            // Normalised per path as the importons are.
            for (auto& e : g) e.get<ExitWeight>() /= static_cast<float>(pathCount);
            exits.exits.append(std::span<const ImportonExitBuffer::Record>(g));
        }
        ctx.addItems(static_cast<std::int64_t>(pathCount));
        ctx.addCounter("exits", static_cast<std::int64_t>(exits.exits.size()));
        ctx.addCounter("importons", static_cast<std::int64_t>(total));
        ctx.addCounter("path_segments", segmentTotal);
    }
};

}  // namespace

PassRegistration importonPass() {
    PassSpec spec;
    spec.name = "importon";
    spec.doc = "Importon tracing (Vorba et al. 2014): camera paths guided by the radiance cache, storing their "
               "guidable vertices";
    SlotSpec radianceCache{"radiance_cache", "GuidingCache",
                           "the radiance cache of the previous training pass that guides the paths (absent: BSDF sampling)"};
    radianceCache.optional = true;
    spec.inputs = {radianceCache};
    spec.outputs = {{"importons", "ImportonMap", "importons at the paths' guidable surface vertices, in path order"},
                    {"exits", "ImportonExits",
                     "importons leaving the scene (§4.4): exit point on the bounding sphere, direction, weight; "
                     "empty without an environment emitter"}};
    spec.params = {
        {"spp", ParamType::Int, std::int64_t{1}, 1, 1 << 16, {}, "camera paths per pixel"},
        {"max_depth", ParamType::Int, std::int64_t{16}, 1, 4096, {},
         "maximum number of scattering events per path (as pt's)"},
        {"rr_depth", ParamType::Int, std::int64_t{5}, 1, 4096, {},
         "scattering events before Russian roulette may end a path (as pt's)"},
        rouletteThresholdParam("path"),
    };
    const std::vector<ParamSpec> guided = guidedSamplingParams();
    spec.params.insert(spec.params.end(), guided.begin(), guided.end());
    return {spec, [] { return std::make_unique<ImportonPass>(); }, {}, {}};
}

}  // namespace fg
