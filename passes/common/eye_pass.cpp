// Eye pass (`eye`): the camera half of the photon pipelines. Each pixel sample
// follows the camera ray through purely specular surfaces (the S* E part of
// L S* D S* E) and stops at the first surface with a diffuse or glossy lobe,
// where it stores an eye-path vertex: the map of eye vertices that photon
// gathering reads and photon splatting writes to (Frisvad et al. 2014 §3.3,
// after Herzog et al. 2007).
//
// Everything the photon maps do not carry is estimated here and written to
// the `direct` film: emission seen directly or through the specular chain, and
// direct lighting at the stored vertex — next-event estimation plus one BSDF
// sample, combined with the power heuristic exactly as the path tracer's last
// vertex does (the per-vertex code of path_vertex.h is reused, so `direct`
// equals the `pt` pipeline with max_depth = 1 in expectation on scenes
// without specular surfaces). Mixed materials (e.g. plastic) end the chain: their
// specular lobe then only reflects emitters (through the BSDF-sampled ray),
// not photon-mapped indirect light.
//
// The vertex throughput is the specular chain's weight divided by the sample
// count, so photon estimates times throughput summed over a pixel's vertices
// are that pixel's box-filtered mean. Vertices are stored in (pixel, sample)
// order. Random numbers are keyed by (seed, instance, sample index).
//
// With direct_light = false the `direct` film stays black: the pipeline's
// image is then the photon estimates alone (caustic-only images, as in the
// comparisons of Frisvad et al. 2014 §4.1). The vertices do not change: the
// light sampling that is skipped comes after a sample's vertex is stored, and
// every sample has its own random stream.
#include "passes/common/eye_vertex_records.h"
#include "passes/passes.h"
#include "passes/common/path_vertex.h"

#include "engine/core/error.h"
#include "engine/image/film.h"
#include "engine/buffers/photon_buffers.h"
#include "engine/accel/ray_query.h"
#include "engine/scene/scene.h"
#include "jobs/parallel.h"
#include "jobs/random.h"

#include <algorithm>

namespace fg {

namespace {

// Samples traced per film round; bounds the temporary per-sample storage.
constexpr std::size_t kWaveSamples = 1 << 18;

// Traces one camera sample; returns the radiance for the `direct` film (black
// without `directLight`) and fills `vertex`.
Rgb traceEyeSample(const PathTracerScene& pts, const Camera& camera, Ray ray, jobs::Rng& rng, int maxSpecularDepth,
                   float sampleWeight, bool directLight, EyeRecord& vertex) {
    const Scene& scene = pts.scene;
    Rgb beta(1.0f), radiance(0.0f);
    PathHistory history = PathHistory::atCamera(camera.medium);
    PathVertexState state{ray, beta, radiance, history, rng};
    PathLimits chain;
    chain.maxDepth = maxSpecularDepth;
    chain.rrDepth = kNoRoulette;
    vertex.valid = false;

    for (;;) {
        const Hit hit = pts.rays.intersect(state.ray);
        if (hit.valid()) {
            const Shape& shape = scene.shapes[hit.shape];
            const Bsdf* bsdf = shape.bsdf >= 0 ? scene.bsdfs[static_cast<std::size_t>(shape.bsdf)].get() : nullptr;
            if (bsdf && bsdf->hasSmoothLobe()) {
                const SurfacePoint sp = pts.rays.surface(state.ray, hit);
                // The transparent part of a mask is crossed as a null boundary.
                if (passesThroughMask(bsdf, sp.texturePoint(), rng)) {
                    crossSurface(shape, sp, state);
                    continue;
                }
                history.maskResolved = bsdf->hasOpacity();
                vertex.get<EyePosition>() = sp.p;
                vertex.get<EyeNormal>() = sp.ns;
                vertex.get<EyeGeometricNormal>() = sp.ng;
                vertex.get<EyeOutgoing>() = -glm::normalize(state.ray.direction);
                vertex.get<EyeUv>() = sp.uv;
                vertex.get<EyeThroughput>() = beta * sampleWeight;
                vertex.get<EyeBsdf>() = static_cast<std::uint32_t>(shape.bsdf);
                vertex.valid = true;
                if (!directLight) return Rgb(0.0f);

                endPathAtEyeVertex(pts, hit, state, false);
                return radiance;
            }
        }
        // A miss (environment), a null boundary or a purely specular event.
        ShadowRequest unused;  // specular surfaces sample no lights
        if (!advancePath(pts, chain, hit, state, unused)) return directLight ? radiance : Rgb(0.0f);
    }
}

class EyePass final : public Pass {
public:
    void run(PassContext& ctx) override {
        const Scene& scene = ctx.scene();
        if (!scene.media.empty() || scene.camera.medium >= 0) {
            throw InputError(scene.sourcePath, 0,
                             "pass '" + ctx.instanceName() +
                                 "': participating media are not supported by the surface photon pipelines; render "
                                 "this scene with the bre (volumetric photon mapping) or pt pipeline");
        }
        const int spp = static_cast<int>(ctx.params().getInt("spp"));
        const int maxSpecularDepth = static_cast<int>(ctx.params().getInt("max_specular_depth"));
        const bool directLight = ctx.params().getBool("direct_light");
        const float sampleWeight = 1.0f / static_cast<float>(spp);

        const Camera camera = ctx.filmCamera();
        const PathTracerScene pts(scene, ctx.rays());

        Film& film = ctx.createOutput<Film>("direct", ctx.filmSettings());
        EyeVertices& eye = ctx.createOutput<EyeVertices>("eye_vertices");
        eye.samplesPerPixel = spp;
        EyeVertexBuffer& out = eye.vertices;

        const std::size_t pixelCount = film.pixelCount();
        const auto samplesPerPixel = static_cast<std::size_t>(spp);
        const std::size_t pixelsPerWave = std::max<std::size_t>(1, kWaveSamples / samplesPerPixel);
        const std::uint64_t stream = ctx.streamKey();
        std::vector<Vec2> raster;
        std::vector<Rgb> radiance;
        std::vector<EyeRecord> records;
        std::vector<std::size_t> slot;

        for (std::size_t firstPixel = 0; firstPixel < pixelCount; firstPixel += pixelsPerWave) {
            const std::size_t pixels = std::min(pixelsPerWave, pixelCount - firstPixel);
            const std::size_t count = pixels * samplesPerPixel;
            raster.resize(count);
            radiance.resize(count);
            records.resize(count);
            const std::size_t pixelGrain = std::max<std::size_t>(1, 256 / samplesPerPixel);
            jobs::parallelForChunks(pixels, pixelGrain, [&](jobs::IndexRange range) {
                for (std::size_t local = range.begin; local != range.end; ++local) {
                    const std::size_t pixel = firstPixel + local;
                    const Vec2 corner(static_cast<float>(pixel % static_cast<std::size_t>(camera.width)),
                                      static_cast<float>(pixel / static_cast<std::size_t>(camera.width)));
                    for (std::size_t s = 0; s < samplesPerPixel; ++s) {
                        const std::size_t i = local * samplesPerPixel + s;
                        jobs::Rng rng(ctx.seed(), stream, static_cast<std::uint64_t>(pixel) * samplesPerPixel + s);
                        raster[i] = corner + rng.uniform2();
                        const Rgb L = traceEyeSample(pts, camera, camera.generateRay(raster[i]), rng, maxSpecularDepth,
                                                     sampleWeight, directLight, records[i]);
                        // A non-finite sample would poison every pixel its filter reaches.
                        radiance[i] = isFinite(L) ? L : Rgb(0.0f);
                    }
                }
            });
            film.addRound({firstPixel, pixels, spp, raster, radiance});

            appendEyeVertices(records, firstPixel, samplesPerPixel, out, slot, ctx);
            ctx.addItems(static_cast<std::int64_t>(count));
            ctx.reportProgress(static_cast<double>(firstPixel + pixels) / static_cast<double>(pixelCount));
        }
    }
};

}  // namespace

PassRegistration eyePass() {
    PassSpec spec;
    spec.name = "eye";
    spec.doc = "Camera paths through specular chains to the first diffuse/glossy vertex: stores the eye-vertex map "
               "and renders emission plus direct lighting (NEE + MIS) at those vertices (unless direct_light = false)";
    spec.outputs = {
        {"eye_vertices", "EyeVertices", "first non-specular vertex of each camera sample, in (pixel, sample) order"},
        {"direct", "Film", "emission seen through S* chains and direct lighting at the eye vertices"},
    };
    spec.params = {
        {"spp", ParamType::Int, std::int64_t{4}, 1, 1 << 16, {}, "camera samples per pixel (jittered)", "sample_count"},
        {"max_specular_depth", ParamType::Int, std::int64_t{16}, 0, 4096, {},
         "specular bounces followed before a camera path is given up (0: only directly seen surfaces)"},
        {"direct_light", ParamType::Bool, true, 0, 0, {},
         "add emission and direct lighting at the eye vertices to the film (false: the photon estimates alone, "
         "e.g. caustic-only images)"},
    };
    // Refused before any photon is traced: the surface pipelines have no media estimator.
    const auto preflight = [](const PreflightContext& pf) {
        if (!pf.scene.media.empty() || pf.scene.camera.medium >= 0) {
            throw InputError(pf.scene.sourcePath, 0,
                             "pass '" + pf.instance +
                                 "': participating media are not supported by the surface photon pipelines; render "
                                 "this scene with the bre (volumetric photon mapping) or pt pipeline");
        }
    };
    // The direct-light film and one eye vertex per camera sample (an upper
    // bound: samples that leave the scene store none).
    const auto memory = [](const PreflightContext& pf) {
        const auto spp = static_cast<std::uint64_t>(pf.params.getInt("spp"));
        const std::uint64_t pixels = static_cast<std::uint64_t>(pf.film.width) * static_cast<std::uint64_t>(pf.film.height);
        constexpr std::uint64_t kBytesPerVertex = 4 * sizeof(Vec3) + sizeof(std::uint32_t) + sizeof(Vec2) + sizeof(Rgb) +
                                                  sizeof(std::uint32_t);
        MemoryEstimate estimate;
        estimate.bytes = addBytes(filmBytes(pf.film), multiplyBytes(multiplyBytes(pixels, spp), kBytesPerVertex));
        estimate.what = "film " + std::to_string(pf.film.width) + " x " + std::to_string(pf.film.height) + " and " +
                        std::to_string(spp) + " eye vertices per pixel";
        return estimate;
    };
    return {spec, [] { return std::make_unique<EyePass>(); }, preflight, memory};
}

}  // namespace fg
