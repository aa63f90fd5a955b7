// Bidirectional path tracing (`bdpt`), Veach 1997 ch. 10: for every camera
// sample a camera subpath z_0..z_{t-1} and a light subpath y_0..y_{s-1} are
// traced, and every pair of prefixes is joined by one connection (strategy
// (s, t), a path of s + t vertices, Veach §10.2):
//  - s = 0: the camera subpath itself reaches a light (area emitter or environment);
//  - s = 1: next-event estimation, a light point sampled afresh from z_{t-1};
//  - t = 1: a light vertex connected to the pinhole and splatted on the film
//    through the pixel filter (the light tracing of light_trace_pass.cpp);
//  - otherwise y_{s-1} and z_{t-1} are joined by a shadow ray.
// The strategies are combined with the balance or power heuristic (Veach
// §9.2), the weights built from the ratios of neighbouring strategies'
// densities (§10.2-10.3, bdpt_path.h). Delta lights
// (point, spot, directional) and specular vertices take no weight in the
// strategies that cannot produce them.
//
// Guided BDPT (Vorba et al. 2014, Fig. 1 and §4.1). With a `radiance_cache`
// input, camera subpaths draw their directions at vertices with smooth,
// non-transmissive lobes from the one-sample mixture α p_bsdf + (1 - α) p_gmm
// of the radiance record there, with an `importance_cache` light subpaths do
// the same with the importance record, and the throughput takes f cos / p_mix.
// Every density in the weights is the one of the subpath that would sample
// the direction: a vertex's forward density the mixture of its own side's
// cache, its reverse density the mixture of the other side's (BSDF densities
// where that side has no record), so the ratios stay those of the strategies.
//
// Subpaths grow through surfaces and homogeneous media as `pt`'s paths do:
// chromatic free-flight sampling (HomogeneousMedium::sampleDistance) gives
// medium vertices scattered by the Henyey-Greenstein phase function; null
// boundaries, masks and thindielectric's straight-through events are crossed
// without a vertex; connections are shadow rays that accumulate transmittance
// through null boundaries and media (shadowTransmittance of path_vertex.h).
//
// Film. A camera sample's estimate (t >= 2) goes to the film as `pt`'s samples
// do; light-image contributions (t = 1) of a light path with throughput
// beta at x, seen from the eye at distance d and angle theta_c off the axis,
//
//   I_j += beta f(x -> eye) (H / 2 tan(fov_y / 2))^2 / (d^2 cos^3 theta_c) w(r - c_j) / W_j / N,
//
// (f holding the cosine at x; the raster area per unit solid angle at the eye
// is (H / 2 tan)^2 / cos^3 theta_c) where N is the number of light paths
// (one per camera sample) and W_j the integral of pixel j's filter over the
// image, the normaliser the camera samples' filter-weighted average of that
// pixel converges to (it differs from the whole filter's integral only within
// the filter radius of the border). Splats are summed per fixed block of
// camera samples and the blocks merged in block order, so the image is the
// same for any thread count.
//
// Data layout: the samples of a wave keep their per-sample state in SoA
// columns (raster position, estimate, subpath lengths, random stream) and
// their subpaths in a vertex column of fixed-size slots per sample (a vertex
// is one record: every connection reads most of its fields); a wave advances
// in three stages (camera subpaths, light subpaths, connections), the
// connections of each group of samples resolved as one stream of shadow rays.
#include "passes/bdpt/bdpt_path.h"
#include "passes/common/light_media.h"
#include "passes/common/path_vertex.h"
#include "passes/common/roulette.h"
#include "passes/passes.h"

#include "engine/accel/ray_query.h"
#include "engine/core/error.h"
#include "engine/core/memory.h"
#include "engine/core/soa.h"
#include "engine/image/film.h"
#include "engine/scene/scene.h"
#include "jobs/parallel.h"
#include "jobs/random.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

namespace fg {

namespace {

FG_SOA_COLUMN(SampleRaster, Vec2, "raster");
FG_SOA_COLUMN(SampleRadiance, Rgb, "radiance");
FG_SOA_COLUMN(SampleCameraLength, std::uint16_t, "camera_vertices");
FG_SOA_COLUMN(SampleLightLength, std::uint16_t, "light_vertices");
FG_SOA_COLUMN(SampleRng, jobs::Rng, "rng");
using SampleBuffer = SoaBuffer<SampleRaster, SampleRadiance, SampleCameraLength, SampleLightLength, SampleRng>;

// Subpath vertices: max_depth + 1 camera or max_depth light slots per sample.
FG_SOA_COLUMN(SubpathVertex, BdptVertex, "vertex");
using VertexBuffer = SoaBuffer<SubpathVertex>;

// Relative length by which connection rays stop short of the vertex they aim at.
constexpr float kShadowEpsilon = 1e-3f;
// Bytes of per-block light-image accumulators the pass may hold at once.
constexpr std::size_t kAccumulatorBudget = std::size_t{256} << 20;
constexpr std::size_t kMaxBlocks = 16;
// Samples whose connections are resolved as one shadow-ray stream.
constexpr std::size_t kConnectGroup = 64;
constexpr int kMaxDepthLimit = 64;

struct Settings {
    int spp = 16;
    int maxDepth = 17;  // Mitsuba's: longest path in segments
    int rrDepth = 5;
    float rrThreshold = 1.0f;
    MisHeuristic heuristic = MisHeuristic::Power;
    int strategyLength = 0;  // write per-strategy AOVs for paths up to this many segments
    bool weightedStrategies = true;
    std::size_t waveSize = 1 << 14;
};

// Index of strategy (s, t) among the AOVs, or -1.
struct StrategyTable {
    int maxLength = 0;
    std::vector<std::pair<int, int>> strategies;  // (s, t)
    int index(int s, int t) const {
        const int length = s + t - 1;
        if (length < 1 || length > maxLength || t < 1) return -1;
        // Strategies of length l are (l + 1 - t, t) for t = 1..l+1, in that order.
        int first = 0;
        for (int l = 1; l < length; ++l) first += l + 1;
        return first + (t - 1);
    }
    explicit StrategyTable(int max) : maxLength(max) {
        for (int l = 1; l <= max; ++l)
            for (int t = 1; t <= l + 1; ++t) strategies.emplace_back(l + 1 - t, t);
    }
    std::size_t size() const { return strategies.size(); }
};

struct SplatBlock {
    std::vector<Rgb> pixels;
    std::vector<Rgb> strategyPixels;  // strategies x pixels, unfiltered (each pixel its own area)
    std::int64_t connections = 0;
};

// A connection waiting for its shadow ray.
struct PendingConnection {
    Ray ray;
    Rgb value{0.0f};  // unweighted and unoccluded
    BdptWeightTerms weight;  // finished once the shadow ray has walked the media between the ends
    float shortfall = 0.0f;  // how far short of the far vertex the ray stops
    Vec2 raster{0.0f};
    std::uint32_t sample = 0;
    int medium = -1;
    int strategy = -1;
    bool splat = false;
};

// Russian roulette on the throughput relative to the subpath's start.
bool survives(int scatterings, int rrDepth, float rrThreshold, float startMax, float etaScale, Rgb& beta,
              jobs::Rng& rng) {
    if (scatterings < rrDepth) return true;
    return rouletteSurvives(maxComponent(beta * etaScale) / startMax, rrThreshold, rng, beta);
}

// Extends path[0] (the camera or a light origin) by a random walk; returns the vertex count.
int randomWalk(const BdptScene& bs, Ray ray, Rgb beta, float pdfDirection, int medium, TransportMode mode,
               int maxVertices, int rrDepth, float rrThreshold, jobs::Rng& rng, BdptVertex* path) {
    const Scene& scene = bs.scene;
    int count = 1;
    float etaScale = 1.0f;
    const float startMax = std::max(maxComponent(beta), 1e-30f);
    // The media crossed since the last vertex, for the free-flight densities of the next one.
    FreeFlightSegment segment;
    const auto addVertex = [&](BdptVertex v) -> BdptVertex& {
        BdptVertex& prev = path[count - 1];
        v.pdfFwd = count == 1 ? bdptPdf(bs, nullptr, prev, v) : bdptConvertDensity(pdfDirection, prev, v);
        v.pdfFwd *= bdptDistancePdf(segment, prev, v, true);
        v.distancePdfRev = bdptDistancePdf(segment, prev, v, false);
        segment = FreeFlightSegment();
        path[count++] = v;
        return path[count - 1];
    };
    while (count < maxVertices) {
        const Hit hit = bs.rays.intersect(ray);
        if (medium >= 0) {
            const HomogeneousMedium& m = scene.media[static_cast<std::size_t>(medium)];
            const float uChannel = rng.uniform();
            const float uDistance = rng.uniform();
            const DistanceSample ds = m.sampleDistance(hit.valid() ? hit.t : kInfinity, uChannel, uDistance, beta);
            if (ds.scattered || hit.valid()) segment.add(m, ds.t);
            beta *= ds.weight;
            if (isBlack(beta)) break;
            if (ds.scattered) {
                BdptVertex v;
                v.kind = BdptVertexKind::Medium;
                v.p = ray.origin + ds.t * ray.direction;
                v.wo = -ray.direction;
                v.beta = beta;
                v.medium = medium;
                BdptVertex& added = addVertex(v);
                if (count >= maxVertices) break;
                const PhaseSample ps = m.phase().sample(added.wo, rng.uniform2());
                if (!(ps.pdf > 0.0f)) break;
                // Henyey-Greenstein depends on the angle alone: the reverse density is the same.
                path[count - 2].pdfRev = bdptConvertDensity(ps.pdf, added, path[count - 2]) * added.distancePdfRev;
                pdfDirection = ps.pdf;
                ray = Ray{added.p, ps.wi, kInfinity};
                if (!survives(count - 1, rrDepth, rrThreshold, startMax, etaScale, beta, rng)) break;
                continue;
            }
        }
        if (!hit.valid()) {
            if (mode == TransportMode::Radiance && !bs.infiniteLights.empty()) {
                BdptVertex v;
                v.kind = BdptVertexKind::Light;
                v.infinite = true;
                v.p = ray.direction;
                v.wo = -ray.direction;
                v.beta = beta;
                v.medium = medium;
                addVertex(v);
            }
            break;
        }
        const SurfacePoint sp = bs.rays.surface(ray, hit);
        const Shape& shape = scene.shapes[sp.shape];
        const Bsdf* bsdf = shape.bsdf >= 0 ? scene.bsdfs[static_cast<std::size_t>(shape.bsdf)].get() : nullptr;
        if (!bsdf || bsdf->isNull() || passesThroughMask(bsdf, sp.texturePoint(), rng)) {
            // No vertex: the direction is unchanged, so densities still convert
            // over the straight line between the real vertices on either side.
            medium = mediumAfterCrossing(shape, sp.ng, ray.direction, medium);
            ray = Ray{offsetRayOrigin(sp.p, sp.ng, ray.direction), ray.direction, kInfinity};
            continue;
        }
        const Frame frame(sp.ns);
        const Vec3 woLocal = frame.toLocal(-ray.direction);
        std::optional<BsdfSample> chosen;
        if (bsdf->hasNullLobe()) {
            const float uLobe = rng.uniform();
            const Vec2 uDir = rng.uniform2();
            chosen = bsdf->sample(woLocal, sp.texturePoint(), uLobe, uDir, mode);
            if (!chosen || chosen->pdf <= 0.0f || isBlack(chosen->weight)) break;
            if (chosen->lobe & BsdfLobe::Null) {
                beta *= chosen->weight;
                medium = mediumAfterCrossing(shape, sp.ng, ray.direction, medium);
                ray = Ray{offsetRayOrigin(sp.p, sp.ng, ray.direction), ray.direction, kInfinity};
                continue;
            }
        }
        BdptVertex v;
        v.kind = BdptVertexKind::Surface;
        v.p = sp.p;
        v.ng = sp.ng;
        v.ns = sp.ns;
        v.at = sp.texturePoint();
        v.shape = sp.shape;
        v.wo = -ray.direction;
        v.beta = beta;
        v.medium = medium;
        v.light = shape.areaLight;
        BdptVertex& added = addVertex(v);
        if (count >= maxVertices) break;
        if (!chosen) {
            if (const std::optional<GuidedBsdfSampler> guided = bs.guide(added, *bsdf, added.wo, mode)) {
                const float uStrategy = rng.uniform();
                const float uLobe = rng.uniform();
                const Vec2 uDirection = rng.uniform2();
                chosen = guided->sampleAsBsdf(uStrategy, uLobe, uDirection, mode);
                if (!chosen) break;
            } else {
                const float uLobe = rng.uniform();
                const Vec2 uDir = rng.uniform2();
                chosen = bsdf->sample(woLocal, sp.texturePoint(), uLobe, uDir, mode);
            }
        }
        if (!chosen || chosen->pdf <= 0.0f || isBlack(chosen->weight)) break;
        const Vec3 wi = frame.toWorld(chosen->wi);
        if (glm::dot(wi, sp.ng) * chosen->wi.z <= 0.0f) break;
        beta *= chosen->weight;
        float pdfForward = chosen->pdf;
        // The reverse density is that of a subpath from the other end, guided by its own cache.
        const TransportMode otherWalk = mode == TransportMode::Radiance ? TransportMode::Importance : TransportMode::Radiance;
        float pdfReverse = 0.0f;
        if (const std::optional<GuidedBsdfSampler> reverse = bs.guide(added, *bsdf, wi, otherWalk))
            pdfReverse = reverse->pdf(woLocal, added.wo);
        else
            pdfReverse = bsdf->pdf(chosen->wi, woLocal, sp.texturePoint());
        if (chosen->isSpecular()) {
            added.delta = true;
            const BdptSpecularPdfs specular = bdptSpecularPdfs(woLocal, chosen->wi, chosen->eta);
            pdfForward = specular.forward;
            pdfReverse = specular.reverse;
        }
        path[count - 2].pdfRev = bdptConvertDensity(pdfReverse, added, path[count - 2]) * added.distancePdfRev;
        if (chosen->lobe & BsdfLobe::Transmission) {
            if (mode == TransportMode::Radiance) etaScale *= sqr(chosen->eta);
            medium = mediumAfterCrossing(shape, sp.ng, wi, medium);
        }
        pdfDirection = pdfForward;
        ray = Ray{offsetRayOrigin(sp.p, sp.ng, wi), wi, kInfinity};
        if (!survives(count - 1, rrDepth, rrThreshold, startMax, etaScale, beta, rng)) break;
    }
    return count;
}

// Medium a connection ray leaves vertex v in, towards `dir`.
int mediumTowards(const BdptScene& bs, const BdptVertex& v, const Vec3& dir) {
    if (v.kind == BdptVertexKind::Camera) return bs.view.medium;
    if (v.kind == BdptVertexKind::Surface)
        return mediumAfterCrossing(bs.scene.shapes[v.shape], v.ng, dir, v.medium);
    return v.medium;
}

// A ray from `from` (the camera-side vertex) that stops just short of `to`.
Ray connectionRay(const BdptScene& bs, const BdptVertex& from, const BdptVertex& to) {
    Ray ray;
    Vec3 origin = from.p;
    if (from.kind == BdptVertexKind::Camera) {
        const Vec3 dir = bdptDirection(from, to);
        // As the camera's own rays, connections start on the near plane.
        origin = from.p + (bs.view.nearClip / glm::dot(dir, bs.view.forward)) * dir;
    } else if (from.onSurface()) {
        origin = offsetRayOrigin(from.p, from.ng, bdptDirection(from, to));
    }
    ray.origin = origin;
    if (to.infinite) {
        ray.direction = to.p;
        ray.tMax = kInfinity;
        return ray;
    }
    const Vec3 d = to.p - origin;
    const float distance = glm::length(d);
    ray.direction = d / distance;
    ray.tMax = distance * (1.0f - kShadowEpsilon);
    return ray;
}

// Distance between where a connection ray stops and the vertex it aims at.
float rayShortfall(const Ray& ray, const BdptVertex& to) {
    if (to.infinite) return 0.0f;
    return std::max(0.0f, glm::length(to.p - ray.origin) - ray.tMax);
}

// Integral of each pixel's filter over the image: the normaliser its camera
// samples' filter-weighted average converges to. The filters are separable,
// w(dx, dy) = g(dx) g(dy), so the integral is the product of two 1-D integrals
// of w(., 0) and w(0, .), divided by w(0, 0) = g(0)^2 (midpoint rule).
std::vector<float> filterNormalisers(const FilmSettings& film) {
    const PixelFilter filter(film);
    const double radius = film.filterRadius;
    constexpr int kSteps = 1024;
    const double step = 2.0 * radius / kSteps;
    const auto axisIntegral = [&](int pixel, int size, bool horizontal) {
        double sum = 0.0;
        for (int i = 0; i < kSteps; ++i) {
            const double offset = -radius + (i + 0.5) * step;
            const double position = pixel + 0.5 + offset;
            if (position < 0.0 || position >= size) continue;
            const auto d = static_cast<float>(offset);
            sum += horizontal ? filter(d, 0.0f) : filter(0.0f, d);
        }
        return sum * step;
    };
    const double centre = filter(0.0f, 0.0f);
    std::vector<double> columns(static_cast<std::size_t>(film.width)), rows(static_cast<std::size_t>(film.height));
    for (int x = 0; x < film.width; ++x) columns[static_cast<std::size_t>(x)] = axisIntegral(x, film.width, true);
    for (int y = 0; y < film.height; ++y) rows[static_cast<std::size_t>(y)] = axisIntegral(y, film.height, false);
    std::vector<float> normaliser(static_cast<std::size_t>(film.width) * static_cast<std::size_t>(film.height));
    for (int y = 0; y < film.height; ++y)
        for (int x = 0; x < film.width; ++x)
            normaliser[static_cast<std::size_t>(y) * static_cast<std::size_t>(film.width) + static_cast<std::size_t>(x)] =
                static_cast<float>(columns[static_cast<std::size_t>(x)] * rows[static_cast<std::size_t>(y)] / centre);
    return normaliser;
}

struct SplatTarget {
    const FilmSettings& film;
    const PixelFilter& filter;
    const std::vector<float>& normaliser;
    std::size_t strategies = 0;
    bool weightedStrategies = true;
};

// Traces the shadow rays of a group of connections (one occlusion stream when
// nothing but opaque surfaces can block them) and adds what passes: camera
// strategies to their sample's estimate, t = 1 to the block's light image.
void resolveConnections(const BdptScene& bs, const SplatTarget& target, std::span<const PendingConnection> pending,
                        std::span<Rgb> radiance, std::span<Rgb> sampleStrategies, SplatBlock& acc) {
    constexpr std::size_t kStream = 256;
    std::array<Ray, kStream> rays;
    std::array<std::uint8_t, kStream> blocked;
    std::array<Rgb, kStream> transmittance;
    std::array<float, kStream> weights;
    const std::ptrdiff_t width = target.film.width, height = target.film.height;
    const float reach = target.film.filterRadius;
    for (std::size_t first = 0; first < pending.size(); first += kStream) {
        const std::size_t n = std::min(kStream, pending.size() - first);
        if (bs.connectionsNeedTransmittance) {
            for (std::size_t k = 0; k < n; ++k) {
                const PendingConnection& c = pending[first + k];
                ShadowRequest request;
                request.ray = c.ray;
                request.medium = c.medium;
                request.pending = true;
                FreeFlightSegment media;
                transmittance[k] = shadowTransmittance(bs.tracer, request, &media);
                // The ray stops short of the far vertex; the densities need the whole segment.
                media.extendEnd(c.shortfall);
                weights[k] = bdptFinishWeight(c.weight, media);
            }
        } else {
            for (std::size_t k = 0; k < n; ++k) rays[k] = pending[first + k].ray;
            bs.rays.occluded(std::span<const Ray>(rays.data(), n), std::span<std::uint8_t>(blocked.data(), n));
            for (std::size_t k = 0; k < n; ++k) {
                transmittance[k] = blocked[k] ? Rgb(0.0f) : Rgb(1.0f);
                weights[k] = bdptFinishWeight(pending[first + k].weight, FreeFlightSegment());
            }
        }
        for (std::size_t k = 0; k < n; ++k) {
            const PendingConnection& c = pending[first + k];
            if (isBlack(transmittance[k])) continue;
            const Rgb value = c.value * transmittance[k];
            const Rgb weighted = value * weights[k];
            const Rgb strategyValue = target.weightedStrategies ? weighted : value;
            if (!isFinite(value)) continue;
            ++acc.connections;
            if (!c.splat) {
                radiance[c.sample] += weighted;
                if (c.strategy >= 0) sampleStrategies[c.sample * target.strategies + static_cast<std::size_t>(c.strategy)] += strategyValue;
                continue;
            }
            const auto x0 = std::max<std::ptrdiff_t>(0, static_cast<std::ptrdiff_t>(std::floor(c.raster.x - reach)));
            const auto x1 = std::min<std::ptrdiff_t>(width - 1, static_cast<std::ptrdiff_t>(std::floor(c.raster.x + reach)));
            const auto y0 = std::max<std::ptrdiff_t>(0, static_cast<std::ptrdiff_t>(std::floor(c.raster.y - reach)));
            const auto y1 = std::min<std::ptrdiff_t>(height - 1, static_cast<std::ptrdiff_t>(std::floor(c.raster.y + reach)));
            for (std::ptrdiff_t py = y0; py <= y1; ++py)
                for (std::ptrdiff_t px = x0; px <= x1; ++px) {
                    const float w = target.filter(c.raster.x - (static_cast<float>(px) + 0.5f),
                                                  c.raster.y - (static_cast<float>(py) + 0.5f));
                    const auto pixel = static_cast<std::size_t>(py * width + px);
                    if (w != 0.0f) acc.pixels[pixel] += weighted * (w / target.normaliser[pixel]);
                }
            if (c.strategy >= 0) {
                const auto px = std::min<std::ptrdiff_t>(width - 1, static_cast<std::ptrdiff_t>(c.raster.x));
                const auto py = std::min<std::ptrdiff_t>(height - 1, static_cast<std::ptrdiff_t>(c.raster.y));
                acc.strategyPixels[static_cast<std::size_t>(c.strategy) * static_cast<std::size_t>(width * height) +
                                   static_cast<std::size_t>(py * width + px)] += strategyValue;
            }
        }
    }
}

class BdptPass final : public Pass {
public:
    void run(PassContext& ctx) override {
        const Scene& scene = ctx.scene();
        const PassParams& params = ctx.params();
        Settings settings;
        settings.spp = static_cast<int>(params.getInt("spp"));
        settings.maxDepth = static_cast<int>(params.getInt("max_depth"));
        settings.rrDepth = static_cast<int>(params.getInt("rr_depth"));
        settings.rrThreshold = static_cast<float>(params.getFloat("rr_threshold"));
        settings.heuristic = params.getString("heuristic") == "balance" ? MisHeuristic::Balance : MisHeuristic::Power;
        settings.strategyLength = static_cast<int>(params.getInt("strategy_aovs"));
        settings.weightedStrategies = params.getBool("strategy_weighted");
        settings.waveSize = static_cast<std::size_t>(params.getInt("wave_size"));

        const FilmSettings& filmSettings = ctx.filmSettings();
        const Camera camera = ctx.filmCamera();
        BdptScene guidedScene(scene, ctx.rays(), camera);
        if (ctx.hasInput("radiance_cache")) guidedScene.radianceCache = &ctx.input<GuidingCache>("radiance_cache");
        if (ctx.hasInput("importance_cache")) guidedScene.importanceCache = &ctx.input<GuidingCache>("importance_cache");
        if (guidedScene.radianceCache || guidedScene.importanceCache) {
            guidedScene.guidingBsdfProbability = static_cast<float>(params.getFloat("guiding_bsdf_probability"));
            guidedScene.guidingCandidates = static_cast<std::uint32_t>(params.getInt("guiding_candidates"));
            guidedScene.guidingCovering = params.getString("guiding_query") == "covering";
        }
        const BdptScene& bs = guidedScene;
        const StrategyTable table(settings.strategyLength);

        Film& film = ctx.createOutput<Film>("image", filmSettings);
        const std::size_t pixelCount = film.pixelCount();
        const auto spp = static_cast<std::size_t>(settings.spp);
        const int cameraMax = settings.maxDepth + 1;
        const int lightMax = settings.maxDepth;
        const std::uint64_t lightStream = jobs::splitmix64(ctx.streamKey() ^ 0x6c69676874706174ull);

        const std::vector<float> borderNormaliser = filterNormalisers(filmSettings);
        const PixelFilter filter(filmSettings);
        const SplatTarget splatTarget{filmSettings, filter, borderNormaliser, table.size(), settings.weightedStrategies};
        const std::size_t imageBytes = std::max<std::size_t>(1, pixelCount * sizeof(Rgb) * (1 + table.size()));
        blocks_.assign(std::clamp<std::size_t>(kAccumulatorBudget / imageBytes, 1, kMaxBlocks), SplatBlock{});

        std::vector<std::vector<Rgb>> strategyCamera(table.size(), std::vector<Rgb>(pixelCount, Rgb(0.0f)));

        const std::size_t passSamples = std::clamp<std::size_t>(settings.waveSize / pixelCount, 1, spp);
        const std::size_t pixelsPerWave = std::max<std::size_t>(1, settings.waveSize / passSamples);
        SampleBuffer samples;
        VertexBuffer cameraVertices, lightVertices;
        std::vector<Rgb> sampleStrategies;
        std::int64_t totalCameraVertices = 0, totalLightVertices = 0;
        std::size_t samplesDone = 0;  // per pixel, over the completed sample passes
        for (std::size_t passStart = 0; passStart < spp; passStart += passSamples) {
            const std::size_t samplesPerPixel = std::min(passSamples, spp - passStart);
            for (std::size_t firstPixel = 0; firstPixel < pixelCount; firstPixel += pixelsPerWave) {
                const std::size_t pixels = std::min(pixelsPerWave, pixelCount - firstPixel);
                const std::size_t count = pixels * samplesPerPixel;
                samples.resize(count);
                cameraVertices.resize(count * static_cast<std::size_t>(cameraMax));
                lightVertices.resize(count * static_cast<std::size_t>(lightMax));
                sampleStrategies.assign(count * table.size(), Rgb(0.0f));
                auto raster = samples.column<SampleRaster>();
                auto radiance = samples.column<SampleRadiance>();
                auto cameraLength = samples.column<SampleCameraLength>();
                auto lightLength = samples.column<SampleLightLength>();
                auto rngs = samples.column<SampleRng>();
                auto camVerts = cameraVertices.column<SubpathVertex>();
                auto lightVerts = lightVertices.column<SubpathVertex>();
                const auto sampleKey = [&](std::size_t i) {
                    const std::uint64_t pixel = firstPixel + i / samplesPerPixel;
                    return pixel * spp + passStart + i % samplesPerPixel;
                };

                // Stage: camera subpaths.
                jobs::parallelForChunks(count, 256, [&](jobs::IndexRange r) {
                    for (std::size_t i = r.begin; i != r.end; ++i) {
                        const auto pixel = static_cast<std::uint32_t>(firstPixel + i / samplesPerPixel);
                        rngs[i] = jobs::Rng(ctx.seed(), ctx.streamKey(), sampleKey(i));
                        const Vec2 jitter = rngs[i].uniform2();
                        raster[i] = Vec2(static_cast<float>(pixel % static_cast<std::uint32_t>(camera.width)),
                                         static_cast<float>(pixel / static_cast<std::uint32_t>(camera.width))) + jitter;
                        radiance[i] = Rgb(0.0f);
                        BdptVertex* path = &camVerts[i * static_cast<std::size_t>(cameraMax)];
                        path[0] = BdptVertex{};
                        path[0].kind = BdptVertexKind::Camera;
                        path[0].p = camera.eye;
                        path[0].beta = Rgb(1.0f);
                        path[0].medium = camera.medium;
                        path[0].pdfFwd = 1.0f;
                        const Ray ray = camera.generateRay(raster[i]);
                        cameraLength[i] = static_cast<std::uint16_t>(randomWalk(
                            bs, ray, Rgb(1.0f), 0.0f, camera.medium, TransportMode::Radiance, cameraMax,
                            settings.rrDepth, settings.rrThreshold, rngs[i], path));
                    }
                });

                // Stage: light subpaths.
                jobs::parallelForChunks(count, 256, [&](jobs::IndexRange r) {
                    for (std::size_t i = r.begin; i != r.end; ++i) {
                        jobs::Rng rng(ctx.seed(), lightStream, sampleKey(i));
                        lightLength[i] = static_cast<std::uint16_t>(
                            traceLightSubpath(bs, settings, lightMax, rng, &lightVerts[i * static_cast<std::size_t>(lightMax)]));
                    }
                });

                // Stage: connections, per fixed block of samples (the splat accumulators' unit).
                jobs::parallelForBlocks(count, blocks_.size(), [&](std::size_t block, jobs::IndexRange r) {
                    SplatBlock& acc = blocks_[block];
                    if (acc.pixels.empty()) {
                        acc.pixels.assign(pixelCount, Rgb(0.0f));
                        acc.strategyPixels.assign(pixelCount * table.size(), Rgb(0.0f));
                    }
                    std::vector<PendingConnection> pending;
                    for (std::size_t group = r.begin; group < r.end; group += kConnectGroup) {
                        const std::size_t groupEnd = std::min(r.end, group + kConnectGroup);
                        pending.clear();
                        for (std::size_t i = group; i != groupEnd; ++i) {
                            const std::span<const BdptVertex> cam(&camVerts[i * static_cast<std::size_t>(cameraMax)],
                                                                  cameraLength[i]);
                            const std::span<const BdptVertex> light(&lightVerts[i * static_cast<std::size_t>(lightMax)],
                                                                    lightLength[i]);
                            connectSample(bs, settings, table, static_cast<std::uint32_t>(i), cam, light, rngs[i],
                                          radiance[i], &sampleStrategies[i * table.size()], pending);
                        }
                        resolveConnections(bs, splatTarget, pending, radiance, sampleStrategies, acc);
                    }
                });

                for (Rgb& L : radiance)
                    if (!isFinite(L)) L = Rgb(0.0f);
                film.addRound({firstPixel, pixels, static_cast<int>(samplesPerPixel), raster, radiance});
                for (std::size_t k = 0; k < table.size(); ++k)
                    for (std::size_t px = 0; px < pixels; ++px)
                        for (std::size_t s = 0; s < samplesPerPixel; ++s) {
                            const Rgb& value = sampleStrategies[(px * samplesPerPixel + s) * table.size() + k];
                            if (isFinite(value)) strategyCamera[k][firstPixel + px] += value;
                        }
                for (std::size_t i = 0; i < count; ++i) {
                    totalCameraVertices += cameraLength[i];
                    totalLightVertices += lightLength[i];
                }
                ctx.addItems(static_cast<std::int64_t>(count));
                ctx.reportProgress((static_cast<double>(passStart) * static_cast<double>(pixelCount) +
                                    static_cast<double>((firstPixel + pixels) * samplesPerPixel)) /
                                   (static_cast<double>(pixelCount) * static_cast<double>(spp)));
            }
            ctx.completedUnit();
            samplesDone = passStart + samplesPerPixel;
            if (samplesDone < spp && ctx.stopRequested()) {
                ctx.keptPartial(ctx.instanceName() + ": " + std::to_string(samplesDone) + " of " + std::to_string(spp) +
                                " samples per pixel");
                break;
            }
        }

        // Merge the light image in block order.
        std::vector<Rgb> lightImage(pixelCount, Rgb(0.0f));
        std::vector<Rgb> strategyLight(pixelCount * table.size(), Rgb(0.0f));
        std::int64_t connections = 0;
        for (const SplatBlock& block : blocks_) {
            if (block.pixels.empty()) continue;
            for (std::size_t p = 0; p < pixelCount; ++p) lightImage[p] += block.pixels[p];
            for (std::size_t k = 0; k < strategyLight.size(); ++k) strategyLight[k] += block.strategyPixels[k];
            connections += block.connections;
        }
        // One light path per camera sample; an interrupt leaves fewer than planned.
        const double lightPaths = static_cast<double>(pixelCount) * static_cast<double>(std::max<std::size_t>(samplesDone, 1));
        film.addToPixels(lightImage, static_cast<float>(1.0 / lightPaths));
        for (std::size_t k = 0; k < table.size(); ++k) {
            const auto [s, t] = table.strategies[k];
            const std::string name = "s" + std::to_string(s) + "t" + std::to_string(t);
            std::array<std::vector<float>*, 3> channels{&film.aov(name + ".R"), &film.aov(name + ".G"),
                                                        &film.aov(name + ".B")};
            for (std::size_t p = 0; p < pixelCount; ++p) {
                const Rgb value = strategyCamera[k][p] / static_cast<float>(std::max<std::size_t>(samplesDone, 1)) +
                                  strategyLight[k * pixelCount + p] / static_cast<float>(lightPaths);
                for (int c = 0; c < 3; ++c) (*channels[static_cast<std::size_t>(c)])[p] = value[c];
            }
        }
        ctx.addCounter("camera_vertices", totalCameraVertices);
        ctx.addCounter("light_vertices", totalLightVertices);
        ctx.addCounter("unoccluded_connections", connections);
    }

private:
    static int traceLightSubpath(const BdptScene& bs, const Settings& settings, int lightMax, jobs::Rng& rng,
                                 BdptVertex* path) {
        const Scene& scene = bs.scene;
        if (scene.lights.empty() || lightMax < 1) return 0;
        const float uLight = rng.uniform();
        const Vec2 uPosition = rng.uniform2();
        const Vec2 uDirection = rng.uniform2();
        float pmf = 0.0f;
        const std::size_t index = scene.lightPower.sampleDiscrete(uLight, &pmf);
        if (!(pmf > 0.0f)) return 0;
        const std::optional<EmissionSample> emission = scene.lights[index]->sampleEmission(uPosition, uDirection);
        if (!emission || isBlack(emission->flux) || !(emission->pdfPosition > 0.0f) || !(emission->pdfDirection > 0.0f))
            return 0;
        const BdptLightInfo& info = bs.lights[index];
        BdptVertex& origin = path[0];
        origin = BdptVertex{};
        origin.kind = BdptVertexKind::Light;
        origin.light = static_cast<int>(index);
        const bool atInfinity = info.kind == BdptLightInfo::Kind::Directional || info.kind == BdptLightInfo::Kind::Environment;
        origin.infinite = atInfinity;
        origin.p = atInfinity ? -emission->direction : emission->origin;
        origin.ng = atInfinity ? Vec3(0.0f) : emission->normal;
        origin.beta = emission->flux;
        origin.pdfFwd = bdptPdfLightOrigin(bs, origin);
        int medium = info.medium;
        if (medium == kMediumBySide) {
            const Shape& shape = scene.shapes[static_cast<std::size_t>(scene.lightShape[index])];
            medium = mediumAfterCrossing(shape, emission->normal, emission->direction, -1);
        }
        origin.medium = medium;
        Ray ray;
        ray.origin = origin.ng != Vec3(0.0f) ? offsetRayOrigin(emission->origin, emission->normal, emission->direction)
                                            : emission->origin;
        ray.direction = emission->direction;
        ray.tMax = kInfinity;
        return randomWalk(bs, ray, emission->flux / pmf, emission->pdfDirection, medium, TransportMode::Importance,
                          lightMax, settings.rrDepth, settings.rrThreshold, rng, path);
    }

    // Every strategy (s, t) of one sample: s = 0 is added at once, the others
    // queue a shadow ray with their unoccluded weighted contribution.
    static void connectSample(const BdptScene& bs, const Settings& settings, const StrategyTable& table,
                              std::uint32_t sample, std::span<const BdptVertex> cam, std::span<const BdptVertex> light,
                              jobs::Rng& rng, Rgb& radiance, Rgb* strategies, std::vector<PendingConnection>& pending) {
        const Scene& scene = bs.scene;
        const int nCam = static_cast<int>(cam.size());
        const int nLight = static_cast<int>(light.size());
        const auto record = [&](int s, int t, const Rgb& weighted, const Rgb& unweighted) {
            const int k = table.index(s, t);
            if (k >= 0) strategies[k] += settings.weightedStrategies ? weighted : unweighted;
        };
        for (int t = 1; t <= nCam; ++t) {
            for (int s = 0; s <= nLight; ++s) {
                if (s + t < 2 || s + t - 1 > settings.maxDepth) continue;
                const BdptVertex& pt = cam[static_cast<std::size_t>(t - 1)];
                if (s == 0) {
                    // The camera subpath ends on a light.
                    if (pt.kind == BdptVertexKind::Light && pt.infinite) {
                        for (int index : bs.infiniteLights) {
                            const Rgb Le = scene.lights[static_cast<std::size_t>(index)]->environment(pt.p);
                            if (isBlack(Le)) continue;
                            BdptVertex emitter = pt;
                            emitter.light = index;
                            const Rgb value = pt.beta * Le;
                            const float w = bdptMisWeight(bs, {}, cam.first(static_cast<std::size_t>(t)), &emitter, 0, t,
                                                          settings.heuristic);
                            radiance += value * w;
                            record(0, t, value * w, value);
                        }
                    } else if (pt.kind == BdptVertexKind::Surface && pt.light >= 0) {
                        const Rgb Le = scene.lights[static_cast<std::size_t>(pt.light)]->emittedAt(pt.ng, pt.wo, pt.at.uv);
                        if (isBlack(Le)) continue;
                        const Rgb value = pt.beta * Le;
                        const float w = bdptMisWeight(bs, {}, cam.first(static_cast<std::size_t>(t)), nullptr, 0, t,
                                                      settings.heuristic);
                        radiance += value * w;
                        record(0, t, value * w, value);
                    }
                    continue;
                }
                if (pt.infinite || !bdptConnectible(bs, pt)) continue;
                if (t == 1) {
                    connectToCamera(bs, settings, table, sample, light, s, rng, pending);
                    continue;
                }
                if (s == 1) {
                    nextEvent(bs, settings, sample, cam.first(static_cast<std::size_t>(t)), light, rng, table, pending);
                    continue;
                }
                const BdptVertex& qs = light[static_cast<std::size_t>(s - 1)];
                if (!bdptConnectible(bs, qs)) continue;
                const Vec3 toLight = qs.p - pt.p;
                const float distance2 = glm::dot(toLight, toLight);
                if (!(distance2 > 0.0f)) continue;
                const Vec3 dir = toLight / std::sqrt(distance2);
                const Rgb value = pt.beta * bdptScatter(bs, pt, dir, false) * bdptScatter(bs, qs, -dir, true) * qs.beta /
                                  distance2;
                if (isBlack(value) || !isFinite(value)) continue;
                const BdptWeightTerms w = bdptMisTerms(bs, light.first(static_cast<std::size_t>(s)),
                                              cam.first(static_cast<std::size_t>(t)), nullptr, s, t, settings.heuristic);
                PendingConnection c;
                c.ray = connectionRay(bs, pt, qs);
                c.shortfall = rayShortfall(c.ray, qs);
                c.medium = mediumTowards(bs, pt, dir);
                c.value = value;
                c.weight = w;
                c.sample = sample;
                c.strategy = table.index(s, t);
                pending.push_back(c);
            }
        }
    }

    // s = 1: a light point sampled from z_{t-1} as the path tracer's next-event estimation does.
    static void nextEvent(const BdptScene& bs, const Settings& settings, std::uint32_t sample,
                          std::span<const BdptVertex> cam, std::span<const BdptVertex> light, jobs::Rng& rng,
                          const StrategyTable& table, std::vector<PendingConnection>& pending) {
        const Scene& scene = bs.scene;
        const BdptVertex& pt = cam.back();
        const float uLight = rng.uniform();
        const Vec2 uPoint = rng.uniform2();
        if (scene.lights.empty()) return;
        float pmf = 0.0f;
        const std::size_t index = scene.lightPower.sampleDiscrete(uLight, &pmf);
        if (!(pmf > 0.0f)) return;
        const std::optional<LightSample> ls = scene.lights[index]->sampleLi(pt.p, uPoint);
        if (!ls || !(ls->pdf > 0.0f) || isBlack(ls->value)) return;
        const Rgb f = bdptScatter(bs, pt, ls->wi, false);
        if (isBlack(f)) return;
        BdptVertex sampled;
        sampled.kind = BdptVertexKind::Light;
        sampled.light = static_cast<int>(index);
        const bool atInfinity = std::isinf(ls->distance) || ls->distance >= kInfinity;
        sampled.infinite = atInfinity;
        sampled.p = atInfinity ? ls->wi : ls->p;
        sampled.ng = atInfinity ? Vec3(0.0f) : ls->n;
        sampled.pdfFwd = bdptPdfLightOrigin(bs, sampled);
        const Rgb value = pt.beta * f * ls->value / (ls->pdf * pmf);
        if (!isFinite(value)) return;
        const BdptWeightTerms w = bdptMisTerms(bs, light, cam, &sampled, 1, static_cast<int>(cam.size()), settings.heuristic);
        PendingConnection c;
        c.ray = connectionRay(bs, pt, sampled);
        c.shortfall = rayShortfall(c.ray, sampled);
        c.medium = mediumTowards(bs, pt, ls->wi);
        c.value = value;
        c.weight = w;
        c.sample = sample;
        c.strategy = table.index(1, static_cast<int>(cam.size()));
        pending.push_back(c);
    }

    // t = 1: light vertex y_{s-1} seen by the pinhole, splatted at its raster position.
    static void connectToCamera(const BdptScene& bs, const Settings& settings, const StrategyTable& table,
                                std::uint32_t sample, std::span<const BdptVertex> light, int s, jobs::Rng& rng,
                                std::vector<PendingConnection>& pending) {
        const Scene& scene = bs.scene;
        BdptVertex eye;
        eye.kind = BdptVertexKind::Camera;
        eye.p = bs.view.eye;
        eye.medium = bs.view.medium;
        eye.beta = Rgb(1.0f);
        eye.pdfFwd = 1.0f;
        Rgb value;
        BdptVertex sampled;
        const BdptVertex* qs = nullptr;
        if (s == 1) {
            // The light seen directly: a point sampled on it from the eye.
            const float uLight = rng.uniform();
            const Vec2 uPoint = rng.uniform2();
            float pmf = 0.0f;
            const std::size_t index = scene.lightPower.sampleDiscrete(uLight, &pmf);
            // A point source seen directly is a Dirac in the image, which a pixel's
            // radiance (and pt) never holds.
            if (!(pmf > 0.0f) || scene.lights[index]->isDelta()) return;
            const std::optional<LightSample> ls = scene.lights[index]->sampleLi(eye.p, uPoint);
            if (!ls || !(ls->pdf > 0.0f) || isBlack(ls->value)) return;
            const bool atInfinity = std::isinf(ls->distance) || ls->distance >= kInfinity;
            sampled.kind = BdptVertexKind::Light;
            sampled.light = static_cast<int>(index);
            sampled.infinite = atInfinity;
            sampled.p = atInfinity ? ls->wi : ls->p;
            sampled.ng = atInfinity ? Vec3(0.0f) : ls->n;
            sampled.pdfFwd = bdptPdfLightOrigin(bs, sampled);
            // Radiance over its solid-angle density, times d^2 so that the common factor below applies.
            value = ls->value / (ls->pdf * pmf) * (atInfinity ? 1.0f : glm::dot(ls->p - eye.p, ls->p - eye.p));
            qs = &sampled;
        } else {
            qs = &light[static_cast<std::size_t>(s - 1)];
            if (!bdptConnectible(bs, *qs)) return;
            const Vec3 dir = bdptDirection(*qs, eye);
            value = qs->beta * bdptScatter(bs, *qs, dir, true);
        }
        if (isBlack(value)) return;
        // Lights at infinity are seen along a direction: no distance falls off.
        const Vec3 toVertex = qs->infinite ? qs->p : qs->p - eye.p;
        const float distance2 = qs->infinite ? 1.0f : glm::dot(toVertex, toVertex);
        if (!(distance2 > 0.0f)) return;
        const float distance = std::sqrt(distance2);
        const Vec3 dir = toVertex / distance;
        const float cosCamera = glm::dot(dir, bs.view.forward);
        Vec2 raster;
        if (!(cosCamera > 0.0f) || !(bs.cameraDirectionPdf(dir, &raster) > 0.0f)) return;
        const float depth = distance * cosCamera;
        if (!qs->infinite && (depth < bs.view.nearClip || depth > bs.view.farClip)) return;
        value *= bs.view.rasterPerImagePlane / (distance2 * cosCamera * cosCamera * cosCamera);
        if (!isFinite(value) || isBlack(value)) return;
        std::array<BdptVertex, 1> eyePath{eye};
        const BdptWeightTerms w = s == 1 ? bdptMisTerms(bs, light, eyePath, &sampled, 1, 1, settings.heuristic)
                               : bdptMisTerms(bs, light.first(static_cast<std::size_t>(s)), eyePath, nullptr, s, 1,
                                               settings.heuristic);
        PendingConnection c;
        c.ray = connectionRay(bs, eye, *qs);
        c.shortfall = rayShortfall(c.ray, *qs);
        c.medium = bs.view.medium;
        c.value = value;
        c.weight = w;
        c.raster = raster;
        c.sample = sample;
        c.splat = true;
        c.strategy = table.index(s, 1);
        pending.push_back(c);
    }

    std::vector<SplatBlock> blocks_;
};

}  // namespace

PassRegistration bdptPass() {
    PassSpec spec;
    spec.name = "bdpt";
    spec.doc = "Bidirectional path tracer: camera and light subpaths through surfaces and homogeneous media, every "
               "connection strategy combined by MIS";
    SlotSpec radianceCache{"radiance_cache", "GuidingCache", "directional GMMs of incident radiance that guide camera subpaths"};
    radianceCache.optional = true;
    SlotSpec importanceCache{"importance_cache", "GuidingCache", "directional GMMs of incident importance that guide light subpaths"};
    importanceCache.optional = true;
    spec.inputs = {radianceCache, importanceCache};
    spec.outputs = {{"image", "Film", "radiance estimate per pixel; per-strategy AOVs sStT.R/G/B when strategy_aovs > 0"}};
    spec.params = {
        {"spp", ParamType::Int, std::int64_t{16}, 1, 1 << 20, {}, "samples (camera and light subpath pairs) per pixel",
         "sample_count"},
        {"max_depth", ParamType::Int, std::int64_t{17}, 1, kMaxDepthLimit, {},
         "longest path in segments, Mitsuba's convention: 1 = emitters seen directly, 2 = direct light "
         "(pt's max_depth + 1)"},
        {"rr_depth", ParamType::Int, std::int64_t{5}, 1, 4096, {},
         "scattering events on a subpath before Russian roulette may end it"},
        rouletteThresholdParam("subpath"),
        {"heuristic", ParamType::String, std::string("power"), 0, 0, {"power", "balance"},
         "MIS heuristic combining the strategies (Veach 1997 §9.2)"},
        {"strategy_aovs", ParamType::Int, std::int64_t{0}, 0, 6, {},
         "write each strategy (s, t) of paths up to this many segments as AOVs sStT.R/G/B (box-filtered)"},
        {"strategy_weighted", ParamType::Bool, true, 0, 0, {},
         "the strategy AOVs hold MIS-weighted contributions (they sum to the image); false: unweighted"},
        {"wave_size", ParamType::Int, std::int64_t{1 << 14}, 1, 1 << 22, {},
         "camera samples in flight per wave (memory: about 2 max_depth vertices of 96 bytes each)"},
    };
    const std::vector<ParamSpec> guidedParams = guidedSamplingParams();
    spec.params.insert(spec.params.end(), guidedParams.begin(), guidedParams.end());
    const auto preflight = [](const PreflightContext& pf) {
        if (pf.scene.camera.orthographic) {
            throw InputError("pass '" + pf.instance + "': " + pf.scene.sourcePath +
                             " has an orthographic camera, which light subpaths cannot connect to; render it with pt");
        }
    };
    // The film with its strategy AOVs, one wave of subpaths, and the light-image accumulators.
    const auto memory = [](const PreflightContext& pf) {
        const auto maxDepth = static_cast<std::uint64_t>(pf.params.getInt("max_depth"));
        const auto strategyLength = static_cast<std::uint64_t>(pf.params.getInt("strategy_aovs"));
        const std::uint64_t strategies = strategyLength * (strategyLength + 3) / 2;
        const std::uint64_t pixels = static_cast<std::uint64_t>(pf.film.width) * static_cast<std::uint64_t>(pf.film.height);
        const std::uint64_t wave = std::min(multiplyBytes(pixels, static_cast<std::uint64_t>(pf.params.getInt("spp"))),
                                            static_cast<std::uint64_t>(pf.params.getInt("wave_size")));
        const std::uint64_t perSample = (2 * maxDepth + 1) * sizeof(BdptVertex) + sizeof(Vec2) + sizeof(Rgb) +
                                        2 * sizeof(std::uint16_t) + sizeof(jobs::Rng) + strategies * sizeof(Rgb);
        const std::uint64_t image = multiplyBytes(pixels, sizeof(Rgb) * (1 + strategies));
        const std::uint64_t blocks = std::clamp<std::uint64_t>(kAccumulatorBudget / std::max<std::uint64_t>(image, 1), 1, kMaxBlocks);
        MemoryEstimate estimate;
        estimate.bytes = addBytes(addBytes(filmBytes(pf.film, static_cast<int>(3 * strategies)), multiplyBytes(wave, perSample)),
                                  multiplyBytes(image, blocks + 2));
        estimate.what = "film " + std::to_string(pf.film.width) + " x " + std::to_string(pf.film.height) + ", " +
                        std::to_string(wave) + " subpath pairs in flight and " + std::to_string(blocks) +
                        " light-image accumulators";
        return estimate;
    };
    return {spec, [] { return std::make_unique<BdptPass>(); }, preflight, memory};
}

}  // namespace fg
