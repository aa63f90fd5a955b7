// Radiance cache record selection (`cache_select`): Herzog et al. 2007, §8.3,
// which calls its cache "well-suited for sparse sampling in the image plane":
// the records are chosen before any photon ray is splatted, so that the rays
// are splatted onto the records' eye vertices alone and radiance_cache
// interpolates the records' radiance at every other eye vertex. Placement is
// the multi-pass image-space cache splatting of Gautron et al. 2005 with
// Ward et al.'s (1988) weight w_k(x) = 1 / (‖x − x_k‖ / R_k + √(1 − n·n_k)),
// record k used where w_k > 1/ε (passes/prs/radiance_cache.h). The paper
// sizes R_k by the harmonic mean distance of the photon rays splatted at the
// record, which is only known after the splat; here R_k is Ward et al.'s
// harmonic mean distance of the geometry, R_k = N / Σ 1/d_i over N
// stratified cosine-distributed rays from x_k, held to [min_radius,
// max_radius] × the scene diagonal. A record sits at its pixel's first eye
// vertex. Every eye vertex that no record is valid at is splatted directly
// instead (a fallback vertex), so every vertex gets light.
// Output `record_vertices`: the records' eye vertices in record order, then
// the fallback vertices in eye order; radiance_cache relies on that order.
#include "passes/passes.h"
#include "passes/prs/radiance_cache.h"

#include "engine/accel/ray_query.h"
#include "engine/buffers/photon_buffers.h"
#include "engine/buffers/radiance_cache_buffers.h"
#include "engine/core/error.h"
#include "engine/scene/scene.h"
#include "jobs/parallel.h"

#include <algorithm>
#include <cstdint>
#include <string>
#include <vector>

namespace fg {

namespace {

class CacheSelectPass final : public Pass {
public:
    void run(PassContext& ctx) override {
        const Scene& scene = ctx.scene();
        const RayQuery& rayQuery = ctx.rays();
        const EyeVertexBuffer::View eye = ctx.input<EyeVertices>("eye_vertices").vertices.view();
        RadianceCacheSettings settings;
        settings.error = static_cast<float>(ctx.params().getFloat("error"));
        settings.grid = static_cast<int>(ctx.params().getInt("grid"));
        settings.passes = static_cast<int>(ctx.params().getInt("passes"));
        settings.minRecords = static_cast<int>(ctx.params().getInt("min_records"));
        const float diagonal = glm::length(scene.boundsMax - scene.boundsMin);
        const float maxRadius = static_cast<float>(ctx.params().getFloat("max_radius")) * diagonal;
        const float minRadius =
            std::min(maxRadius, static_cast<float>(ctx.params().getFloat("min_radius")) * diagonal);
        const std::vector<Vec3> directions =
            harmonicMeanDistanceDirections(static_cast<int>(ctx.params().getInt("distance_strata")));

        const Camera camera = ctx.filmCamera();
        const std::size_t pixelCount = static_cast<std::size_t>(camera.width) * static_cast<std::size_t>(camera.height);

        const auto pixelOf = eye.column<EyePixel>();
        const auto positionOf = eye.column<EyePosition>();
        const auto normalOf = eye.column<EyeNormal>();
        const auto geometricNormalOf = eye.column<EyeGeometricNormal>();
        const auto outgoingOf = eye.column<EyeOutgoing>();
        std::vector<std::uint32_t> firstVertex(pixelCount, ~std::uint32_t(0));
        for (std::size_t v = eye.size(); v-- > 0;) {
            if (pixelOf[v] >= pixelCount) throw std::logic_error("cache_select: eye vertex outside the film");
            firstVertex[pixelOf[v]] = static_cast<std::uint32_t>(v);
        }
        std::vector<CachePixelSample> samples(pixelCount);
        for (std::size_t pixel = 0; pixel < pixelCount; ++pixel) {
            const std::uint32_t v = firstVertex[pixel];
            if (v == ~std::uint32_t(0)) continue;
            samples[pixel].valid = true;
            samples[pixel].position = positionOf[v];
            samples[pixel].normal = normalOf[v];
        }

        std::vector<std::int64_t> escapedRays(pixelCount, 0);
        const auto measureRadius = [&](std::uint32_t pixel) {
            const std::uint32_t v = firstVertex[pixel];
            const Vec3 p = positionOf[v];
            const Vec3 ng = geometricNormalOf[v];
            const Frame frame(glm::dot(ng, outgoingOf[v]) >= 0.0f ? ng : -ng);
            std::vector<float> distances(directions.size());
            for (std::size_t i = 0; i < directions.size(); ++i) {
                Ray ray;
                ray.direction = frame.toWorld(directions[i]);
                ray.origin = offsetRayOrigin(p, ng, ray.direction);
                const Hit hit = rayQuery.intersect(ray);
                distances[i] = hit.valid() ? hit.t : kInfinity;
                if (!hit.valid()) ++escapedRays[pixel];
            }
            samples[pixel].radius = harmonicMeanRadius(distances, minRadius, maxRadius);
        };
        const RadianceCachePlacement placement = placeCacheRecords(samples, camera, settings, measureRadius);
        const std::size_t recordCount = placement.recordPixels.size();

        CacheRecords& cache = ctx.createOutput<CacheRecords>("cache_records");
        cache.error = settings.error;
        cache.records.resize(recordCount);
        CacheCoefficientArray zero;
        zero.fill(Rgb(0.0f));
        for (std::size_t k = 0; k < recordCount; ++k) {
            const std::uint32_t pixel = placement.recordPixels[k];
            const CachePixelSample& s = samples[pixel];
            cache.records.set(k, CacheRecordBuffer::Record(s.position, s.normal, s.radius, pixel, zero));
        }

        const CacheRecordLookup lookup(cache.records.column<CachePosition>(), cache.records.column<CacheNormal>(),
                                       cache.records.column<CacheRadius>(), placement.windows, camera.height,
                                       settings.error);
        std::vector<std::uint8_t> uncovered(eye.size(), 0);
        jobs::parallelFor(eye.size(), 1024, [&](std::size_t v) {
            const int x = static_cast<int>(pixelOf[v] % static_cast<std::uint32_t>(camera.width));
            const int y = static_cast<int>(pixelOf[v] / static_cast<std::uint32_t>(camera.width));
            if (lookup.forEachValid(x, y, positionOf[v], normalOf[v], [](std::uint32_t, float) {}) == 0) uncovered[v] = 1;
        });
        std::vector<std::uint32_t> splatVertices;
        for (std::uint32_t pixel : placement.recordPixels) splatVertices.push_back(firstVertex[pixel]);
        for (std::size_t v = 0; v < eye.size(); ++v)
            if (uncovered[v]) splatVertices.push_back(static_cast<std::uint32_t>(v));
        EyeVertices& out = ctx.createOutput<EyeVertices>("record_vertices");
        out.vertices.resize(splatVertices.size());
        jobs::parallelFor(splatVertices.size(), 1024, [&](std::size_t i) { out.vertices.set(i, eye.get(splatVertices[i])); });

        std::int64_t escaped = 0;
        for (std::int64_t e : escapedRays) escaped += e;
        ctx.addItems(static_cast<std::int64_t>(eye.size()));
        ctx.addCounter("cache_records", static_cast<std::int64_t>(recordCount));
        for (std::size_t pass = 0; pass < placement.recordsPerPass.size(); ++pass)
            ctx.addCounter("records_pass_" + std::to_string(pass + 1), static_cast<std::int64_t>(placement.recordsPerPass[pass]));
        ctx.addCounter("undercovered_pixels", static_cast<std::int64_t>(placement.undercoveredPixels.size()));
        ctx.addCounter("fallback_vertices", static_cast<std::int64_t>(splatVertices.size() - recordCount));
        ctx.addCounter("distance_rays", static_cast<std::int64_t>(recordCount * directions.size()));
        ctx.addCounter("escaped_distance_rays", escaped);
    }
};

}  // namespace

PassRegistration cacheSelectPass() {
    PassSpec spec;
    spec.name = "cache_select";
    spec.doc = "Radiance cache records chosen before splatting (Herzog et al. 2007, §8.3; Gautron et al. 2005; Ward et "
               "al. 1988): multi-pass image-space placement with R_k from the geometry's harmonic mean distance; the "
               "records' eye vertices, and those no record is valid at, are the vertices to splat onto";
    spec.inputs = {{"eye_vertices", "EyeVertices", "every eye vertex of the image"}};
    spec.outputs = {
        {"cache_records", "CacheRecords", "the records: position, normal, radius R_k, pixel (coefficients zero)"},
        {"record_vertices", "EyeVertices",
         "the vertices to splat onto: the records' in record order, then those no record is valid at, in eye order"},
    };
    spec.params = placementParams();
    spec.params.insert(spec.params.end(), {
        {"distance_strata", ParamType::Int, std::int64_t{8}, 1, 64, {},
         "the harmonic mean distance traces distance_strata² cosine-distributed rays per record"},
        {"min_radius", ParamType::Float, 0.0, 0.0, 10.0, {},
         "lower bound on a record's radius R_k as a fraction of the scene diagonal"},
        {"max_radius", ParamType::Float, 0.25, 1e-4, 10.0, {},
         "upper bound on a record's radius R_k as a fraction of the scene diagonal (also the radius where every "
         "ray escapes)"},
    });
    return {spec, [] { return std::make_unique<CacheSelectPass>(); }, checkPlacementGrid};
}

}  // namespace fg
