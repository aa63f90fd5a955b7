// Reference path tracer (`pt`): unidirectional path tracing with next-event
// estimation and multiple importance sampling (power heuristic, Veach 1997
// §9.2), Russian roulette, and homogeneous participating media (chromatic
// free-flight sampling with spectral MIS, HG phase function, shadow rays that
// pass through index-matched `null` boundaries accumulating transmittance;
// thindielectric's straight-through transmission is a null event too, as in
// Mitsuba 3). It is the ground truth for every other pipeline.
//
// Two schedules share the same per-vertex code (path_vertex.h):
//  - wavefront (default): paths live in SoA columns and advance stage by stage
//    (intersect stream -> shade -> shadow stream -> compact), as in pbrt-v4's
//    wavefront integrator, in streams of 256 paths that one task each carries to
//    the end, so that a stream stays in cache and a wave has a single barrier;
//  - tile: each pixel's samples are traced to completion one after another.
// Both consume the same random numbers per path, keyed by (seed, instance, sample
// index), and RayQuery's streams report the hits its single rays do, so they
// produce the same image up to floating-point order in the film (identical
// here: the film gathers in a fixed order).
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

// The state a path carries from one vertex to the next, for one stream of
// paths in flight; dead paths are compacted away after every bounce so that the
// live ones stay contiguous and feed Embree's stream queries directly.
FG_SOA_COLUMN(PathRay, Ray, "ray");
FG_SOA_COLUMN(PathThroughput, Rgb, "throughput");
FG_SOA_COLUMN(PathRadiance, Rgb, "radiance");
FG_SOA_COLUMN(PathPrevious, PathHistory, "history");
FG_SOA_COLUMN(PathRng, jobs::Rng, "rng");
FG_SOA_COLUMN(PathSample, std::uint32_t, "sample");  // the path's sample in the wave
FG_SOA_COLUMN(PathTimeNs, float, "time_ns");
using PathBuffer = SoaBuffer<PathRay, PathThroughput, PathRadiance, PathPrevious, PathRng, PathSample, PathTimeNs>;

// What one bounce produces and consumes, not carried to the next.
FG_SOA_COLUMN(VertexHit, Hit, "hit");
FG_SOA_COLUMN(VertexShadow, ShadowRequest, "shadow");
FG_SOA_COLUMN(VertexAlive, std::uint8_t, "alive");
using VertexBuffer = SoaBuffer<VertexHit, VertexShadow, VertexAlive>;

// A wave's finished samples, in the order the film takes them.
FG_SOA_COLUMN(SampleRaster, Vec2, "raster");
FG_SOA_COLUMN(SampleRadiance, Rgb, "radiance");
FG_SOA_COLUMN(SampleTimeNs, float, "time_ns");
using SampleBuffer = SoaBuffer<SampleRaster, SampleRadiance, SampleTimeNs>;

// Paths per stream: one Embree stream query's worth, and small enough that a
// stream's state (about 100 bytes a path, plus the bounce's hits and shadow
// rays) stays in the L2 cache while the stream bounces.
constexpr std::size_t kStream = 256;

struct PathStream {
    PathBuffer paths;
    VertexBuffer vertices;
};

constexpr std::array<std::uint32_t, kStream> streamSlots() {
    std::array<std::uint32_t, kStream> slots{};
    for (std::size_t i = 0; i < kStream; ++i) slots[i] = static_cast<std::uint32_t>(i);
    return slots;
}
constexpr std::array<std::uint32_t, kStream> kStreamSlots = streamSlots();

struct Settings {
    int spp = 16;
    PathLimits limits;
    std::size_t waveSize = 1 << 18;
    bool wavefront = true;
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

Vec2 jitteredRaster(const Camera& camera, std::uint32_t pixel, jobs::Rng& rng) {
    const Vec2 jitter = rng.uniform2();
    return Vec2(static_cast<float>(pixel % static_cast<std::uint32_t>(camera.width)),
                static_cast<float>(pixel / static_cast<std::uint32_t>(camera.width))) + jitter;
}

// A non-finite sample would poison every pixel its filter reaches.
Rgb finiteOrBlack(const Rgb& L) { return isFinite(L) ? L : Rgb(0.0f); }

// Traces the wave's samples [first.begin, first.end) in SoA stages (closest-hit
// stream -> shading -> shadow stream -> compaction) until all have ended, and
// writes their results into `samples`. Returns the path segments traced.
std::int64_t traceStream(const PathTracerScene& pts, const Camera& camera, std::uint64_t seed, std::uint64_t stream,
                         const Settings& settings, const SampleRange& range, jobs::IndexRange first,
                         PathStream& state, SampleBuffer& samples) {
    PathBuffer& paths = state.paths;
    VertexBuffer& vertices = state.vertices;
    paths.resize(first.size());
    vertices.resize(first.size());
    auto rays = paths.column<PathRay>();
    auto throughput = paths.column<PathThroughput>();
    auto radiance = paths.column<PathRadiance>();
    auto history = paths.column<PathPrevious>();
    auto rngs = paths.column<PathRng>();
    auto sampleOf = paths.column<PathSample>();
    auto timeNs = paths.column<PathTimeNs>();
    auto hits = vertices.column<VertexHit>();
    auto shadows = vertices.column<VertexShadow>();
    auto alive = vertices.column<VertexAlive>();
    auto raster = samples.column<SampleRaster>();
    auto sampleRadiance = samples.column<SampleRadiance>();
    auto sampleTimeNs = samples.column<SampleTimeNs>();

    std::int64_t clock = jobs::wallNanos();
    for (std::size_t k = 0; k < first.size(); ++k) {
        const std::size_t i = first.begin + k;
        rngs[k] = jobs::Rng(seed, stream, range.key(i, static_cast<std::uint64_t>(settings.spp)));
        raster[i] = jitteredRaster(camera, range.pixel(i), rngs[k]);
        rays[k] = camera.generateRay(raster[i]);
        throughput[k] = Rgb(1.0f);
        radiance[k] = Rgb(0.0f);
        history[k] = PathHistory::atCamera(camera.medium);
        sampleOf[k] = static_cast<std::uint32_t>(i);
        timeNs[k] = 0.0f;
    }

    std::int64_t segments = 0;
    std::size_t live = first.size();
    while (live > 0) {
        segments += static_cast<std::int64_t>(live);
        pts.rays.intersect(rays.first(live), hits.first(live));
        for (std::size_t k = 0; k < live; ++k) {
            PathVertexState vertex{rays[k], throughput[k], radiance[k], history[k], rngs[k]};
            // advancePath sets every field of a request it makes pending.
            shadows[k].pending = false;
            alive[k] = advancePath(pts, settings.limits, hits[k], vertex, shadows[k]) ? 1 : 0;
        }
        resolveShadowRays(pts, std::span<const std::uint32_t>(kStreamSlots.data(), live), shadows, radiance);

        // The bounce's wall time is shared by the paths that took part in it,
        // so long paths are booked more of the pixel's time.
        const std::int64_t now = jobs::wallNanos();
        const float share = static_cast<float>(now - clock) / static_cast<float>(live);
        clock = now;

        // Compaction keeps the order of paths; a path's result does not depend on it.
        std::size_t kept = 0;
        for (std::size_t k = 0; k < live; ++k) {
            timeNs[k] += share;
            if (alive[k]) {
                if (kept != k) paths.copyItem(kept, k);
                ++kept;
            } else {
                sampleRadiance[sampleOf[k]] = finiteOrBlack(radiance[k]);
                sampleTimeNs[sampleOf[k]] = timeNs[k];
            }
        }
        live = kept;
    }
    return segments;
}

// Wavefront schedule: the wave is cut into streams of kStream paths, each
// advanced bounce by bounce to the end by one task, so a wave has one barrier
// (its end) instead of several per bounce. Stream state lives in per-worker
// buffers reused across streams and waves.
std::int64_t traceWave(const PathTracerScene& pts, const Camera& camera, std::uint64_t seed, std::uint64_t stream,
                       const Settings& settings, const SampleRange& range, jobs::PerWorker<PathStream>& streams,
                       SampleBuffer& samples) {
    std::atomic<std::int64_t> segments{0};
    jobs::parallelForChunks(range.count(), kStream, [&](jobs::IndexRange r) {
        segments += traceStream(pts, camera, seed, stream, settings, range, r, streams.local(), samples);
    });
    return segments.load();
}

std::int64_t traceTile(const PathTracerScene& pts, const Camera& camera, std::uint64_t seed, std::uint64_t stream,
                       const Settings& settings, const SampleRange& range, SampleBuffer& out) {
    std::atomic<std::int64_t> segments{0};
    auto radiance = out.column<SampleRadiance>();
    auto raster = out.column<SampleRaster>();
    auto timeNs = out.column<SampleTimeNs>();
    const std::size_t samples = range.samples;
    // One chunk = whole pixels, so each pixel's samples run back to back.
    const std::size_t pixelGrain = std::max<std::size_t>(1, kStream / samples);
    jobs::parallelForChunks(range.pixels, pixelGrain, [&](jobs::IndexRange pixels) {
        std::int64_t chunkSegments = 0;
        for (std::size_t localPixel = pixels.begin; localPixel != pixels.end; ++localPixel) {
            const std::int64_t start = jobs::wallNanos();
            for (std::size_t s = 0; s < samples; ++s) {
                const std::size_t i = localPixel * samples + s;
                jobs::Rng rng(seed, stream, range.key(i, static_cast<std::uint64_t>(settings.spp)));
                raster[i] = jitteredRaster(camera, range.pixel(i), rng);
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
                    if (shadow.pending) L += shadowContribution(pts, shadow);
                }
                radiance[i] = finiteOrBlack(L);
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
        settings.limits.rrThreshold = static_cast<float>(params.getFloat("rr_threshold"));
        settings.waveSize = static_cast<std::size_t>(params.getInt("wave_size"));
        settings.wavefront = params.getString("schedule") == "wavefront";

        const Camera camera = ctx.filmCamera();
        PathTracerScene pts(scene, ctx.rays());
        const std::string& guiding = params.getString("guiding");
        if (guiding == "gmm" || (guiding == "auto" && ctx.hasInput("radiance_cache"))) {
            if (!ctx.hasInput("radiance_cache"))
                throw InputError("pass '" + ctx.instanceName() + "': guiding = \"gmm\" needs a radiance_cache input");
            guideByRadianceCache(pts, ctx.input<GuidingCache>("radiance_cache"), params);
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

        SampleBuffer samples;
        jobs::PerWorker<PathStream> streams;
        for (std::size_t passStart = 0; passStart < spp; passStart += passSamples) {
            const std::size_t samplesPerPixel = std::min(passSamples, spp - passStart);
            for (std::size_t firstPixel = 0; firstPixel < pixelCount; firstPixel += pixelsPerWave) {
                const SampleRange range{firstPixel, std::min(pixelsPerWave, pixelCount - firstPixel), passStart,
                                        samplesPerPixel};
                samples.resize(range.count());
                const std::int64_t segments =
                    settings.wavefront
                        ? traceWave(pts, camera, ctx.seed(), ctx.streamKey(), settings, range, streams, samples)
                        : traceTile(pts, camera, ctx.seed(), ctx.streamKey(), settings, range, samples);
                ctx.addCounter("path_segments", segments);
                film.addRound({firstPixel, range.pixels, static_cast<int>(samplesPerPixel),
                               samples.column<SampleRaster>(), samples.column<SampleRadiance>()});
                const auto times = std::span<const float>(samples.column<SampleTimeNs>());
                jobs::parallelFor(range.pixels, 4096, [&](std::size_t px) {
                    float sum = 0.0f;
                    for (std::size_t s = 0; s < samplesPerPixel; ++s) sum += times[px * samplesPerPixel + s];
                    timeAov[firstPixel + px] += sum;
                    sampleAov[firstPixel + px] += static_cast<float>(samplesPerPixel);
                });
                ctx.addItems(static_cast<std::int64_t>(range.count()));
                ctx.reportProgress((static_cast<double>(passStart) * static_cast<double>(pixelCount) +
                                    static_cast<double>((firstPixel + range.pixels) * samplesPerPixel)) /
                                   (static_cast<double>(pixelCount) * static_cast<double>(spp)));
            }
            ctx.completedUnit();
            const std::size_t done = passStart + samplesPerPixel;
            if (done < spp && ctx.stopRequested()) {
                ctx.keptPartial(ctx.instanceName() + ": " + std::to_string(done) + " of " + std::to_string(spp) +
                                " samples per pixel");
                break;
            }
        }
    }
};

// Bytes of one path in flight: its carried state plus one bounce's hit and shadow request.
constexpr std::uint64_t kBytesPerPathInFlight = sizeof(Ray) + 2 * sizeof(Rgb) + sizeof(PathHistory) +
                                                sizeof(jobs::Rng) + sizeof(std::uint32_t) + sizeof(float) +
                                                sizeof(Hit) + sizeof(ShadowRequest) + sizeof(std::uint8_t);
// Bytes of one finished sample waiting for the film: raster position, radiance, time.
constexpr std::uint64_t kBytesPerWaveSample = sizeof(Vec2) + sizeof(Rgb) + sizeof(float);

// The film (sums and the time_ns and samples AOVs), one wave of finished
// samples and one stream of paths in flight per worker thread.
MemoryEstimate pathTracerMemory(const PreflightContext& pf) {
    const auto spp = static_cast<std::uint64_t>(pf.params.getInt("spp"));
    const std::uint64_t pixels = static_cast<std::uint64_t>(pf.film.width) * static_cast<std::uint64_t>(pf.film.height);
    const std::uint64_t wave = std::min(multiplyBytes(pixels, spp), static_cast<std::uint64_t>(pf.params.getInt("wave_size")));
    const std::uint64_t inFlight = static_cast<std::uint64_t>(std::max(1, jobs::hardwareThreads())) * kStream;
    MemoryEstimate estimate;
    estimate.bytes = addBytes(filmBytes(pf.film, 2), addBytes(multiplyBytes(wave, kBytesPerWaveSample),
                                                              multiplyBytes(inFlight, kBytesPerPathInFlight)));
    estimate.what = "film " + std::to_string(pf.film.width) + " x " + std::to_string(pf.film.height) + ", " +
                    std::to_string(wave) + " samples per wave and " + std::to_string(inFlight) + " paths in flight";
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
        rouletteThresholdParam("path"),
        {"schedule", ParamType::String, std::string("wavefront"), 0, 0, {"wavefront", "tile"},
         "wavefront: SoA path queues advanced stage by stage; tile: each pixel's paths traced to completion"},
        {"wave_size", ParamType::Int, std::int64_t{1 << 18}, 1, 1 << 26, {},
         "samples per wave, traced and then added to the film together (24 bytes each while in flight)"},
        {"guiding", ParamType::String, std::string("auto"), 0, 0, {"auto", "none", "gmm"},
         "none: BSDF sampling; gmm: guided by the radiance_cache input (Vorba et al. 2014); auto: gmm when "
         "that input is bound"},
    };
    const std::vector<ParamSpec> guided = guidedSamplingParams();
    spec.params.insert(spec.params.end(), guided.begin(), guided.end());
    return {spec, [] { return std::make_unique<PathTracerPass>(); }, {}, pathTracerMemory};
}

}  // namespace fg
