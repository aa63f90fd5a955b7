// Final gathering by photon ray splatting (`fg_splat`): Herzog et al. 2007,
// §8.4. Instead of the primary eye vertices, the hits of N BSDF-sampled final
// gather rays per primary vertex are indexed (the splat kd-tree of §7.1) and
// every photon ray, direct ones included, splats onto them with the estimate
// of §4-5 as passes/prs/ray_splat.h reads Eqs. 4-6,
//   L(x, w_o) = sum_i f_s(w_i, x, w_o) Phi_i |cos theta_i| K_R(d_perp),
// weighted by the hit's final-gather throughput (passes/common/final_gather.h),
// straight into the pixels: no radiance map (§8.4). The image is rendered in
// tiles x tiles rectangles, each with its own hits and tree, splatted by the
// same photon rays (§8.4 after Havran et al. 2005). Caustic photon rays are
// splatted once more at the primary vertices: final-gather hits on specular
// surfaces are dropped, so that light (L S+ D at the primary) comes only from
// there.
//
// The kd search (`traversal = "tight_boxes"`) is ray_splat's
// (forEachWeightedVertex in passes/prs/ray_splat.h): nodes entered by their
// hits' tight boxes, leaf hits weighed from the tree's columns, in
// Algorithm 1's order (§7.2); its vertex_candidates are the hits weighed.
// `origin_boundary = "renormalise"` corrects the kernel beside the surface a
// ray leaves as ray_splat's does (SplatFrustum::originBoundaryGain), and
// `slices = "hit_plane"` reads the growing radius as ray_splat's does; both
// are the defaults, as ray_splat's (`"cut"` and `"perpendicular"` give the
// paper's estimate).
//
// Rays are splatted in fixed blocks into per-block tile films merged in block
// order, so the image is the same for any thread count.
#include "passes/caustics/photon_estimate.h"
#include "passes/common/final_gather.h"
#include "passes/passes.h"
#include "passes/prs/ray_splat.h"

#include "engine/buffers/photon_buffers.h"
#include "engine/buffers/photon_ray_buffers.h"
#include "engine/core/error.h"
#include "engine/image/film.h"
#include "engine/scene/scene.h"
#include "jobs/parallel.h"

#include <algorithm>
#include <cmath>
#include <ctime>
#include <optional>
#include <vector>

namespace fg {

namespace {

// Memory for the per-block tile films; at least one block, at most 64.
constexpr std::size_t kAccumulatorBudget = std::size_t{256} << 20;

// Process CPU time since `start`, for the phase counters (gather-ray tracing
// and splatting, Table 2's T_E and T_S): nothing else runs in the process
// during this pass's phases, and on a shared machine wall time mostly
// measures the other load.
std::int64_t cpuMicrosecondsSince(std::clock_t start) {
    return static_cast<std::int64_t>(1e6 * static_cast<double>(std::clock() - start) / CLOCKS_PER_SEC);
}

// The vertices one splatting round writes to: a kd-tree over them and, in
// tree order, what a deposit needs. f_s at a Lambertian vertex is one
// constant, folded into `weight` with the throughput once per vertex.
struct SplatTargets {
    struct Target {
        Vec3 geometricNormal{0.0f};
        Rgb weight{0.0f};
        std::uint32_t pixel = 0;  // index into the round's pixel rectangle
        std::uint32_t vertex = 0;
        bool lambertian = false;
    };
    SplatKdTree tree;
    std::vector<Target> targets;
};

// A rectangle of the film: pixels x in [x0, x1), y in [y0, y1).
struct PixelRect {
    std::size_t x0 = 0, y0 = 0, x1 = 0, y1 = 0, filmWidth = 0;
    std::size_t size() const { return (x1 - x0) * (y1 - y0); }
    std::uint32_t local(std::uint32_t pixel) const {
        const std::size_t x = pixel % filmWidth, y = pixel / filmWidth;
        return static_cast<std::uint32_t>((y - y0) * (x1 - x0) + (x - x0));
    }
    std::size_t global(std::size_t local) const {
        return (y0 + local / (x1 - x0)) * filmWidth + x0 + local % (x1 - x0);
    }
};

SplatTargets indexTargets(const Scene& scene, const EyeVertexBuffer::View& vertices, const PixelRect& rect,
                          std::uint32_t leafSize) {
    SplatTargets out;
    SplatKdTreeOptions options;  // 0.1 % of the scene diagonal, as splat_index's default
    options.maxLeafSize = leafSize;
    options.minCellDiagonal = 0.001f * glm::length(scene.boundsMax - scene.boundsMin);
    out.tree.build(vertices.column<EyePosition>(), vertices.column<EyeNormal>(), options);
    out.targets.assign(vertices.size(), SplatTargets::Target{});
    jobs::parallelFor(vertices.size(), 4096, [&](std::size_t slot) {
        SplatTargets::Target& t = out.targets[slot];
        const std::uint32_t v = out.tree.vertexOf(static_cast<std::uint32_t>(slot));
        t.vertex = v;
        t.pixel = rect.local(vertices.column<EyePixel>()[v]);
        t.geometricNormal = vertices.column<EyeGeometricNormal>()[v];
        const std::optional<Rgb> reflectance =
            scene.bsdfs[vertices.column<EyeBsdf>()[v]]->constantReflectance(vertices.column<EyeUv>()[v]);
        if (!reflectance) return;
        t.lambertian = true;
        // Seen from below its shading normal, a Lambertian surface reflects nothing.
        if (glm::dot(vertices.column<EyeOutgoing>()[v], vertices.column<EyeNormal>()[v]) > 0.0f)
            t.weight = *reflectance * vertices.column<EyeThroughput>()[v];
    });
    return out;
}

struct SplatCounts {
    std::int64_t candidates = 0;
    std::int64_t deposits = 0;
};

// Every ray whose class `wanted` accepts splats onto the targets; returns the
// rectangle's pixels, summed per fixed block of rays and merged in block order.
template <class WantedClass>
std::vector<Rgb> splatOnto(const Scene& scene, const EyeVertexBuffer::View& vertices, const SplatTargets& targets,
                           std::size_t pixelCount, const SplatRayBuffer& rays, WantedClass wanted, SplatEndCap cap,
                           bool useCullNodes, bool tightBoxes, bool renormalise, SplatSlices slices,
                           SplatCounts& counts) {
    const auto origin = rays.column<RayOrigin>();
    const auto direction = rays.column<RayDirection>();
    const auto length = rays.column<RayLength>();
    const auto power = rays.column<RayPower>();
    const auto h0 = rays.column<RayH0>();
    const auto dh = rays.column<RayDh>();
    const auto rayClass = rays.column<RayClassColumn>();
    const auto originNormal = rays.column<RayOriginNormal>();
    const auto endNormal = rays.column<RayEndNormal>();
    const auto throughput = vertices.column<EyeThroughput>();

    struct Block {
        std::vector<Rgb> pixels;
        SplatCounts counts;
    };
    const std::size_t blockBytes = std::max<std::size_t>(1, pixelCount * sizeof(Rgb));
    std::vector<Block> blocks(std::clamp<std::size_t>(kAccumulatorBudget / blockBytes, 1, 64));
    jobs::parallelForBlocks(rays.size(), blocks.size(), [&](std::size_t b, jobs::IndexRange range) {
        Block& acc = blocks[b];
        acc.pixels.assign(pixelCount, Rgb(0.0f));
        for (std::size_t r = range.begin; r != range.end; ++r) {
            if (!wanted(rayClass[r])) continue;
            const SplatRay ray{origin[r], direction[r], h0[r], dh[r], length[r], originNormal[r], endNormal[r]};
            if (!(ray.h0 > 0.0f || ray.dh > 0.0f)) continue;
            const Vec3 incident = -ray.direction;
            const SplatFrustum frustum(ray, cap, slices);
            const Rgb rayPower = power[r] * frustum.hitPlaneGain();
            const auto deposit = [&](std::uint32_t slot, float weight) {
                const SplatTargets::Target& target = targets.targets[slot];
                Rgb f;
                if (target.lambertian) {
                    if (!(glm::dot(incident, target.geometricNormal) > 0.0f)) return;
                    f = target.weight;
                } else {
                    f = VertexBrdf(scene, vertices, target.vertex)(incident) * throughput[target.vertex];
                }
                const Rgb value = f * rayPower * weight;
                if (!isFinite(value)) return;
                acc.pixels[target.pixel] += value;
                ++acc.counts.deposits;
            };
            const SplatCone cone = splatCone(ray, cap, slices);
            if (tightBoxes && renormalise && frustum.hasOriginSurface) {
                const auto renormalised = [&](std::uint32_t slot, float weight) {
                    deposit(slot, weight * frustum.originBoundaryGain(targets.tree.slotPosition(slot)));
                };
                acc.counts.candidates += static_cast<std::int64_t>(
                    forEachWeightedVertex(targets.tree, frustum, cone, renormalised, useCullNodes));
            } else if (tightBoxes) {
                acc.counts.candidates +=
                    static_cast<std::int64_t>(forEachWeightedVertex(targets.tree, frustum, cone, deposit, useCullNodes));
            } else {
                targets.tree.forEachCandidate(
                    cone,
                    [&](std::uint32_t slot) {
                        ++acc.counts.candidates;
                        float weight = frustum.weight(targets.tree.slotPosition(slot), targets.tree.slotNormal(slot));
                        if (weight > 0.0f && renormalise)
                            weight *= frustum.originBoundaryGain(targets.tree.slotPosition(slot));
                        if (weight > 0.0f) deposit(slot, weight);
                    },
                    useCullNodes);
            }
        }
    });
    std::vector<Rgb> total(pixelCount, Rgb(0.0f));
    for (const Block& block : blocks) {
        for (std::size_t i = 0; i < block.pixels.size(); ++i) total[i] += block.pixels[i];
        counts.candidates += block.counts.candidates;
        counts.deposits += block.counts.deposits;
    }
    return total;
}

// The mean kernel radius where the rays meet a surface, R(t_hit), in
// millionths of the scene diagonal: the bandwidth to compare with the photon
// map's mean gather radius (final_gather's mean_gather_radius_ppm), as the
// paper chooses C for equal mean bandwidths (§9, Fig. 9). Rays that escape
// or carry no footprint do not count. Summed in integers, so the figure does
// not depend on the order.
std::int64_t meanHitRadiusPpm(const Scene& scene, const SplatRayBuffer& rays) {
    const auto h0 = rays.column<RayH0>();
    const auto dh = rays.column<RayDh>();
    const auto length = rays.column<RayLength>();
    const auto endNormal = rays.column<RayEndNormal>();
    const double scale = 1e6 / static_cast<double>(glm::length(scene.boundsMax - scene.boundsMin));
    std::int64_t sum = 0, count = 0;
    for (std::size_t r = 0; r < rays.size(); ++r) {
        const float radius = h0[r] + dh[r] * length[r];
        if (endNormal[r] == Vec3(0.0f) || !(radius > 0.0f)) continue;
        sum += std::llround(scale * static_cast<double>(radius));
        ++count;
    }
    return count > 0 ? sum / count : 0;
}

class FinalGatherSplatPass final : public Pass {
public:
    void run(PassContext& ctx) override {
        const Scene& scene = ctx.scene();
        const EyeVertexBuffer::View eye = ctx.input<EyeVertices>("eye_vertices").vertices.view();
        const SplatRays& splatRays = ctx.input<SplatRays>("splat_rays");
        const int raysPerVertex = static_cast<int>(ctx.params().getInt("fg_rays"));
        const int tiles = static_cast<int>(ctx.params().getInt("tiles"));
        const SplatEndCap cap = ctx.params().getString("end_cap") == "hemisphere" ? SplatEndCap::Hemisphere
                                                                                  : SplatEndCap::TangentPlane;
        const bool useCullNodes = ctx.params().getBool("cull_nodes");
        const bool tightBoxes = ctx.params().getString("traversal") == "tight_boxes";
        const bool renormalise = ctx.params().getString("origin_boundary") == "renormalise";
        const SplatSlices slices =
            ctx.params().getString("slices") == "hit_plane" ? SplatSlices::HitPlane : SplatSlices::Perpendicular;
        const auto leafSize = static_cast<std::uint32_t>(ctx.params().getInt("leaf_size"));
        const SplatRayBuffer& rays = splatRays.rays;

        Film& global = ctx.createOutput<Film>("global", ctx.filmSettings());
        Film& caustic = ctx.createOutput<Film>("caustic", ctx.filmSettings());
        const auto width = static_cast<std::size_t>(global.width());
        const auto height = static_cast<std::size_t>(global.height());
        const auto tileCount = static_cast<std::size_t>(tiles);
        const std::vector<std::vector<std::uint32_t>> byTile =
            primariesByTile(eye, global.width(), global.height(), tiles);

        std::vector<Rgb> globalPixels(global.pixelCount(), Rgb(0.0f));
        SplatCounts counts;
        std::int64_t hitCount = 0, traceMicroseconds = 0, splatMicroseconds = 0;
        const auto everyClass = [](std::uint8_t) { return true; };
        for (std::size_t tile = 0; tile < byTile.size(); ++tile) {
            const std::size_t tx = tile % tileCount, ty = tile / tileCount;
            const PixelRect rect{(tx * width + tileCount - 1) / tileCount, (ty * height + tileCount - 1) / tileCount,
                                 ((tx + 1) * width + tileCount - 1) / tileCount,
                                 ((ty + 1) * height + tileCount - 1) / tileCount, width};
            if (byTile[tile].empty() || rect.size() == 0) continue;
            auto start = std::clock();
            FinalGatherHits hits;
            traceFinalGatherHits(scene, ctx.rays(), eye, byTile[tile], raysPerVertex, ctx.seed(), ctx.streamKey(), hits);
            traceMicroseconds += cpuMicrosecondsSince(start);
            hitCount += static_cast<std::int64_t>(hits.vertices.size());

            start = std::clock();
            const EyeVertexBuffer::View hitView = hits.vertices.view();
            const SplatTargets targets = indexTargets(scene, hitView, rect, leafSize);
            const std::vector<Rgb> local =
                splatOnto(scene, hitView, targets, rect.size(), rays, everyClass, cap, useCullNodes, tightBoxes,
                          renormalise, slices, counts);
            for (std::size_t i = 0; i < local.size(); ++i) globalPixels[rect.global(i)] += local[i];
            splatMicroseconds += cpuMicrosecondsSince(start);
            ctx.reportProgress(static_cast<double>(tile + 1) / static_cast<double>(byTile.size()));
        }
        global.addToPixels(globalPixels, 1.0f);

        if (splatRays.countPerClass[PhotonRayClass::Caustic] > 0) {
            const auto start = std::clock();
            const PixelRect film{0, 0, width, height, width};
            const SplatTargets targets = indexTargets(scene, eye, film, leafSize);
            const auto causticOnly = [](std::uint8_t c) { return c == PhotonRayClass::Caustic; };
            caustic.addToPixels(
                splatOnto(scene, eye, targets, film.size(), rays, causticOnly, cap, useCullNodes, tightBoxes, renormalise,
                          slices, counts),
                1.0f);
            splatMicroseconds += cpuMicrosecondsSince(start);
        }
        ctx.addItems(hitCount);
        ctx.addCounter("gather_hits", hitCount);
        ctx.addCounter("mean_hit_radius_ppm", meanHitRadiusPpm(scene, rays));
        ctx.addCounter("vertex_candidates", counts.candidates);
        ctx.addCounter("vertex_deposits", counts.deposits);
        ctx.addCounter("trace_cpu_us", traceMicroseconds);
        ctx.addCounter("splat_cpu_us", splatMicroseconds);
    }
};

}  // namespace

PassRegistration finalGatherSplatPass() {
    PassSpec spec;
    spec.name = "fg_splat";
    spec.doc = "Final gathering by photon ray splatting (Herzog et al. 2007, §8.4): every photon ray splats onto the hits "
               "of BSDF-sampled final-gather rays, tile by tile; caustic rays also onto the primary vertices";
    spec.inputs = {
        {"eye_vertices", "EyeVertices", "primary vertices the final-gather rays leave from, with pixel and throughput"},
        {"splat_rays", "SplatRays", "photon rays with bandwidths (ray_bandwidth), direct ones included"},
    };
    spec.outputs = {
        {"global", "Film", "indirect light through the final-gather hits (a film from black)"},
        {"caustic", "Film", "caustic photon rays splatted at the primary vertices (a film from black)"},
    };
    spec.params = {
        {"fg_rays", ParamType::Int, std::int64_t{16}, 1, 4096, {},
         "final-gather rays per primary vertex (the paper: 600; 16 keeps test and preview renders fast)"},
        {"tiles", ParamType::Int, std::int64_t{5}, 1, 64, {},
         "the image is gathered in tiles x tiles rectangles, one kd-tree of hits at a time (the paper: 5)"},
        {"end_cap", ParamType::String, std::string("tangent_plane"), 0, 0, {"tangent_plane", "hemisphere"},
         "footprint beyond the hit point, as ray_splat's"},
        {"cull_nodes", ParamType::Bool, true, 0, 0, {}, "use the kd-trees' backface-culling nodes"},
        {"origin_boundary", ParamType::String, std::string("renormalise"), 0, 0, {"cut", "renormalise"},
         "the kernel where its disk reaches behind the surface the ray leaves: renormalised over the part in front "
         "of it, or cut there, as the paper (ray_splat's parameter of the same name)"},
        {"slices", ParamType::String, std::string("hit_plane"), 0, 0, {"perpendicular", "hit_plane"},
         "where the growing radius is read at a vertex: where the plane through it parallel to the hit's tangent "
         "plane crosses the ray, or at its foot on the ray (the paper) (ray_splat's parameter of the same name)"},
        {"traversal", ParamType::String, std::string("tight_boxes"), 0, 0, {"tight_boxes", "cells"},
         "kd search: nodes by their vertices' tight boxes and leaf vertices weighed from columns, or Algorithm 1's "
         "cell clipping (same deposits in the same order)"},
        {"leaf_size", ParamType::Int, std::int64_t{16}, 1, 1 << 20, {},
         "kd-tree nodes with fewer hits become leaves (§7.1: 16)"},
    };
    const auto preflight = [](const PreflightContext& pf) {
        if (!pf.scene.media.empty())
            throw InputError(pf.source + ": pass '" + pf.instance +
                             "': photon ray splatting traces rays between surfaces only; the scene has participating media");
    };
    // Per-block films of one tile (the largest, rounded up), and the tile's hits: at most fg_rays per camera sample.
    const auto memory = [](const PreflightContext& pf) {
        const auto tiles = static_cast<std::uint64_t>(pf.params.getInt("tiles"));
        const std::uint64_t tilePixels = ((static_cast<std::uint64_t>(pf.film.width) + tiles - 1) / tiles) *
                                         ((static_cast<std::uint64_t>(pf.film.height) + tiles - 1) / tiles);
        const std::uint64_t tileFilm = multiplyBytes(tilePixels, sizeof(Rgb));
        const std::uint64_t blocks = std::clamp<std::uint64_t>(kAccumulatorBudget / std::max<std::uint64_t>(tileFilm, 1), 1, 64);
        constexpr std::uint64_t kBytesPerHit = 6 * sizeof(Vec3) + sizeof(Vec2) + sizeof(Rgb) + 4 * sizeof(std::uint32_t);
        const std::uint64_t hits = multiplyBytes(tilePixels, static_cast<std::uint64_t>(pf.params.getInt("fg_rays")));
        return MemoryEstimate{addBytes(multiplyBytes(filmBytes(pf.film), 2),
                                       addBytes(multiplyBytes(tileFilm, blocks), multiplyBytes(hits, kBytesPerHit))),
                              std::to_string(blocks) + " tile splat accumulators and one tile's final-gather hits "
                                                       "per camera sample",
                              {}};
    };
    return {spec, [] { return std::make_unique<FinalGatherSplatPass>(); }, preflight, memory};
}

}  // namespace fg
