// Radiance caching (`radiance_cache`): Herzog et al. 2007, §8.3, with the
// multi-pass image-space cache splatting of Gautron et al. 2005 and the
// weight of Ward et al. 1988, w_k(x) = 1 / (‖x − x_k‖ / R_k + √(1 − n·n_k)),
// record k used where w_k > 1/ε (passes/prs/radiance_cache.h). The radiance
// map must hold every eye vertex (ray_splat lambertian = "sh_map"). A pixel's
// record sits at its first mapped eye vertex; its coefficients are the mean
// of the pixel's mapped vertices that the record is valid at, and its radius
// R_k the kernel-weighted harmonic mean distance over all of them,
// Σ w / Σ (w / d) from the map's sums, clamped to `max_radius` times the
// scene diagonal (pixels no ray reached get that bound). The output map has
// the input's vertices, in its order, each with Σ w_k c_k / Σ w_k over the
// records valid at the vertex's own position and normal; vertices no record
// is valid at keep their own coefficients. radiance_integrate turns it into
// radiance as before (§8.1).
#include "passes/passes.h"
#include "passes/prs/radiance_cache.h"

#include "engine/buffers/photon_buffers.h"
#include "engine/buffers/photon_ray_buffers.h"
#include "engine/buffers/radiance_cache_buffers.h"
#include "engine/core/error.h"
#include "engine/scene/scene.h"
#include "jobs/parallel.h"

#include <algorithm>
#include <cstdint>
#include <numeric>
#include <string>
#include <utility>
#include <vector>

namespace fg {

namespace {

class RadianceCachePass final : public Pass {
public:
    void run(PassContext& ctx) override {
        const Scene& scene = ctx.scene();
        const EyeVertexBuffer::View eye = ctx.input<EyeVertices>("eye_vertices").vertices.view();
        const RadianceMapBuffer& map = ctx.input<RadianceMap>("radiance_map").vertices;
        RadianceCacheSettings settings;
        settings.error = static_cast<float>(ctx.params().getFloat("error"));
        settings.grid = static_cast<int>(ctx.params().getInt("grid"));
        settings.passes = static_cast<int>(ctx.params().getInt("passes"));
        settings.minRecords = static_cast<int>(ctx.params().getInt("min_records"));
        const float maxRadius =
            static_cast<float>(ctx.params().getFloat("max_radius")) * glm::length(scene.boundsMax - scene.boundsMin);

        Camera camera = scene.camera;
        camera.width = ctx.filmSettings().width;
        camera.height = ctx.filmSettings().height;
        const std::size_t pixelCount = static_cast<std::size_t>(camera.width) * static_cast<std::size_t>(camera.height);

        // Map entries grouped by pixel, each pixel's in eye-vertex order.
        const auto vertexOf = map.column<MapVertex>();
        const auto pixelOf = eye.column<EyePixel>();
        for (std::uint32_t v : vertexOf)
            if (v >= eye.size() || pixelOf[v] >= pixelCount)
                throw std::logic_error("radiance_cache: map vertex outside the eye vertices or the film");
        std::vector<std::uint32_t> entries(map.size());
        std::iota(entries.begin(), entries.end(), 0u);
        std::sort(entries.begin(), entries.end(), [&](std::uint32_t a, std::uint32_t b) {
            return std::pair(pixelOf[vertexOf[a]], vertexOf[a]) < std::pair(pixelOf[vertexOf[b]], vertexOf[b]);
        });
        std::vector<std::size_t> pixelStart(pixelCount + 1, 0);
        for (std::uint32_t g : entries) ++pixelStart[pixelOf[vertexOf[g]] + 1];
        std::partial_sum(pixelStart.begin(), pixelStart.end(), pixelStart.begin());

        const auto columns = radianceMapShColumns(map);
        const auto weightSum = map.column<MapWeightSum>();
        const auto inverseDistanceSum = map.column<MapInverseDistanceSum>();
        const auto positionOf = eye.column<EyePosition>();
        const auto normalOf = eye.column<EyeNormal>();
        const auto coefficientsOf = [&](std::uint32_t g) {
            CacheCoefficientArray c;
            for (std::size_t k = 0; k < c.size(); ++k) c[k] = columns[k][g];
            return c;
        };

        std::vector<CachePixelSample> samples(pixelCount);
        jobs::parallelFor(pixelCount, 256, [&](std::size_t pixel) {
            const std::size_t begin = pixelStart[pixel], end = pixelStart[pixel + 1];
            if (begin == end) return;
            CachePixelSample& sample = samples[pixel];
            const std::uint32_t first = vertexOf[entries[begin]];
            sample.valid = true;
            sample.position = positionOf[first];
            sample.normal = normalOf[first];
            double weights = 0.0, inverseDistances = 0.0;
            for (std::size_t i = begin; i < end; ++i) {
                weights += weightSum[entries[i]];
                inverseDistances += inverseDistanceSum[entries[i]];
            }
            const double harmonicMean = inverseDistances > 0.0 ? weights / inverseDistances : maxRadius;
            sample.radius = std::min(static_cast<float>(harmonicMean), maxRadius);
            sample.coefficients.fill(Rgb(0.0f));
            int used = 0;
            for (std::size_t i = begin; i < end; ++i) {
                const std::uint32_t v = vertexOf[entries[i]];
                if (!(wardDenominator(positionOf[v], normalOf[v], sample.position, sample.normal, sample.radius) <
                      settings.error))
                    continue;
                const CacheCoefficientArray c = coefficientsOf(entries[i]);
                for (std::size_t k = 0; k < c.size(); ++k) sample.coefficients[k] += c[k];
                ++used;
            }
            for (Rgb& c : sample.coefficients) c /= static_cast<float>(used);
        });

        const RadianceCachePlacement placement = placeCacheRecords(samples, camera, settings);

        CacheRecords& cache = ctx.createOutput<CacheRecords>("cache_records");
        cache.error = settings.error;
        const std::size_t recordCount = placement.recordPixels.size();
        cache.records.resize(recordCount);
        for (std::size_t k = 0; k < recordCount; ++k) {
            const std::uint32_t pixel = placement.recordPixels[k];
            const CachePixelSample& s = samples[pixel];
            cache.records.set(k, CacheRecordBuffer::Record(s.position, s.normal, s.radius, pixel, s.coefficients));
        }

        // Records whose window meets each row, in record order, so that every
        // vertex sums its records in the same order on any thread count.
        std::vector<std::vector<std::uint32_t>> rowRecords(static_cast<std::size_t>(camera.height));
        for (std::size_t k = 0; k < recordCount; ++k)
            for (int y = placement.windows[k].y0; y < placement.windows[k].y1; ++y)
                rowRecords[static_cast<std::size_t>(y)].push_back(static_cast<std::uint32_t>(k));

        RadianceMap& cached = ctx.createOutput<RadianceMap>("cached_map");
        cached.vertices.resize(map.size());
        jobs::parallelFor(map.size(), 4096, [&](std::size_t g) { cached.vertices.set(g, map.get(g)); });
        const auto cachedColumns = radianceMapShColumns(cached.vertices);
        std::vector<std::uint8_t> uncached(map.size(), 0);
        jobs::parallelFor(static_cast<std::size_t>(camera.height), 1, [&](std::size_t row) {
            const int y = static_cast<int>(row);
            for (int x = 0; x < camera.width; ++x) {
                const std::size_t pixel = row * static_cast<std::size_t>(camera.width) + static_cast<std::size_t>(x);
                for (std::size_t i = pixelStart[pixel]; i < pixelStart[pixel + 1]; ++i) {
                    const std::uint32_t g = entries[i];
                    const std::uint32_t v = vertexOf[g];
                    CacheCoefficientArray sum;
                    sum.fill(Rgb(0.0f));
                    float weightTotal = 0.0f;
                    for (std::uint32_t k : rowRecords[row]) {
                        if (!placement.windows[k].contains(x, y)) continue;
                        const CachePixelSample& record = samples[placement.recordPixels[k]];
                        const float denominator =
                            wardDenominator(positionOf[v], normalOf[v], record.position, record.normal, record.radius);
                        if (!(denominator < settings.error)) continue;
                        const float w = wardWeight(denominator);
                        for (std::size_t c = 0; c < sum.size(); ++c) sum[c] += w * record.coefficients[c];
                        weightTotal += w;
                    }
                    if (!(weightTotal > 0.0f)) {
                        uncached[g] = 1;
                        continue;
                    }
                    for (std::size_t c = 0; c < sum.size(); ++c) cachedColumns[c][g] = sum[c] / weightTotal;
                }
            }
        });

        ctx.addItems(static_cast<std::int64_t>(map.size()));
        ctx.addCounter("cache_records", static_cast<std::int64_t>(recordCount));
        for (std::size_t pass = 0; pass < placement.recordsPerPass.size(); ++pass)
            ctx.addCounter("records_pass_" + std::to_string(pass + 1), static_cast<std::int64_t>(placement.recordsPerPass[pass]));
        ctx.addCounter("undercovered_pixels", static_cast<std::int64_t>(placement.undercoveredPixels.size()));
        ctx.addCounter("uncached_vertices", std::count(uncached.begin(), uncached.end(), std::uint8_t{1}));
    }
};

}  // namespace

PassRegistration radianceCachePass() {
    PassSpec spec;
    spec.name = "radiance_cache";
    spec.doc = "Radiance caching in image space (Herzog et al. 2007, §8.3; Gautron et al. 2005): records at pixels of "
               "ever finer grids take the radiance map's SH coefficients and harmonic mean distance; every mapped "
               "vertex gets the Ward-weighted mean of the records valid at it";
    spec.inputs = {
        {"eye_vertices", "EyeVertices", "the vertices the map was splatted onto"},
        {"radiance_map", "RadianceMap", "SH coefficients of every eye vertex (ray_splat lambertian = sh_map)"},
    };
    spec.outputs = {
        {"cached_map", "RadianceMap", "the map's vertices with the coefficients interpolated from the cache records"},
        {"cache_records", "CacheRecords", "the records: position, normal, radius R_k, pixel, SH coefficients"},
    };
    spec.params = {
        {"error", ParamType::Float, 0.7, 0.01, 1.0, {},
         "ε: a record is used where its Ward weight exceeds 1/ε (smaller: more, smaller records)"},
        {"grid", ParamType::Int, std::int64_t{32}, 1, 4096, {}, "pixel spacing of the first placement pass"},
        {"passes", ParamType::Int, std::int64_t{3}, 1, 12, {},
         "placement passes; each halves the grid spacing (at least 1 pixel)"},
        {"min_records", ParamType::Int, std::int64_t{4}, 1, 64, {},
         "records a pixel should be covered by; grid pixels covered by fewer get a record in the next pass"},
        {"max_radius", ParamType::Float, 0.25, 1e-4, 10.0, {},
         "bound on a record's radius R_k as a fraction of the scene diagonal (also the radius where no ray arrived)"},
    };
    const auto preflight = [](const PreflightContext& pf) {
        const auto grid = pf.params.getInt("grid");
        const auto passes = pf.params.getInt("passes");
        if ((grid >> (passes - 1)) < 1)
            throw InputError(pf.source + ": pass '" + pf.instance + "': grid " + std::to_string(grid) + " cannot be halved " +
                             std::to_string(passes - 1) + " times; use a grid of at least " +
                             std::to_string(std::int64_t{1} << (passes - 1)) + " or fewer passes");
        if (const PassParams* splat = pf.producerParams("radiance_map");
            splat && pf.producerPass("radiance_map") == "ray_splat" && splat->getString("lambertian") != "sh_map")
            throw InputError(pf.source + ": pass '" + pf.instance +
                             "': the radiance cache serves every vertex from the radiance map; set [passes." +
                             "ray_splat] lambertian = \"sh_map\" so that Lambertian vertices are mapped too");
    };
    return {spec, [] { return std::make_unique<RadianceCachePass>(); }, preflight};
}

}  // namespace fg
