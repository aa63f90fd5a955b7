// Photon gathering (standard photon mapping, SPM; Jensen 1996): at every eye
// vertex the k nearest photons of a map give the reflected radiance by
// Frisvad et al. 2014 Eq. 10 with the isotropic filter M_p = I / h, where the
// bandwidth h is the distance to the k-th nearest photon:
//
//   L(x, w) = sum_p f_r(x, w_p, w) Phi_p K(|x - x_p| / h) / h^2
//
// with Silverman's second-order kernel K (Eq. 11) — Eq. 10's pi K f_r E_p with
// E_p = Phi_p / (pi h^2). When fewer than k photons lie within max_radius the
// search disk itself is the support: h = max_radius. f_r is Bsdf::eval divided
// by |cos theta_i| (eval includes the cosine; the photon density is already
// flux per area). For a uniform Poisson photon density the k-th-neighbour
// kernel estimate is unbiased: the k-1 inner photons average K = 1/pi over
// the disk and E[1 / (pi h^2)] = density / (k - 1).
//
// Two registrations share the code:
//  - `gather` (the spm pipeline): caustic and global maps, each with its own k;
//  - `gather_global` (the pds pipeline): the global map only, while the
//    caustics come from splatting — the paper's comparison setting, photon
//    differential splatting for caustics and a photon map for the rest.
//
// Output: one radiance layer per map (`caustic`, `global`), each a film from
// black holding, per pixel, the sum over the pixel's vertices of throughput x
// that map's estimate; the composite pass adds them to the direct light.
// Estimates are computed in parallel per vertex and summed into pixels in
// vertex order, so the layers do not depend on the thread count.
#include "passes/passes.h"
#include "passes/caustics/photon_estimate.h"

#include "engine/image/film.h"
#include "engine/buffers/photon_buffers.h"
#include "engine/scene/scene.h"
#include "jobs/parallel.h"

#include <atomic>
#include <limits>
#include <string>

namespace fg {

namespace {

class PhotonGatherPass final : public Pass {
public:
    explicit PhotonGatherPass(bool withCaustics) : withCaustics_(withCaustics) {}

    void run(PassContext& ctx) override {
        const Scene& scene = ctx.scene();
        const EyeVertices& eyeVertices = ctx.input<EyeVertices>("eye_vertices");
        const double maxRadiusParam = ctx.params().getFloat("max_radius");
        const float maxRadius = maxRadiusParam > 0.0 ? static_cast<float>(maxRadiusParam)
                                                     : std::numeric_limits<float>::infinity();

        std::vector<GatherSource> sources;
        if (withCaustics_) {
            sources.push_back({ctx.input<PhotonMap>("caustic_photons"), ctx.input<PointIndex>("caustic_index"),
                               static_cast<std::size_t>(ctx.params().getInt("k_caustic")), "caustic"});
        }
        sources.push_back({ctx.input<PhotonMap>("global_photons"), ctx.input<PointIndex>("global_index"),
                           static_cast<std::size_t>(ctx.params().getInt("k_global")), "global"});
        std::size_t maxK = 0;
        for (const GatherSource& s : sources) maxK = std::max(maxK, s.k);

        const EyeVertexBuffer::View eye = eyeVertices.vertices.view();
        const auto throughput = eye.column<EyeThroughput>();
        const auto pixelOf = eye.column<EyePixel>();
        const std::size_t vertexCount = eye.size();
        const std::size_t sourceCount = sources.size();
        // contribution[v * sourceCount + s]: vertex v's radiance from map s.
        std::vector<Rgb> contribution(vertexCount * sourceCount, Rgb(0.0f));
        std::atomic<std::int64_t> photonsUsed{0};
        jobs::parallelForChunks(vertexCount, 256, [&](jobs::IndexRange range) {
            std::vector<std::uint32_t> ids(maxK);
            std::vector<float> dist2(maxK);
            std::int64_t used = 0;
            for (std::size_t v = range.begin; v != range.end; ++v) {
                const VertexBrdf brdf(scene, eye, v);
                for (std::size_t s = 0; s < sourceCount; ++s) {
                    const Rgb L = gatherRadiance(eye.column<EyePosition>()[v], brdf, sources[s], maxRadius, ids, dist2, used);
                    const Rgb value = L * throughput[v];
                    contribution[v * sourceCount + s] = isFinite(value) ? value : Rgb(0.0f);
                }
            }
            photonsUsed += used;
        });

        for (std::size_t s = 0; s < sourceCount; ++s) {
            Film& layer = ctx.createOutput<Film>(sources[s].layer, ctx.filmSettings());
            std::vector<Rgb> perPixel(layer.pixelCount(), Rgb(0.0f));
            for (std::size_t v = 0; v < vertexCount; ++v) {
                if (pixelOf[v] >= perPixel.size()) throw std::logic_error("gather: eye vertex outside the film");
                perPixel[pixelOf[v]] += contribution[v * sourceCount + s];
            }
            layer.addToPixels(perPixel, 1.0f);
        }
        ctx.addItems(static_cast<std::int64_t>(vertexCount));
        ctx.addCounter("photon_contributions", photonsUsed.load());
    }

private:
    bool withCaustics_;
};

ParamSpec maxRadiusParam() {
    return {"max_radius", ParamType::Float, 0.0, 0.0, 1e30, {},
            "largest gather radius in scene units; with fewer than k photons inside, it is the bandwidth "
            "(0 = unlimited)"};
}
ParamSpec kGlobalParam() {
    return {"k_global", ParamType::Int, std::int64_t{100}, 1, 1 << 16, {},
            "nearest global photons per estimate; the k-th one's distance is the bandwidth h"};
}

// One film per radiance layer; the estimates are written straight into them.
std::function<MemoryEstimate(const PreflightContext&)> layerFilms(int layers) {
    return [layers](const PreflightContext& pf) {
        return MemoryEstimate{multiplyBytes(filmBytes(pf.film), static_cast<std::uint64_t>(layers)),
                              std::to_string(layers) + " film(s) " + std::to_string(pf.film.width) + " x " +
                                  std::to_string(pf.film.height),
                              {}};
    };
}

}  // namespace

PassRegistration gatherPass() {
    PassSpec spec;
    spec.name = "gather";
    spec.doc = "Standard photon mapping at the eye vertices: k nearest caustic and global photons, Silverman kernel, "
               "bandwidth = k-th neighbour distance, one radiance layer per map";
    spec.inputs = {
        {"eye_vertices", "EyeVertices", "where radiance is estimated, with pixel and throughput"},
        {"caustic_photons", "PhotonMap", "caustic photons (L S+ D)"},
        {"global_photons", "PhotonMap", "global photons (at least one diffuse bounce)"},
        {"caustic_index", "PointIndex", "search structure over caustic_photons"},
        {"global_index", "PointIndex", "search structure over global_photons"},
    };
    spec.outputs = {
        {"caustic", "Film", "caustic photon estimates alone (a film from black)"},
        {"global", "Film", "global photon estimates alone (a film from black)"},
    };
    spec.params = {
        {"k_caustic", ParamType::Int, std::int64_t{50}, 1, 1 << 16, {},
         "nearest caustic photons per estimate; the k-th one's distance is the bandwidth h"},
        kGlobalParam(),
        maxRadiusParam(),
    };
    return {spec, [] { return std::make_unique<PhotonGatherPass>(true); }, {}, layerFilms(2)};
}

PassRegistration gatherGlobalPass() {
    PassSpec spec;
    spec.name = "gather_global";
    spec.doc = "Standard photon mapping of the global map only (indirect light without caustics), as its own "
               "radiance layer";
    spec.inputs = {
        {"eye_vertices", "EyeVertices", "where radiance is estimated, with pixel and throughput"},
        {"global_photons", "PhotonMap", "global photons (at least one diffuse bounce)"},
        {"global_index", "PointIndex", "search structure over global_photons"},
    };
    spec.outputs = {{"global", "Film", "global photon estimates alone (a film from black)"}};
    spec.params = {kGlobalParam(), maxRadiusParam()};
    return {spec, [] { return std::make_unique<PhotonGatherPass>(false); }, {}, layerFilms(1)};
}

}  // namespace fg
