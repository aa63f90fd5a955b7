// Volume eye pass (`volume_eye`): the camera half of the beam-radiance-estimate
// pipeline (Jarosz, Zwicker & Jensen 2008; Jakob et al. 2011 §3.1-3.2, Eq. 1):
//
//   L(x, w) = Tr(x <-> x_b) L_s(x_b, w) + L_m(x, w, b).
//
// Each pixel sample follows the camera ray through index-matched (`null`)
// boundaries and purely specular surfaces, as the `eye` pass does, up to the
// first surface with a diffuse or glossy lobe. Media along the way are not
// sampled: every stretch of the path inside a scattering medium is stored as
// a segment (origin, direction, tNear, tFar, medium, pixel, throughput), the
// domain of the media radiance L_m that the beam query estimates from volume
// photons, and the path weight is multiplied by the stretch's transmittance.
// A straight leg that crosses several media gives several segments with the
// leg's origin; a specular bounce starts a new leg.
//
// The surface term Tr L_s is left to the surface part of the pipeline, exactly
// as the `eye` pass leaves it: the first smooth vertex is stored as an eye
// vertex whose throughput includes the transmittance to it (for photon
// gathering of caustic and global photons), and the `direct` film receives
// emission seen along the chain plus direct lighting at the vertex (next-event
// estimation with shadow rays through media and null boundaries, and one BSDF
// sample whose emission is found by free-flight sampling, power-heuristic MIS)
// — the per-vertex code of path_vertex.h. So L_s = direct light + photon-mapped
// indirect light (caustics L S+ D and global L ... D ... D, the latter
// including light that scattered in a medium before reaching the surface).
//
// Sample weights include 1/spp; vertices and segments are stored in (pixel,
// sample) order, segments of one sample in path order. Random numbers are
// keyed by (seed, instance, sample index).
#include "passes/common/eye_vertex_records.h"
#include "passes/passes.h"
#include "passes/common/path_vertex.h"

#include "engine/buffers/beam_buffers.h"
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
// Null boundaries crossed in a row; the bound only guards against degenerate geometry.
constexpr int kMaxNullCrossings = 1024;

using SegmentRecord = SegmentBuffer::Record;

class VolumeEyeTracer {
public:
    VolumeEyeTracer(const PathTracerScene& pts, int maxSpecularDepth, float sampleWeight)
        : pts_(pts), maxSpecularDepth_(maxSpecularDepth), sampleWeight_(sampleWeight) {}

    // Traces one camera sample: returns the radiance for the `direct` film, fills
    // `vertex` and appends the sample's segments.
    Rgb trace(Ray ray, int cameraMedium, std::uint32_t pixel, jobs::Rng& rng, EyeRecord& vertex,
              std::vector<SegmentRecord>& segments) const {
        const Scene& scene = pts_.scene;
        ray.direction = glm::normalize(ray.direction);
        Rgb beta(1.0f), radiance(0.0f);
        PathHistory history = PathHistory::atCamera(cameraMedium);
        PathVertexState state{ray, beta, radiance, history, rng};
        PathLimits chain;
        chain.maxDepth = maxSpecularDepth_;
        chain.rrDepth = kNoRoulette;
        vertex.valid = false;
        Vec3 legOrigin = ray.origin;
        Vec3 legDirection = ray.direction;
        int nullCrossings = 0;

        for (;;) {
            const Hit hit = pts_.rays.intersect(state.ray);
            if (history.medium >= 0) {
                const HomogeneousMedium& medium = scene.media[static_cast<std::size_t>(history.medium)];
                const float tStart = glm::dot(state.ray.origin - legOrigin, legDirection);
                if (!isBlack(medium.sigmaS()) && !isBlack(beta)) {
                    segments.push_back({legOrigin, legDirection, tStart, hit.valid() ? tStart + hit.t : kInfinity,
                                        history.medium, pixel, beta * sampleWeight_});
                }
                beta *= segmentTransmittance(medium, hit.valid() ? hit.t : kInfinity);
            }
            // Nothing further along can be seen (e.g. a ray escaping through a medium).
            if (isBlack(beta)) return radiance;

            if (hit.valid()) {
                const Shape& shape = scene.shapes[hit.shape];
                const Bsdf* bsdf = shape.bsdf >= 0 ? scene.bsdfs[static_cast<std::size_t>(shape.bsdf)].get() : nullptr;
                const SurfacePoint sp = bsdf && bsdf->hasSmoothLobe() ? pts_.rays.surface(state.ray, hit) : SurfacePoint{};
                // The transparent part of a mask is crossed as a null boundary.
                if (bsdf && bsdf->hasSmoothLobe() && passesThroughMask(bsdf, sp.texturePoint(), rng)) {
                    if (++nullCrossings > kMaxNullCrossings) return radiance;
                    crossSurface(shape, sp, state);
                    continue;
                }
                if (bsdf && bsdf->hasSmoothLobe()) {
                    history.maskResolved = bsdf->hasOpacity();
                    vertex.get<EyePosition>() = sp.p;
                    vertex.get<EyeNormal>() = sp.ns;
                    vertex.get<EyeGeometricNormal>() = sp.ng;
                    vertex.get<EyeOutgoing>() = -state.ray.direction;
                    vertex.get<EyeUv>() = sp.uv;
                    vertex.get<EyeThroughput>() = beta * sampleWeight_;
                    vertex.get<EyeBsdf>() = static_cast<std::uint32_t>(shape.bsdf);
                    vertex.valid = true;

                    // The segment's medium is in the throughput as transmittance already.
                    endPathAtEyeVertex(pts_, hit, state, true);
                    return radiance;
                }
                if (!bsdf || bsdf->isNull()) {
                    if (++nullCrossings > kMaxNullCrossings) return radiance;
                } else {
                    nullCrossings = 0;
                }
            }
            // A miss (environment), a null boundary or a purely specular event.
            const Vec3 before = state.ray.direction;
            ShadowRequest unused;  // specular surfaces sample no lights
            if (!advancePathAtSurface(pts_, chain, hit, state, unused)) return radiance;
            if (state.ray.direction != before) {
                legOrigin = state.ray.origin;
                legDirection = state.ray.direction;
            }
        }
    }

private:
    const PathTracerScene& pts_;
    int maxSpecularDepth_;
    float sampleWeight_;
};

class VolumeEyePass final : public Pass {
public:
    void run(PassContext& ctx) override {
        const Scene& scene = ctx.scene();
        const int spp = static_cast<int>(ctx.params().getInt("spp"));
        const int maxSpecularDepth = static_cast<int>(ctx.params().getInt("max_specular_depth"));

        const Camera camera = ctx.filmCamera();
        const PathTracerScene pts(scene, ctx.rays());
        const VolumeEyeTracer tracer(pts, maxSpecularDepth, 1.0f / static_cast<float>(spp));

        Film& film = ctx.createOutput<Film>("direct", ctx.filmSettings());
        EyeVertices& eye = ctx.createOutput<EyeVertices>("eye_vertices");
        EyeSegments& segmentsOut = ctx.createOutput<EyeSegments>("eye_segments");
        eye.samplesPerPixel = spp;
        segmentsOut.samplesPerPixel = spp;
        EyeVertexBuffer& out = eye.vertices;
        SegmentBuffer& segmentBuffer = segmentsOut.segments;

        const std::size_t pixelCount = film.pixelCount();
        const auto samplesPerPixel = static_cast<std::size_t>(spp);
        const std::size_t pixelsPerWave = std::max<std::size_t>(1, kWaveSamples / samplesPerPixel);
        const std::size_t pixelGrain = std::max<std::size_t>(1, 256 / samplesPerPixel);
        const std::uint64_t stream = ctx.streamKey();
        std::vector<Vec2> raster;
        std::vector<Rgb> radiance;
        std::vector<EyeRecord> records;
        std::vector<std::vector<SegmentRecord>> chunkSegments;
        std::vector<std::size_t> slot;

        for (std::size_t firstPixel = 0; firstPixel < pixelCount; firstPixel += pixelsPerWave) {
            const std::size_t pixels = std::min(pixelsPerWave, pixelCount - firstPixel);
            const std::size_t count = pixels * samplesPerPixel;
            raster.resize(count);
            radiance.resize(count);
            records.resize(count);
            chunkSegments.assign((pixels + pixelGrain - 1) / pixelGrain, {});
            jobs::parallelForChunks(pixels, pixelGrain, [&](jobs::IndexRange range) {
                std::vector<SegmentRecord>& segments = chunkSegments[range.begin / pixelGrain];
                for (std::size_t local = range.begin; local != range.end; ++local) {
                    const std::size_t pixel = firstPixel + local;
                    const Vec2 corner(static_cast<float>(pixel % static_cast<std::size_t>(camera.width)),
                                      static_cast<float>(pixel / static_cast<std::size_t>(camera.width)));
                    for (std::size_t s = 0; s < samplesPerPixel; ++s) {
                        const std::size_t i = local * samplesPerPixel + s;
                        jobs::Rng rng(ctx.seed(), stream, static_cast<std::uint64_t>(pixel) * samplesPerPixel + s);
                        raster[i] = corner + rng.uniform2();
                        const Rgb L = tracer.trace(camera.generateRay(raster[i]), camera.medium,
                                                   static_cast<std::uint32_t>(pixel), rng, records[i], segments);
                        // A non-finite sample would poison every pixel its filter reaches.
                        radiance[i] = isFinite(L) ? L : Rgb(0.0f);
                    }
                }
            });
            film.addRound({firstPixel, pixels, spp, raster, radiance});
            appendEyeVertices(records, firstPixel, samplesPerPixel, out, slot, ctx);
            appendSegments(chunkSegments, segmentBuffer, ctx);
            ctx.addItems(static_cast<std::int64_t>(count));
            ctx.reportProgress(static_cast<double>(firstPixel + pixels) / static_cast<double>(pixelCount));
        }
    }

private:
    static void appendSegments(const std::vector<std::vector<SegmentRecord>>& chunks, SegmentBuffer& out,
                               PassContext& ctx) {
        std::size_t total = 0;
        for (const auto& chunk : chunks) total += chunk.size();
        // One resize per wave: appending chunk by chunk would let the capacity run ahead of the size.
        std::size_t i = out.size();
        out.resize(i + total);
        for (const auto& chunk : chunks)
            for (const SegmentRecord& segment : chunk) out.set(i++, segment);
        ctx.addCounter("eye_segments", static_cast<std::int64_t>(total));
    }
};

}  // namespace

PassRegistration volumeEyePass() {
    PassSpec spec;
    spec.name = "volume_eye";
    spec.doc = "Camera paths through null boundaries and specular chains to the first diffuse/glossy vertex: "
               "stores the segments inside scattering media (for the beam query), the eye-vertex map, and "
               "emission plus direct lighting (NEE + MIS, attenuated by transmittance) at those vertices";
    spec.outputs = {
        {"eye_vertices", "EyeVertices",
         "first non-specular vertex of each camera sample, throughput including transmittance, (pixel, sample) order"},
        {"direct", "Film", "emission seen through S* chains and media, and direct lighting at the eye vertices"},
        {"eye_segments", "EyeSegments",
         "camera-path segments inside scattering media, with the path weight at their start"},
    };
    spec.params = {
        {"spp", ParamType::Int, std::int64_t{4}, 1, 1 << 16, {}, "camera samples per pixel (jittered)", "sample_count"},
        {"max_specular_depth", ParamType::Int, std::int64_t{16}, 0, 4096, {},
         "specular bounces followed before a camera path is given up (0: only directly seen surfaces)"},
    };
    // The direct-light film, and per camera sample at most one eye vertex and one
    // camera segment.
    const auto memory = [](const PreflightContext& pf) {
        const auto spp = static_cast<std::uint64_t>(pf.params.getInt("spp"));
        const std::uint64_t samples =
            multiplyBytes(static_cast<std::uint64_t>(pf.film.width) * static_cast<std::uint64_t>(pf.film.height), spp);
        constexpr std::uint64_t kVertexBytes = 4 * sizeof(Vec3) + sizeof(std::uint32_t) + sizeof(Vec2) + sizeof(Rgb) +
                                               sizeof(std::uint32_t);
        constexpr std::uint64_t kSegmentBytes = 2 * sizeof(Vec3) + 2 * sizeof(float) + sizeof(std::int32_t) +
                                                sizeof(std::uint32_t) + sizeof(Rgb);
        return MemoryEstimate{addBytes(filmBytes(pf.film), multiplyBytes(samples, kVertexBytes + kSegmentBytes)),
                              "film " + std::to_string(pf.film.width) + " x " + std::to_string(pf.film.height) + " and " +
                                  std::to_string(spp) + " eye vertices and segments per pixel",
                              {}};
    };
    return {spec, [] { return std::make_unique<VolumeEyePass>(); }, {}, memory};
}

}  // namespace fg
