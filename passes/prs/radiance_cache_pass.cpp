// Radiance caching (`radiance_cache`): Herzog et al. 2007, §8.3, with the
// multi-pass image-space cache splatting of Gautron et al. 2005 and the
// weight of Ward et al. 1988, w_k(x) = 1 / (‖x − x_k‖ / R_k + √(1 − n·n_k)),
// record k used where w_k > 1/ε (passes/prs/radiance_cache.h). Two ways:
//
// Sparse (the records chosen before splatting, `placed_records` and
// `record_vertices` from cache_select): the photon rays were splatted onto
// the records' eye vertices alone (and onto the vertices no record is valid
// at), as §8.3's "sparse sampling in the image plane" allows. A record takes
// the coefficients splatted at its vertex; every eye vertex gets
// Σ w_k c_k / Σ w_k over the records valid at it, and a vertex no record is
// valid at its own splatted coefficients. The placement's parameters are
// cache_select's; this pass's placement parameters are not used.
//
// Dense (without those inputs): the radiance map holds every eye vertex
// (ray_splat lambertian = "sh_map"). A pixel's record sits at its first
// mapped eye vertex; its coefficients are the mean of the pixel's mapped
// vertices that the record is valid at, and its radius R_k the
// kernel-weighted harmonic mean distance over all of them, Σ w / Σ (w / d)
// from the map's sums, clamped to `max_radius` times the scene diagonal
// (pixels no ray reached get that bound). Vertices no record is valid at
// keep their own coefficients.
//
// Either way the output map has one entry per eye vertex the cache serves
// (sparse: every eye vertex, in eye order; dense: the input map's vertices,
// in its order), and radiance_integrate turns it into radiance (§8.1).
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
        if (ctx.hasInput("placed_records") || ctx.hasInput("record_vertices")) {
            runSparse(ctx);
            return;
        }
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

        const Camera camera = ctx.filmCamera();
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

private:
    static void runSparse(PassContext& ctx) {
        if (!ctx.hasInput("placed_records") || !ctx.hasInput("record_vertices"))
            throw std::logic_error("radiance_cache: placed_records and record_vertices come together (cache_select)");
        const EyeVertexBuffer::View eye = ctx.input<EyeVertices>("eye_vertices").vertices.view();
        const CacheRecords& placed = ctx.input<CacheRecords>("placed_records");
        const std::size_t splatVertexCount = ctx.input<EyeVertices>("record_vertices").vertices.size();
        const RadianceMapBuffer& map = ctx.input<RadianceMap>("radiance_map").vertices;
        const Camera camera = ctx.filmCamera();
        const std::size_t pixelCount = static_cast<std::size_t>(camera.width) * static_cast<std::size_t>(camera.height);
        const std::size_t recordCount = placed.records.size();
        if (recordCount > splatVertexCount)
            throw std::logic_error("radiance_cache: fewer record vertices than records");

        // The map's entry of every splat vertex: the records' vertices first, in record order.
        constexpr std::uint32_t kUnmapped = ~std::uint32_t(0);
        std::vector<std::uint32_t> entryOf(splatVertexCount, kUnmapped);
        const auto vertexOf = map.column<MapVertex>();
        for (std::size_t g = 0; g < map.size(); ++g) {
            if (vertexOf[g] >= splatVertexCount) throw std::logic_error("radiance_cache: map vertex outside the record vertices");
            entryOf[vertexOf[g]] = static_cast<std::uint32_t>(g);
        }
        if (std::find(entryOf.begin(), entryOf.end(), kUnmapped) != entryOf.end())
            throw std::logic_error("radiance_cache: a record vertex is not in the radiance map (ray_splat glossy and "
                                   "lambertian must both be sh_map)");
        const auto columns = radianceMapShColumns(map);
        const auto coefficientsAt = [&](std::uint32_t splatVertex) {
            CacheCoefficientArray c;
            for (std::size_t k = 0; k < c.size(); ++k) c[k] = columns[k][entryOf[splatVertex]];
            return c;
        };

        CacheRecords& cache = ctx.createOutput<CacheRecords>("cache_records");
        cache.error = placed.error;
        cache.records.resize(recordCount);
        for (std::size_t k = 0; k < recordCount; ++k) {
            CacheRecordBuffer::Record record = placed.records.get(k);
            record.get<CacheCoefficients>() = coefficientsAt(static_cast<std::uint32_t>(k));
            cache.records.set(k, record);
        }
        const auto recordPosition = cache.records.column<CachePosition>();
        const auto recordNormal = cache.records.column<CacheNormal>();
        const auto recordRadius = cache.records.column<CacheRadius>();
        const auto recordCoefficients = cache.records.column<CacheCoefficients>();
        std::vector<PixelWindow> windows(recordCount);
        jobs::parallelFor(recordCount, 64, [&](std::size_t k) {
            windows[k] = recordWindow(camera, recordPosition[k], placed.error * recordRadius[k]);
        });
        const CacheRecordLookup lookup(recordPosition, recordNormal, recordRadius, windows, camera.height, placed.error);
        const bool useGradients = ctx.params().getString("gradients") == "neighbours";
        const std::vector<CacheGradientArray> gradients =
            useGradients ? neighbourGradients(recordPosition, recordNormal, recordRadius, recordCoefficients, placed.error)
                         : std::vector<CacheGradientArray>{};

        const auto pixelOf = eye.column<EyePixel>();
        const auto positionOf = eye.column<EyePosition>();
        const auto normalOf = eye.column<EyeNormal>();
        RadianceMap& cached = ctx.createOutput<RadianceMap>("cached_map");
        cached.vertices.resize(eye.size());
        const auto cachedColumns = radianceMapShColumns(cached.vertices);
        const auto cachedVertex = cached.vertices.column<MapVertex>();
        std::vector<std::uint8_t> uncached(eye.size(), 0);
        jobs::parallelFor(eye.size(), 1024, [&](std::size_t v) {
            if (pixelOf[v] >= pixelCount) throw std::logic_error("radiance_cache: eye vertex outside the film");
            cachedVertex[v] = static_cast<std::uint32_t>(v);
            const int x = static_cast<int>(pixelOf[v] % static_cast<std::uint32_t>(camera.width));
            const int y = static_cast<int>(pixelOf[v] / static_cast<std::uint32_t>(camera.width));
            CacheCoefficientArray c;
            if (!interpolateCache(
                    lookup, recordPosition, x, y, positionOf[v], normalOf[v],
                    [&](std::uint32_t k) -> const CacheCoefficientArray& { return recordCoefficients[k]; },
                    [&](std::uint32_t k) -> const CacheGradientArray* { return useGradients ? &gradients[k] : nullptr; },
                    c)) {
                uncached[v] = 1;
                return;
            }
            for (std::size_t i = 0; i < c.size(); ++i) cachedColumns[i][v] = c[i];
        });
        // The vertices no record is valid at were splatted directly, after the records' vertices, in eye order.
        std::size_t fallback = recordCount;
        for (std::size_t v = 0; v < eye.size(); ++v) {
            if (!uncached[v]) continue;
            if (fallback >= splatVertexCount)
                throw std::logic_error("radiance_cache: more vertices outside every record than cache_select splatted");
            const CacheCoefficientArray c = coefficientsAt(static_cast<std::uint32_t>(fallback++));
            for (std::size_t i = 0; i < c.size(); ++i) cachedColumns[i][v] = c[i];
        }
        if (fallback != splatVertexCount)
            throw std::logic_error("radiance_cache: fewer vertices outside every record than cache_select splatted");

        ctx.addItems(static_cast<std::int64_t>(eye.size()));
        ctx.addCounter("cache_records", static_cast<std::int64_t>(recordCount));
        ctx.addCounter("uncached_vertices", static_cast<std::int64_t>(splatVertexCount - recordCount));
    }
};

}  // namespace

PassRegistration radianceCachePass() {
    PassSpec spec;
    spec.name = "radiance_cache";
    spec.doc = "Radiance caching in image space (Herzog et al. 2007, §8.3; Gautron et al. 2005): records take the "
               "radiance map's SH coefficients (placed by cache_select before splatting, or here at pixels of ever "
               "finer grids with the map's harmonic mean distance); every vertex gets the Ward-weighted mean of the "
               "records valid at it";
    spec.inputs = {
        {"eye_vertices", "EyeVertices", "every eye vertex (sparse) or the vertices the map was splatted onto (dense)"},
        {"radiance_map", "RadianceMap",
         "SH coefficients splatted at every eye vertex (ray_splat lambertian = sh_map), or at the record_vertices"},
        {"placed_records", "CacheRecords", "records chosen before splatting (cache_select); absent: placed here", false,
         true},
        {"record_vertices", "EyeVertices",
         "the vertices the map was splatted onto when the records were chosen before (cache_select)", false, true},
    };
    spec.outputs = {
        {"cached_map", "RadianceMap",
         "coefficients interpolated from the cache records at every eye vertex (sparse) or at the map's vertices (dense)"},
        {"cache_records", "CacheRecords", "the records: position, normal, radius R_k, pixel, SH coefficients"},
    };
    spec.params = placementParams();
    spec.params.insert(spec.params.end(), {
        {"gradients", ParamType::String, std::string("none"), 0, 0, {"none", "neighbours"},
         "with records chosen before splatting: interpolate c_k alone, or c_k + g_k·(x − x_k) with g_k fitted by "
         "least squares to the neighbouring records (exact for linear fields)"},
        {"max_radius", ParamType::Float, 0.25, 1e-4, 10.0, {},
         "bound on a record's radius R_k as a fraction of the scene diagonal (also the radius where no ray arrived)"},
    });
    const auto preflight = [](const PreflightContext& pf) {
        checkPlacementGrid(pf);
        const PassParams* splat = pf.producerParams("radiance_map");
        if (!splat || pf.producerPass("radiance_map") != "ray_splat") return;
        if (splat->getString("lambertian") != "sh_map")
            throw InputError(pf.source + ": pass '" + pf.instance +
                             "': the radiance cache serves every vertex from the radiance map; set [passes." +
                             "ray_splat] lambertian = \"sh_map\" so that Lambertian vertices are mapped too");
        if (!pf.producerPass("placed_records").empty() && splat->getString("glossy") != "sh_map")
            throw InputError(pf.source + ": pass '" + pf.instance +
                             "': with records chosen before splatting, glossy vertices are served from the radiance "
                             "map as well; set [passes.ray_splat] glossy = \"sh_map\"");
    };
    return {spec, [] { return std::make_unique<RadianceCachePass>(); }, preflight};
}

}  // namespace fg
