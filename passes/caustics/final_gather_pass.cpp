// Final gathering with a photon map (`final_gather`), the baseline of Herzog
// et al. 2007, §8.4 and Fig. 7(a) (Jensen 2001): the hits of N
// BSDF-sampled final-gather rays per primary vertex (passes/common/final_gather.h)
// take their reflected radiance from the k nearest photons of the global map,
// direct photons included (photon pass store_direct = true, global_index
// include_direct = true), by the gather
// pass's estimate (Frisvad et al. 2014, Eq. 10):
//   L(x_j, w) = sum_p f_r(x_j, w_p, w) Phi_p K(|x_j - x_p| / h) / h^2.
// Caustics come from the caustic map at the primary vertices, as in `gather`.
//
// Near concave features many gather rays land within the photon search
// radius of where they left, and the estimate there overestimates (§8.4).
// Jensen's remedy, secondary final gathering, is a parameter: a hit closer
// to its primary than `secondary_distance` times its gather radius h takes
// its radiance from M further BSDF-sampled rays instead, each adding the
// emission it reaches and the photon estimate at its hit. Off by default.
//
// Estimates are computed in parallel per hit and summed into pixels in hit
// order, so the layers do not depend on the thread count.
#include "passes/caustics/photon_estimate.h"
#include "passes/common/final_gather.h"
#include "passes/passes.h"

#include "engine/accel/point_index.h"
#include "engine/buffers/photon_buffers.h"
#include "engine/core/error.h"
#include "engine/image/film.h"
#include "engine/scene/scene.h"
#include "jobs/parallel.h"
#include "jobs/random.h"

#include <algorithm>
#include <cmath>
#include <atomic>
#include <ctime>
#include <limits>
#include <optional>
#include <span>
#include <string>
#include <vector>

namespace fg {

namespace {

// Process CPU time since `start`, for the phase counters (as fg_splat's).
std::int64_t cpuMicrosecondsSince(std::clock_t start) {
    return static_cast<std::int64_t>(1e6 * static_cast<double>(std::clock() - start) / CLOCKS_PER_SEC);
}

struct SecondaryGather {
    bool enabled = false;
    int rays = 0;
    float distanceFactor = 0.0f;
    std::uint64_t stream = 0;
};

class FinalGatherPass final : public Pass {
public:
    void run(PassContext& ctx) override {
        const Scene& scene = ctx.scene();
        const EyeVertexBuffer::View eye = ctx.input<EyeVertices>("eye_vertices").vertices.view();
        const int raysPerVertex = static_cast<int>(ctx.params().getInt("fg_rays"));
        const int tiles = static_cast<int>(ctx.params().getInt("tiles"));
        const double maxRadiusParam = ctx.params().getFloat("max_radius");
        const float maxRadius = maxRadiusParam > 0.0 ? static_cast<float>(maxRadiusParam)
                                                     : std::numeric_limits<float>::infinity();
        SecondaryGather secondary;
        secondary.enabled = ctx.params().getBool("secondary_gather");
        secondary.rays = static_cast<int>(ctx.params().getInt("secondary_rays"));
        secondary.distanceFactor = static_cast<float>(ctx.params().getFloat("secondary_distance"));
        secondary.stream = ctx.streamKey() ^ jobs::streamKey("secondary final gathering");

        const PhotonMap& globalMap = ctx.input<PhotonMap>("global_photons");
        const auto photonClass = globalMap.photons.column<PhotonClassColumn>();
        const bool hasDirect = std::any_of(photonClass.begin(), photonClass.end(),
                                           [](std::uint8_t c) { return c == PhotonClass::Direct; });
        if (globalMap.photons.size() > 0 && !hasDirect)
            throw InputError("pass '" + ctx.instanceName() +
                             "': final gathering reads the direct light at its hits from the global map, which holds "
                             "no direct photons: set [passes.photon] store_direct = true");
        const PointIndex& globalIndex = ctx.input<PointIndex>("global_index");
        if (globalIndex.size() != globalMap.photons.size())
            throw InputError("pass '" + ctx.instanceName() + "': the global index holds " +
                             std::to_string(globalIndex.size()) + " of the map's " +
                             std::to_string(globalMap.photons.size()) +
                             " photons; it leaves the direct ones out: set [passes.global_index] include_direct = true");
        const GatherSource global{globalMap, globalIndex,
                                  static_cast<std::size_t>(ctx.params().getInt("k_global")), "global"};
        const GatherSource causticSource{ctx.input<PhotonMap>("caustic_photons"), ctx.input<PointIndex>("caustic_index"),
                                         static_cast<std::size_t>(ctx.params().getInt("k_caustic")), "caustic"};

        Film& globalFilm = ctx.createOutput<Film>("global", ctx.filmSettings());
        Film& causticFilm = ctx.createOutput<Film>("caustic", ctx.filmSettings());
        const std::vector<std::vector<std::uint32_t>> byTile =
            primariesByTile(eye, globalFilm.width(), globalFilm.height(), tiles);

        std::vector<Rgb> globalPixels(globalFilm.pixelCount(), Rgb(0.0f));
        std::atomic<std::int64_t> photonsUsed{0}, secondaryGathers{0}, radiusPpmSum{0}, radiusCount{0};
        const double ppmScale = 1e6 / static_cast<double>(glm::length(scene.boundsMax - scene.boundsMin));
        std::int64_t hitCount = 0, traceMicroseconds = 0, gatherMicroseconds = 0;
        std::vector<Rgb> contribution;
        for (std::size_t tile = 0; tile < byTile.size(); ++tile) {
            if (byTile[tile].empty()) continue;
            auto start = std::clock();
            FinalGatherHits hits;
            traceFinalGatherHits(scene, ctx.rays(), eye, byTile[tile], raysPerVertex, ctx.seed(), ctx.streamKey(), hits);
            traceMicroseconds += cpuMicrosecondsSince(start);

            start = std::clock();
            const EyeVertexBuffer::View hitView = hits.vertices.view();
            const auto throughput = hitView.column<EyeThroughput>();
            contribution.assign(hitView.size(), Rgb(0.0f));
            const auto firstHit = static_cast<std::uint64_t>(hitCount);
            jobs::parallelForChunks(hitView.size(), 256, [&](jobs::IndexRange range) {
                std::vector<std::uint32_t> ids(global.k);
                std::vector<float> dist2(global.k);
                std::int64_t used = 0, gathered = 0, ppmSum = 0, ppmCount = 0;
                for (std::size_t i = range.begin; i != range.end; ++i) {
                    const VertexBrdf brdf(scene, hitView, i);
                    float h2 = 0.0f;
                    Rgb L = gatherRadiance(hitView.column<EyePosition>()[i], brdf, global, maxRadius, ids, dist2, used, &h2);
                    if (h2 > 0.0f) {
                        ppmSum += std::llround(ppmScale * std::sqrt(static_cast<double>(h2)));
                        ++ppmCount;
                    }
                    const float reach = secondary.distanceFactor * secondary.distanceFactor * h2;
                    if (secondary.enabled && hits.distance[i] * hits.distance[i] < reach) {
                        jobs::Rng rng(ctx.seed(), secondary.stream, firstHit + i);
                        L = secondaryRadiance(scene, ctx.rays(), gatherOrigin(hitView, i), global, maxRadius,
                                              secondary.rays, rng, ids, dist2, used);
                        ++gathered;
                    }
                    const Rgb value = L * throughput[i];
                    contribution[i] = isFinite(value) ? value : Rgb(0.0f);
                }
                photonsUsed += used;
                secondaryGathers += gathered;
                radiusPpmSum += ppmSum;
                radiusCount += ppmCount;
            });
            const auto pixelOf = hitView.column<EyePixel>();
            for (std::size_t i = 0; i < hitView.size(); ++i) globalPixels[pixelOf[i]] += contribution[i];
            gatherMicroseconds += cpuMicrosecondsSince(start);
            hitCount += static_cast<std::int64_t>(hitView.size());
            ctx.reportProgress(static_cast<double>(tile + 1) / static_cast<double>(byTile.size()));
        }
        globalFilm.addToPixels(globalPixels, 1.0f);

        // Caustics at the primary vertices, as the gather pass estimates them.
        const auto start = std::clock();
        std::vector<Rgb> caustic(eye.size(), Rgb(0.0f));
        jobs::parallelForChunks(eye.size(), 256, [&](jobs::IndexRange range) {
            std::vector<std::uint32_t> ids(causticSource.k);
            std::vector<float> dist2(causticSource.k);
            std::int64_t used = 0;
            for (std::size_t v = range.begin; v != range.end; ++v) {
                const Rgb value = gatherRadiance(eye.column<EyePosition>()[v], VertexBrdf(scene, eye, v), causticSource,
                                                 maxRadius, ids, dist2, used) *
                                  eye.column<EyeThroughput>()[v];
                caustic[v] = isFinite(value) ? value : Rgb(0.0f);
            }
            photonsUsed += used;
        });
        std::vector<Rgb> causticPixels(causticFilm.pixelCount(), Rgb(0.0f));
        const auto pixelOf = eye.column<EyePixel>();
        for (std::size_t v = 0; v < eye.size(); ++v) causticPixels[pixelOf[v]] += caustic[v];
        causticFilm.addToPixels(causticPixels, 1.0f);
        gatherMicroseconds += cpuMicrosecondsSince(start);

        ctx.addItems(hitCount);
        ctx.addCounter("gather_hits", hitCount);
        ctx.addCounter("photon_contributions", photonsUsed.load());
        ctx.addCounter("secondary_gathers", secondaryGathers.load());
        // The mean gather radius at the hits, in millionths of the scene
        // diagonal, to match fg_splat's bandwidth against (mean_hit_radius_ppm).
        ctx.addCounter("mean_gather_radius_ppm", radiusCount.load() > 0 ? radiusPpmSum.load() / radiusCount.load() : 0);
        ctx.addCounter("trace_cpu_us", traceMicroseconds);
        ctx.addCounter("gather_cpu_us", gatherMicroseconds);
    }

private:
    // Radiance leaving `origin` towards its primary, by M BSDF-sampled rays:
    // the emission each reaches plus the photon estimate at its hit.
    static Rgb secondaryRadiance(const Scene& scene, const RayQuery& rays, const GatherOrigin& origin,
                                 const GatherSource& global, float maxRadius, int count, jobs::Rng& rng,
                                 std::span<std::uint32_t> ids, std::span<float> dist2, std::int64_t& used) {
        Rgb sum(0.0f);
        for (int j = 0; j < count; ++j) {
            const std::optional<GatherHit> hit = traceGatherRay(scene, rays, origin, rng);
            if (!hit) continue;
            Rgb incoming(0.0f);
            if (hit->areaLight >= 0)
                incoming += scene.lights[static_cast<std::size_t>(hit->areaLight)]->emittedAt(hit->point.ng, -hit->direction,
                                                                                           hit->point.uv);
            if (hit->bsdf && hit->bsdf->hasSmoothLobe()) {
                const VertexBrdf brdf(*hit->bsdf, hit->point.ns, hit->point.ng, -hit->direction, hit->point.uv);
                incoming += gatherRadiance(hit->point.p, brdf, global, maxRadius, ids, dist2, used);
            }
            sum += hit->weight * incoming;
        }
        return sum / static_cast<float>(count);
    }
};

}  // namespace

PassRegistration finalGatherPass() {
    PassSpec spec;
    spec.name = "final_gather";
    spec.doc = "Final gathering with photon maps (Jensen 2001; the baseline of Herzog et al. 2007, §8.4): k nearest "
               "global photons, direct ones included, at the hits of BSDF-sampled rays; caustics from the caustic map";
    spec.inputs = {
        {"eye_vertices", "EyeVertices", "primary vertices the final-gather rays leave from, with pixel and throughput"},
        {"caustic_photons", "PhotonMap", "caustic photons (L S+ D)"},
        {"global_photons", "PhotonMap", "global photons with the direct ones (photon pass store_direct = true)"},
        {"caustic_index", "PointIndex", "search structure over caustic_photons"},
        {"global_index", "PointIndex", "search structure over all of global_photons (photon_index include_direct = true)"},
    };
    spec.outputs = {
        {"caustic", "Film", "caustic photon estimates at the primary vertices (a film from black)"},
        {"global", "Film", "indirect light through the final-gather hits (a film from black)"},
    };
    spec.params = {
        {"fg_rays", ParamType::Int, std::int64_t{16}, 1, 4096, {},
         "final-gather rays per primary vertex (the paper: 600; 16 keeps test and preview renders fast)"},
        {"tiles", ParamType::Int, std::int64_t{5}, 1, 64, {},
         "the image is gathered in tiles x tiles rectangles, one tile's hits at a time (as fg_splat)"},
        {"k_global", ParamType::Int, std::int64_t{100}, 1, 1 << 16, {},
         "nearest global photons per estimate at a hit; the k-th one's distance is the bandwidth h"},
        {"k_caustic", ParamType::Int, std::int64_t{50}, 1, 1 << 16, {},
         "nearest caustic photons per estimate at a primary vertex"},
        {"max_radius", ParamType::Float, 0.0, 0.0, 1e30, {},
         "largest gather radius in scene units; with fewer than k photons inside, it is the bandwidth (0 = unlimited)"},
        {"secondary_gather", ParamType::Bool, false, 0, 0, {},
         "gather again from hits closer to their primary than secondary_distance x h (Jensen's remedy for corners)"},
        {"secondary_rays", ParamType::Int, std::int64_t{16}, 1, 4096, {}, "rays per secondary final gather"},
        {"secondary_distance", ParamType::Float, 1.0, 0.0, 1e3, {},
         "hits nearer than this many gather radii h to their primary are gathered again"},
    };
    const auto preflight = [](const PreflightContext& pf) {
        if (!pf.scene.media.empty())
            throw InputError(pf.source + ": pass '" + pf.instance +
                             "': final gathering traces rays between surfaces only; the scene has participating media");
    };
    return {spec, [] { return std::make_unique<FinalGatherPass>(); }, preflight};
}

}  // namespace fg
