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
// Not yet here (issue 20): exit points of importons leaving the scene (for
// guided environment emission, §4.4). The weight-based Russian roulette of
// §4.5 is pt's with `rr_threshold` below 1 (roulette.h); the importons'
// weights are stored for the importance cache that will train on them.
#include "passes/common/path_vertex.h"
#include "passes/passes.h"

#include "engine/core/error.h"
#include "engine/guiding/guiding_cache.h"
#include "engine/guiding/importons.h"
#include "engine/accel/ray_query.h"
#include "engine/scene/scene.h"
#include "jobs/parallel.h"
#include "jobs/random.h"

#include <algorithm>
#include <vector>

namespace fg {

namespace {

// Paths per chunk: the unit whose importons are gathered together. Fixed, so
// that the concatenation order never depends on scheduling.
constexpr std::size_t kChunk = 256;

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
                    alive = advancePath(pts, limits, hit, state, unused);
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
        ctx.addItems(static_cast<std::int64_t>(pathCount));
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
    spec.outputs = {{"importons", "ImportonMap", "importons at the paths' guidable surface vertices, in path order"}};
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
