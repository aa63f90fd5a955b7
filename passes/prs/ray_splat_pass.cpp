// Photon ray splatting (`ray_splat`): Herzog et al. 2007, "Global
// Illumination using Photon Ray Splatting", §4-5 (density estimation in ray
// space, Eqs. 3-6 read as in passes/prs/ray_splat.h) and §7.2 (the frustum
// traversal of Algorithm 1 over the splat kd-tree). Each photon ray, with the
// frustum ray_bandwidth gave it (§6), adds f_s Phi |cos theta_x| K_R(d_perp)
// to the pixel of every feasible eye vertex near it. f_s is evaluated at the
// vertex directly (Eq. 6): a Lambertian vertex's f_s is one constant, so its
// light goes straight to the film. Glossy vertices are either evaluated per
// ray here (`glossy = "direct"`) or, as §5 and §8.1 do, get the rays'
// light projected onto spherical harmonics in a radiance map
// (`glossy = "sh_map"`, passes/prs/sh_radiance.h) that radiance_integrate
// turns into radiance. With `lambertian = "sh_map"` the Lambertian vertices
// go into the map as well, so that the radiance cache (§8.3) serves every
// vertex. Each map entry also sums the kernel weights over the distance to
// the rays' origins: the harmonic mean distance that sizes cache records.
// Rays are splatted in fixed blocks into per-block films merged in block
// order, so the image is the same for any thread count.
#include "passes/passes.h"
#include "passes/caustics/photon_estimate.h"
#include "passes/prs/ray_splat.h"
#include "passes/prs/sh_radiance.h"

#include "engine/buffers/photon_buffers.h"
#include "engine/buffers/photon_ray_buffers.h"
#include "engine/core/error.h"
#include "engine/image/film.h"
#include "engine/scene/scene.h"
#include "jobs/parallel.h"

#include <algorithm>
#include <array>
#include <optional>
#include <span>
#include <tuple>
#include <utility>
#include <vector>

namespace fg {

namespace {

// Memory for the per-block films; at least one block, at most 64.
constexpr std::size_t kAccumulatorBudget = std::size_t{256} << 20;

struct BlockFilm {
    std::vector<Rgb> pixels;
    std::vector<sh::Coefficients<Rgb>> map;  // per glossy vertex (glossy = "sh_map")
    std::vector<float> mapWeights;
    std::vector<float> mapInverseDistances;
    std::int64_t deposits = 0;
    std::int64_t candidates = 0;
    std::int64_t splatted = 0;
};

class RaySplatPass final : public Pass {
public:
    void run(PassContext& ctx) override {
        const Scene& scene = ctx.scene();
        const EyeVertexBuffer::View eye = ctx.input<EyeVertices>("eye_vertices").vertices.view();
        const SplatIndex& index = ctx.input<SplatIndex>("splat_index");
        const PhotonRays& photonRays = ctx.input<PhotonRays>("splat_rays");
        if (!photonRays.hasBandwidths) throw std::logic_error("ray_splat: the rays carry no bandwidths");
        if (index.tree.size() != eye.size()) throw std::logic_error("ray_splat: the index was not built from these eye vertices");
        const SplatEndCap cap = ctx.params().getString("end_cap") == "hemisphere" ? SplatEndCap::Hemisphere
                                                                                  : SplatEndCap::TangentPlane;
        const bool withDirect = ctx.params().getString("classes") == "all";
        const bool useCullNodes = ctx.params().getBool("cull_nodes");
        const bool shMap = ctx.params().getString("glossy") == "sh_map";
        const bool lambertianToMap = ctx.params().getString("lambertian") == "sh_map";

        Film& image = ctx.createOutput<Film>("radiance", ctx.filmSettings());
        const std::size_t pixelCount = image.pixelCount();
        for (std::uint32_t pixel : eye.column<EyePixel>())
            if (pixel >= pixelCount) throw std::logic_error("ray_splat: eye vertex outside the film");
        prepareTargets(scene, eye, index.tree, shMap, lambertianToMap);
        const std::size_t glossyCount = glossyVertices_.size();

        const PhotonRayBuffer& rays = photonRays.rays;
        const auto origin = rays.column<RayOrigin>();
        const auto direction = rays.column<RayDirection>();
        const auto length = rays.column<RayLength>();
        const auto power = rays.column<RayPower>();
        const auto h0 = rays.column<RayH0>();
        const auto dh = rays.column<RayDh>();
        const auto rayClass = rays.column<RayClassColumn>();
        const auto originNormal = rays.column<RayOriginNormal>();
        const auto endNormal = rays.column<RayEndNormal>();

        const std::size_t blockBytes = std::max<std::size_t>(
            1, pixelCount * sizeof(Rgb) + glossyCount * (sizeof(sh::Coefficients<Rgb>) + 2 * sizeof(float)));
        std::vector<BlockFilm> blocks(std::clamp<std::size_t>(kAccumulatorBudget / blockBytes, 1, 64));
        jobs::parallelForBlocks(rays.size(), blocks.size(), [&](std::size_t b, jobs::IndexRange range) {
            BlockFilm& acc = blocks[b];
            acc.pixels.assign(pixelCount, Rgb(0.0f));
            if (glossyCount > 0) {
                sh::Coefficients<Rgb> zero;
                zero.fill(Rgb(0.0f));
                acc.map.assign(glossyCount, zero);
                acc.mapWeights.assign(glossyCount, 0.0f);
                acc.mapInverseDistances.assign(glossyCount, 0.0f);
            }
            for (std::size_t r = range.begin; r != range.end; ++r) {
                if (rayClass[r] == PhotonRayClass::Direct && !withDirect) continue;
                const SplatRay ray{origin[r], direction[r], h0[r], dh[r], length[r], originNormal[r], endNormal[r]};
                if (!(ray.h0 > 0.0f || ray.dh > 0.0f)) continue;
                ++acc.splatted;
                const Vec3 incident = -ray.direction;
                const SplatFrustum frustum(ray, cap);
                // Every deposit of a ray arrives from the same direction, so
                // Phi Y_lm(incident) is worked out once per ray and a deposit
                // adds it times its weight: 48 independent multiply-adds the
                // compiler can vectorise.
                std::array<float, 3 * sh::kCoefficients> poweredBasis{};
                if (glossyCount > 0) {
                    float y[sh::kCoefficients];
                    sh::evaluate(incident, y);
                    for (std::size_t k = 0; k < sh::kCoefficients; ++k)
                        for (int channel = 0; channel < 3; ++channel)
                            poweredBasis[3 * k + static_cast<std::size_t>(channel)] = power[r][channel] * y[k];
                }
                index.tree.forEachCandidate(
                    splatCone(ray, cap),
                    [&](std::uint32_t slot) {
                        ++acc.candidates;
                        const Vec3& position = index.tree.slotPosition(slot);
                        const float weight = frustum.weight(position, index.tree.slotNormal(slot));
                        if (!(weight > 0.0f)) return;
                        const Target& target = targets_[slot];
                        Rgb f;
                        if (target.glossy != kNotGlossy) {
                            // Shading normals must not let light through the geometric surface.
                            if (!(glm::dot(incident, target.geometricNormal) > 0.0f)) return;
                            const Rgb value = power[r] * weight;
                            if (!isFinite(value)) return;
                            sh::Coefficients<Rgb>& c = acc.map[target.glossy];
                            for (std::size_t k = 0; k < sh::kCoefficients; ++k) {
                                c[k].x += weight * poweredBasis[3 * k];
                                c[k].y += weight * poweredBasis[3 * k + 1];
                                c[k].z += weight * poweredBasis[3 * k + 2];
                            }
                            acc.mapWeights[target.glossy] += weight;
                            // Feasible vertices lie in front of the origin's surface, so the distance is positive.
                            const float distance = glm::length(position - ray.origin);
                            if (distance > 0.0f) acc.mapInverseDistances[target.glossy] += weight / distance;
                            ++acc.deposits;
                            return;
                        }
                        if (target.lambertian) {
                            if (!(glm::dot(incident, target.geometricNormal) > 0.0f)) return;
                            f = target.weight;
                        } else {
                            f = VertexBrdf(scene, eye, target.vertex)(incident) *
                                eye.column<EyeThroughput>()[target.vertex];
                        }
                        const Rgb value = f * power[r] * weight;
                        if (!isFinite(value)) return;
                        acc.pixels[target.pixel] += value;
                        ++acc.deposits;
                    },
                    useCullNodes);
            }
        });
        std::vector<Rgb> total(pixelCount, Rgb(0.0f));
        RadianceMap& map = ctx.createOutput<RadianceMap>("radiance_map");
        map.vertices.resize(glossyCount);
        std::vector<sh::Coefficients<Rgb>> mapTotal(glossyCount);
        for (sh::Coefficients<Rgb>& c : mapTotal) c.fill(Rgb(0.0f));
        std::vector<float> weightTotal(glossyCount, 0.0f);
        std::vector<float> inverseDistanceTotal(glossyCount, 0.0f);
        std::int64_t deposits = 0, candidates = 0, splatted = 0;
        for (const BlockFilm& block : blocks) {
            for (std::size_t i = 0; i < block.pixels.size(); ++i) total[i] += block.pixels[i];
            for (std::size_t g = 0; g < block.map.size(); ++g) {
                for (int k = 0; k < sh::kCoefficients; ++k)
                    mapTotal[g][static_cast<std::size_t>(k)] += block.map[g][static_cast<std::size_t>(k)];
                weightTotal[g] += block.mapWeights[g];
                inverseDistanceTotal[g] += block.mapInverseDistances[g];
            }
            deposits += block.deposits;
            candidates += block.candidates;
            splatted += block.splatted;
        }
        image.addToPixels(total, 1.0f);
        storeMap(map.vertices, mapTotal, weightTotal, inverseDistanceTotal);
        ctx.addItems(static_cast<std::int64_t>(rays.size()));
        ctx.addCounter("splatted_rays", splatted);
        ctx.addCounter("vertex_candidates", candidates);
        ctx.addCounter("vertex_deposits", deposits);
    }

private:
    // What a deposit needs of its eye vertex, in tree order. At a Lambertian
    // vertex f_s times the throughput is one constant (rho / pi) T:
    // Bsdf::constantReflectance is f_r itself, rho / pi already.
    static constexpr std::uint32_t kNotGlossy = ~std::uint32_t(0);
    struct Target {
        Vec3 geometricNormal{0.0f};
        Rgb weight{0.0f};
        std::uint32_t pixel = 0;
        std::uint32_t vertex = 0;
        std::uint32_t glossy = kNotGlossy;  // index into the radiance map (glossy = "sh_map")
        bool lambertian = false;
    };

    void storeMap(RadianceMapBuffer& out, const std::vector<sh::Coefficients<Rgb>>& coefficients,
                  const std::vector<float>& weights, const std::vector<float>& inverseDistances) const {
        const auto columns = radianceMapShColumns(out);
        const auto vertex = out.column<MapVertex>();
        const auto weightSum = out.column<MapWeightSum>();
        const auto inverseDistanceSum = out.column<MapInverseDistanceSum>();
        for (std::size_t g = 0; g < glossyVertices_.size(); ++g) {
            vertex[g] = glossyVertices_[g];
            weightSum[g] = weights[g];
            inverseDistanceSum[g] = inverseDistances[g];
            for (std::size_t k = 0; k < sh::kCoefficients; ++k) columns[k][g] = coefficients[g][k];
        }
    }

    void prepareTargets(const Scene& scene, const EyeVertexBuffer::View& eye, const SplatKdTree& tree, bool shMap,
                        bool lambertianToMap) {
        targets_.assign(eye.size(), Target{});
        jobs::parallelFor(eye.size(), 4096, [&](std::size_t slot) {
            Target& t = targets_[slot];
            const std::uint32_t v = tree.vertexOf(static_cast<std::uint32_t>(slot));
            const EyeVertexBuffer::Record vertex = eye.get(v);
            t.vertex = v;
            t.pixel = vertex.get<EyePixel>();
            t.geometricNormal = vertex.get<EyeGeometricNormal>();
            const std::optional<Rgb> reflectance =
                scene.bsdfs[vertex.get<EyeBsdf>()]->constantReflectance(vertex.get<EyeUv>());
            if (!reflectance) return;
            t.lambertian = true;
            // Seen from below its shading normal, a Lambertian surface reflects nothing.
            if (glm::dot(vertex.get<EyeOutgoing>(), vertex.get<EyeNormal>()) > 0.0f)
                t.weight = *reflectance * vertex.get<EyeThroughput>();
        });
        // Map entries in tree order, numbered serially: the same for any thread count.
        glossyVertices_.clear();
        if (!shMap && !lambertianToMap) return;
        for (Target& t : targets_) {
            if (t.lambertian ? !lambertianToMap : !shMap) continue;
            t.glossy = static_cast<std::uint32_t>(glossyVertices_.size());
            glossyVertices_.push_back(t.vertex);
        }
    }

    std::vector<Target> targets_;
    std::vector<std::uint32_t> glossyVertices_;
};

}  // namespace

PassRegistration raySplatPass() {
    PassSpec spec;
    spec.name = "ray_splat";
    spec.doc = "Photon ray splatting (Herzog et al. 2007, §4-5, §7.2): every photon ray splats f_s Phi cos K_R(d_perp) "
               "onto the eye vertices in its conical frustum, as a radiance layer";
    spec.inputs = {
        {"eye_vertices", "EyeVertices", "the vertices rays splat to, with pixel and throughput"},
        {"splat_index", "SplatIndex", "splat kd-tree over eye_vertices"},
        {"splat_rays", "PhotonRays", "photon rays with bandwidths (ray_bandwidth)"},
    };
    spec.outputs = {
        {"radiance", "Film", "the splatted indirect light alone (a film from black); glossy vertices only with glossy = direct"},
        {"radiance_map", "RadianceMap",
         "per mapped eye vertex (glossy ones with glossy = sh_map, Lambertian ones with lambertian = sh_map) the SH "
         "coefficients (order 3, world frame, cos folded in) of the splatted light, its kernel-weight sum and "
         "inverse-distance sum"},
    };
    spec.params = {
        {"end_cap", ParamType::String, std::string("tangent_plane"), 0, 0, {"tangent_plane", "hemisphere"},
         "footprint beyond the hit point: the paper's hemisphere (biased at oblique incidence) or the cylinder "
         "cut by the hit's tangent plane (exact on planes)"},
        {"classes", ParamType::String, std::string("indirect"), 0, 0, {"indirect", "all"},
         "which rays splat: indirect (caustic and global; the eye pass has the direct light) or all"},
        {"cull_nodes", ParamType::Bool, true, 0, 0, {}, "use the index's backface-culling nodes"},
        {"glossy", ParamType::String, std::string("direct"), 0, 0, {"direct", "sh_map"},
         "glossy vertices: f_s evaluated per ray (Eq. 6) into the film, or projected into the SH radiance map for "
         "radiance_integrate (§8.1)"},
        {"lambertian", ParamType::String, std::string("film"), 0, 0, {"film", "sh_map"},
         "Lambertian vertices: straight into the film, or into the SH radiance map too, for the radiance cache (§8.3)"},
    };
    const auto preflight = [](const PreflightContext& pf) {
        if (!pf.scene.media.empty())
            throw InputError(pf.source + ": pass '" + pf.instance +
                             "': photon ray splatting traces rays between surfaces only; the scene has participating media");
    };
    const auto memory = [](const PreflightContext& pf) {
        const std::uint64_t image =
            multiplyBytes(static_cast<std::uint64_t>(pf.film.width) * static_cast<std::uint64_t>(pf.film.height), sizeof(Rgb));
        const std::uint64_t blocks = std::clamp<std::uint64_t>(kAccumulatorBudget / std::max<std::uint64_t>(image, 1), 1, 64);
        return MemoryEstimate{addBytes(addBytes(filmBytes(pf.film), image), multiplyBytes(image, blocks)),
                              std::to_string(blocks) + " splat accumulators", {}};
    };
    return {spec, [] { return std::make_unique<RaySplatPass>(); }, preflight, memory};
}

}  // namespace fg
