// Reference path tracer (`pt`): unidirectional path tracing with next-event
// estimation and multiple importance sampling (power heuristic, Veach 1997
// §9.2), Russian roulette, and homogeneous participating media (chromatic
// free-flight sampling with spectral MIS, HG phase function, shadow rays that
// pass through index-matched `null` boundaries accumulating transmittance;
// thindielectric's straight-through transmission is a null event too, as in
// Mitsuba 3). It is the ground truth for every other pipeline.
//
// Two schedules share the same per-vertex code (path_vertex.h):
//  - wavefront (default): paths of a wave live in SoA columns and advance stage
//    by stage (intersect stream -> shade -> shadow stream -> compact), as in
//    pbrt-v4's wavefront integrator;
//  - tile: each pixel's samples are traced to completion one after another.
// Both consume the same random numbers per path, keyed by (seed, instance, sample
// index), so they produce the same image up to floating-point order in the
// film (identical here: the film gathers in a fixed order).
#include "passes/common/path_vertex.h"
#include "passes/passes.h"

#include "engine/core/error.h"
#include "engine/guiding/guiding_cache.h"

#include "engine/image/film.h"
#include "engine/accel/ray_query.h"
#include "engine/scene/scene.h"
#include "engine/core/soa.h"
#include "jobs/parallel.h"
#include "jobs/random.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <cstdint>

namespace fg {

namespace {

FG_SOA_COLUMN(PathRay, Ray, "ray");
FG_SOA_COLUMN(PathHit, Hit, "hit");
FG_SOA_COLUMN(PathThroughput, Rgb, "throughput");
FG_SOA_COLUMN(PathRadiance, Rgb, "radiance");
FG_SOA_COLUMN(PathPrevious, PathHistory, "history");
FG_SOA_COLUMN(PathRng, jobs::Rng, "rng");
FG_SOA_COLUMN(PathShadow, ShadowRequest, "shadow");
FG_SOA_COLUMN(PathRaster, Vec2, "raster");
FG_SOA_COLUMN(PathTimeNs, float, "time_ns");

using PathBuffer = SoaBuffer<PathRay, PathHit, PathThroughput, PathRadiance, PathPrevious, PathRng, PathShadow,
                             PathRaster, PathTimeNs>;

constexpr std::size_t kGrain = 256;

struct Settings {
    int spp = 16;
    PathLimits limits;
    std::size_t waveSize = 1 << 18;
    bool wavefront = true;
};

// Books a chunk's wall time evenly to the paths it processed (the per-pixel time AOV).
class ChunkClock {
public:
    explicit ChunkClock(std::span<float> timeNs, std::span<const std::uint32_t> paths)
        : timeNs_(timeNs), paths_(paths), start_(jobs::wallNanos()) {}
    ~ChunkClock() {
        const float share = static_cast<float>(jobs::wallNanos() - start_) / static_cast<float>(paths_.size());
        for (std::uint32_t p : paths_) timeNs_[p] += share;
    }

private:
    std::span<float> timeNs_;
    std::span<const std::uint32_t> paths_;
    std::int64_t start_;
};

// Samples [firstSample, firstSample + samples) of each pixel in [firstPixel,
// firstPixel + pixels), stored pixel by pixel. Sample s of pixel p draws from
// the stream keyed by p * spp + s whatever the grouping, so a pixel's samples
// are the same however the render is cut into waves and sample passes.
struct SampleRange {
    std::size_t firstPixel = 0;
    std::size_t pixels = 0;
    std::uint64_t firstSample = 0;
    std::size_t samples = 1;
    std::size_t count() const { return pixels * samples; }
    std::uint32_t pixel(std::size_t i) const { return static_cast<std::uint32_t>(firstPixel + i / samples); }
    std::uint64_t key(std::size_t i, std::uint64_t spp) const {
        return static_cast<std::uint64_t>(pixel(i)) * spp + firstSample + i % samples;
    }
};

// Traces the samples of `range` in SoA stages.
// Returns the number of path segments traced (closest-hit queries).
std::int64_t traceWave(const PathTracerScene& pts, const Camera& camera, std::uint64_t seed, std::uint64_t stream,
                       const Settings& settings, const SampleRange& range, PathBuffer& paths) {
    std::int64_t segments = 0;
    const std::size_t count = range.count();
    paths.resize(count);
    auto rays = paths.column<PathRay>();
    auto hits = paths.column<PathHit>();
    auto throughput = paths.column<PathThroughput>();
    auto radiance = paths.column<PathRadiance>();
    auto history = paths.column<PathPrevious>();
    auto rngs = paths.column<PathRng>();
    auto shadows = paths.column<PathShadow>();
    auto raster = paths.column<PathRaster>();
    auto timeNs = paths.column<PathTimeNs>();

    std::vector<std::uint32_t> active(count);
    for (std::size_t i = 0; i < count; ++i) active[i] = static_cast<std::uint32_t>(i);

    // Stage: camera rays.
    jobs::parallelForChunks(count, kGrain, [&](jobs::IndexRange r) {
        ChunkClock clock(timeNs, std::span<const std::uint32_t>(active).subspan(r.begin, r.size()));
        for (std::size_t i = r.begin; i != r.end; ++i) {
            const std::uint32_t pixel = range.pixel(i);
            rngs[i] = jobs::Rng(seed, stream, range.key(i, static_cast<std::uint64_t>(settings.spp)));
            const Vec2 jitter = rngs[i].uniform2();
            raster[i] = Vec2(static_cast<float>(pixel % static_cast<std::uint32_t>(camera.width)),
                             static_cast<float>(pixel / static_cast<std::uint32_t>(camera.width))) + jitter;
            rays[i] = camera.generateRay(raster[i]);
            throughput[i] = Rgb(1.0f);
            radiance[i] = Rgb(0.0f);
            history[i] = PathHistory::atCamera(camera.medium);
            timeNs[i] = 0.0f;
        }
    });

    std::vector<std::uint8_t> alive(count);
    while (!active.empty()) {
        segments += static_cast<std::int64_t>(active.size());
        // Stage: closest hits for all live paths, as ray streams.
        jobs::parallelForChunks(active.size(), kGrain, [&](jobs::IndexRange r) {
            const auto ids = std::span<const std::uint32_t>(active).subspan(r.begin, r.size());
            ChunkClock clock(timeNs, ids);
            std::array<Ray, kGrain> streamRays;
            std::array<Hit, kGrain> streamHits;
            for (std::size_t k = 0; k < ids.size(); ++k) streamRays[k] = rays[ids[k]];
            pts.rays.intersect(std::span<const Ray>(streamRays.data(), ids.size()),
                               std::span<Hit>(streamHits.data(), ids.size()));
            for (std::size_t k = 0; k < ids.size(); ++k) hits[ids[k]] = streamHits[k];
        });

        // Stage: shading (emission, medium events, light sampling, next direction).
        jobs::parallelForChunks(active.size(), kGrain, [&](jobs::IndexRange r) {
            const auto ids = std::span<const std::uint32_t>(active).subspan(r.begin, r.size());
            ChunkClock clock(timeNs, ids);
            for (std::uint32_t p : ids) {
                PathVertexState state{rays[p], throughput[p], radiance[p], history[p], rngs[p]};
                shadows[p] = ShadowRequest{};
                alive[p] = advancePath(pts, settings.limits, hits[p], state, shadows[p]) ? 1 : 0;
            }
        });

        // Stage: shadow rays (transmittance through null boundaries and media).
        jobs::parallelForChunks(active.size(), kGrain, [&](jobs::IndexRange r) {
            const auto ids = std::span<const std::uint32_t>(active).subspan(r.begin, r.size());
            ChunkClock clock(timeNs, ids);
            resolveShadowRays(pts, ids, shadows, radiance);
        });

        // Compaction keeps the order of paths, so nothing depends on scheduling.
        std::erase_if(active, [&](std::uint32_t p) { return alive[p] == 0; });
    }
    return segments;
}

std::int64_t traceTile(const PathTracerScene& pts, const Camera& camera, std::uint64_t seed, std::uint64_t stream,
                       const Settings& settings, const SampleRange& range, PathBuffer& paths) {
    std::atomic<std::int64_t> segments{0};
    paths.resize(range.count());
    auto radiance = paths.column<PathRadiance>();
    auto raster = paths.column<PathRaster>();
    auto timeNs = paths.column<PathTimeNs>();
    const std::size_t samples = range.samples;
    // One chunk = whole pixels, so each pixel's samples run back to back.
    const std::size_t pixelGrain = std::max<std::size_t>(1, kGrain / samples);
    jobs::parallelForChunks(range.pixels, pixelGrain, [&](jobs::IndexRange pixels) {
        std::int64_t chunkSegments = 0;
        for (std::size_t localPixel = pixels.begin; localPixel != pixels.end; ++localPixel) {
            const std::int64_t start = jobs::wallNanos();
            for (std::size_t s = 0; s < samples; ++s) {
                const std::size_t i = localPixel * samples + s;
                const std::uint32_t pixel = range.pixel(i);
                jobs::Rng rng(seed, stream, range.key(i, static_cast<std::uint64_t>(settings.spp)));
                const Vec2 jitter = rng.uniform2();
                raster[i] = Vec2(static_cast<float>(pixel % static_cast<std::uint32_t>(camera.width)),
                                 static_cast<float>(pixel / static_cast<std::uint32_t>(camera.width))) + jitter;
                Ray ray = camera.generateRay(raster[i]);
                Rgb beta(1.0f), L(0.0f);
                PathHistory hist = PathHistory::atCamera(camera.medium);
                PathVertexState state{ray, beta, L, hist, rng};
                bool pathAlive = true;
                while (pathAlive) {
                    const Hit hit = pts.rays.intersect(state.ray);
                    ++chunkSegments;
                    ShadowRequest shadow;
                    pathAlive = advancePath(pts, settings.limits, hit, state, shadow);
                    if (shadow.pending) L += shadow.contribution * shadowTransmittance(pts, shadow);
                }
                radiance[i] = L;
            }
            const float perSample = static_cast<float>(jobs::wallNanos() - start) / static_cast<float>(samples);
            for (std::size_t s = 0; s < samples; ++s) timeNs[localPixel * samples + s] = perSample;
        }
        segments += chunkSegments;
    });
    return segments.load();
}

class PathTracerPass final : public Pass {
public:
    void run(PassContext& ctx) override {
        const Scene& scene = ctx.scene();
        const PassParams& params = ctx.params();
        Settings settings;
        settings.spp = static_cast<int>(params.getInt("spp"));
        settings.limits.maxDepth = static_cast<int>(params.getInt("max_depth"));
        settings.limits.rrDepth = static_cast<int>(params.getInt("rr_depth"));
        settings.waveSize = static_cast<std::size_t>(params.getInt("wave_size"));
        settings.wavefront = params.getString("schedule") == "wavefront";

        Camera camera = scene.camera;
        camera.width = ctx.filmSettings().width;
        camera.height = ctx.filmSettings().height;
        PathTracerScene pts(scene, ctx.rays());
        const std::string& guiding = params.getString("guiding");
        if (guiding == "gmm" || (guiding == "auto" && ctx.hasInput("radiance_cache"))) {
            if (!ctx.hasInput("radiance_cache"))
                throw InputError("pass '" + ctx.instanceName() + "': guiding = \"gmm\" needs a radiance_cache input");
            pts.guiding = &ctx.input<GuidingCache>("radiance_cache");
            pts.guidingBsdfProbability = static_cast<float>(params.getFloat("guiding_bsdf_probability"));
        }

        // Progressive rendering: the samples add to an earlier film's sums, so the
        // output is the average over all samples of both.
        if (ctx.hasInput("accumulate")) {
            const FilmSettings& earlier = ctx.input<Film>("accumulate").settings();
            if (earlier.width != ctx.filmSettings().width || earlier.height != ctx.filmSettings().height)
                throw InputError("pass '" + ctx.instanceName() + "': the film to accumulate onto is " +
                                 std::to_string(earlier.width) + " x " + std::to_string(earlier.height) +
                                 ", the job's film " + std::to_string(ctx.filmSettings().width) + " x " +
                                 std::to_string(ctx.filmSettings().height));
        }
        Film& film = ctx.hasInput("accumulate") ? ctx.createOutput<Film>("image", ctx.input<Film>("accumulate"))
                                                : ctx.createOutput<Film>("image", ctx.filmSettings());
        film.aov("time_ns");  // create both channels before holding references into them
        film.aov("samples");
        std::vector<float>& timeAov = film.aov("time_ns");
        std::vector<float>& sampleAov = film.aov("samples");
        const std::size_t pixelCount = film.pixelCount();
        const auto spp = static_cast<std::size_t>(settings.spp);
        // Sample passes: each gives every pixel the same number of further
        // samples, so the film after any of them is a complete (if noisier)
        // image, normalised by its weights; they are the units an interrupt
        // stops at. A pass is about one wave (all samples at once when the
        // whole image fits in a wave, as small renders do).
        const std::size_t passSamples = std::clamp<std::size_t>(settings.waveSize / pixelCount, 1, spp);
        // Waves hold whole pixels so that each film round has every sample of its pixels in the pass.
        const std::size_t pixelsPerWave = std::max<std::size_t>(1, settings.waveSize / passSamples);

        PathBuffer paths;
        for (std::size_t passStart = 0; passStart < spp; passStart += passSamples) {
            const std::size_t samples = std::min(passSamples, spp - passStart);
            for (std::size_t firstPixel = 0; firstPixel < pixelCount; firstPixel += pixelsPerWave) {
                const SampleRange range{firstPixel, std::min(pixelsPerWave, pixelCount - firstPixel), passStart, samples};
                const std::int64_t segments =
                    settings.wavefront ? traceWave(pts, camera, ctx.seed(), ctx.streamKey(), settings, range, paths)
                                       : traceTile(pts, camera, ctx.seed(), ctx.streamKey(), settings, range, paths);
                ctx.addCounter("path_segments", segments);
                // A non-finite sample would poison every pixel its filter reaches.
                for (Rgb& L : paths.column<PathRadiance>())
                    if (!isFinite(L)) L = Rgb(0.0f);
                film.addRound({firstPixel, range.pixels, static_cast<int>(samples), paths.column<PathRaster>(),
                               paths.column<PathRadiance>()});
                const auto times = paths.column<PathTimeNs>();
                for (std::size_t px = 0; px < range.pixels; ++px) {
                    float sum = 0.0f;
                    for (std::size_t s = 0; s < samples; ++s) sum += times[px * samples + s];
                    timeAov[firstPixel + px] += sum;
                    sampleAov[firstPixel + px] += static_cast<float>(samples);
                }
                ctx.addItems(static_cast<std::int64_t>(range.count()));
                ctx.reportProgress((static_cast<double>(passStart) * static_cast<double>(pixelCount) +
                                    static_cast<double>((firstPixel + range.pixels) * samples)) /
                                   (static_cast<double>(pixelCount) * static_cast<double>(spp)));
            }
            ctx.completedUnit();
            const std::size_t done = passStart + samples;
            if (done < spp && ctx.stopRequested()) {
                ctx.keptPartial(ctx.instanceName() + ": " + std::to_string(done) + " of " + std::to_string(spp) +
                                " samples per pixel");
                break;
            }
        }
    }
};

// The film (sums and the time_ns and samples AOVs) and one wave of paths.
MemoryEstimate pathTracerMemory(const PreflightContext& pf) {
    const auto spp = static_cast<std::uint64_t>(pf.params.getInt("spp"));
    const std::uint64_t pixels = static_cast<std::uint64_t>(pf.film.width) * static_cast<std::uint64_t>(pf.film.height);
    const std::uint64_t wave = std::min(multiplyBytes(pixels, spp), static_cast<std::uint64_t>(pf.params.getInt("wave_size")));
    constexpr std::uint64_t kBytesPerPath = sizeof(Ray) + sizeof(Hit) + 2 * sizeof(Rgb) + sizeof(PathHistory) +
                                            sizeof(jobs::Rng) + sizeof(ShadowRequest) + sizeof(Vec2) + sizeof(float) +
                                            sizeof(std::uint32_t) + sizeof(std::uint8_t);  // + active, alive
    MemoryEstimate estimate;
    estimate.bytes = addBytes(filmBytes(pf.film, 2), multiplyBytes(wave, kBytesPerPath));
    estimate.what = "film " + std::to_string(pf.film.width) + " x " + std::to_string(pf.film.height) + " and " +
                    std::to_string(wave) + " paths in flight";
    return estimate;
}

}  // namespace

PassRegistration pathTracerPass() {
    PassSpec spec;
    spec.name = "pt";
    spec.doc = "Reference unidirectional path tracer with NEE, MIS, Russian roulette and homogeneous media";
    SlotSpec accumulate{"accumulate", "Film",
                        "a film of earlier samples (same settings) the new samples are added to"};
    accumulate.optional = true;
    SlotSpec radianceCache{"radiance_cache", "GuidingCache", "directional GMMs of incident radiance (guiding = gmm)"};
    radianceCache.optional = true;
    spec.inputs = {accumulate, radianceCache};
    spec.outputs = {{"image", "Film", "radiance estimate per pixel, with time_ns and samples AOVs"}};
    spec.params = {
        {"spp", ParamType::Int, std::int64_t{16}, 1, 1 << 20, {}, "samples per pixel", "sample_count"},
        {"max_depth", ParamType::Int, std::int64_t{16}, 1, 4096, {},
         "maximum number of scattering events (surface or medium) per path; 1 = direct/single scattering "
         "(Mitsuba's max_depth - 1)",
         "max_depth"},
        {"rr_depth", ParamType::Int, std::int64_t{5}, 1, 4096, {},
         "scattering events before Russian roulette may end a path"},
        {"schedule", ParamType::String, std::string("wavefront"), 0, 0, {"wavefront", "tile"},
         "wavefront: SoA path queues advanced stage by stage; tile: each pixel's paths traced to completion"},
        {"wave_size", ParamType::Int, std::int64_t{1 << 18}, 1, 1 << 26, {},
         "paths in flight per wave (memory vs. parallelism)"},
        {"guiding", ParamType::String, std::string("auto"), 0, 0, {"auto", "none", "gmm"},
         "none: BSDF sampling; gmm: guided by the radiance_cache input (Vorba et al. 2014); auto: gmm when "
         "that input is bound"},
        {"guiding_bsdf_probability", ParamType::Float, 0.5, 0.01, 1.0, {},
         "alpha: probability of BSDF sampling at a guided vertex (the GMM otherwise)"},
    };
    return {spec, [] { return std::make_unique<PathTracerPass>(); }, {}, pathTracerMemory};
}

}  // namespace fg
