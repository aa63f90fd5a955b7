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
// When no mapped vertex is glossy, the map keeps only c_00 (`map_bands =
// "used"`): §8.1 represents a Lambertian BRDF by that one coefficient,
// radiance_integrate reads nothing else of a Lambertian vertex, and
// radiance_cache interpolates each coefficient on its own, so the other 15
// would be summed for no reader (16 multiply-adds of three channels per
// deposit instead of one; the image is bit for bit the same).
// The kd search (`traversal = "tight_boxes"`, SplatKdTree::forEachLeafNearCone)
// enters nodes by their vertices' tight boxes rather than Algorithm 1's cells,
// four subtrees' boxes at a time (the binary tree collapsed into four-wide nodes),
// and the leaves' vertices are weighed from the tree's coordinate columns
// four at a time (SplatFrustum::weights, bit for bit SplatFrustum::weight),
// in Algorithm 1's order: the same deposits in the same order, so the same
// image bit for bit (`"cells"` keeps Algorithm 1 and weighs one candidate at
// a time). Its vertex_candidates are the leaf vertices weighed.
// `footprint = "sphere"` splats a sphere of radius R(t_hit) around each hit
// instead (§9 times the frustum against it). `origin_boundary =
// "renormalise"` divides a deposit's kernel by its share in front of the
// surface the ray leaves (SplatFrustum::originBoundaryGain): beside a
// concave corner's adjacent wall the paper's kernel averages over a disk
// partly behind that wall, where no ray of it can be. `slices = "hit_plane"`
// reads the growing radius where the plane through the vertex parallel to
// the hit's tangent plane crosses the ray (ray_splat.h), so that a ray's
// deposits on the surface it meets add up to its flux. Both corrections are
// the defaults (on the Cornell box they take the indirect light's mean error
// from -1.17 % to -0.64 %, README "Concave corners"); `slices =
// "perpendicular"`, `origin_boundary = "cut"` and `end_cap = "hemisphere"`
// give the paper's estimator.
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

// SplatFrustum::weights, out of line here for the reason ray_splat.h gives.
// Clang 14 names a cloned function's dispatcher so that callers in other
// translation units do not find it; its builds (sanitizers, fuzzing) take
// the baseline code, which gives the same bits.
#if defined(__clang__)
#define FG_SPLAT_WEIGHT_CLONES
#else
#define FG_SPLAT_WEIGHT_CLONES [[gnu::target_clones("avx2", "default")]]
#endif
FG_SPLAT_WEIGHT_CLONES void SplatFrustum::weights(const SplatVertexColumns& vertices, std::uint32_t first,
                                                                     std::uint32_t count, float* out) const {
    const float ox = origin.x, oy = origin.y, oz = origin.z;
    const float dx = direction.x, dy = direction.y, dz = direction.z;
    const float onx = originNormal.x, ony = originNormal.y, onz = originNormal.z;
    const float enx = endNormal.x, eny = endNormal.y, enz = endNormal.z;
    const float ex = end.x, ey = end.y, ez = end.z;
    const int hemisphere = cap == SplatEndCap::Hemisphere ? 1 : 0;
    const int anyOriginSide = hasOriginSurface ? 0 : 1;
    const int sliced = hitPlaneSlices ? 1 : 0;
    const float hitPlaneLimit = -tolerance;
    const float* xs = vertices.x + first;
    const float* ys = vertices.y + first;
    const float* zs = vertices.z + first;
    const float* nxs = vertices.nx + first;
    const float* nys = vertices.ny + first;
    const float* nzs = vertices.nz + first;
    for (std::uint32_t k = 0; k < count; ++k) {
        const float x = xs[k] - ox, y = ys[k] - oy, z = zs[k] - oz;
        const float tp = x * dx + y * dy + z * dz;
        const float px = x - tp * dx, py = y - tp * dy, pz = z - tp * dz;
        const float d2 = px * px + py * py + pz * pz;
        const float hx = xs[k] - ex, hy = ys[k] - ey, hz = zs[k] - ez;
        const float hitSide = hx * enx + hy * eny + hz * enz;
        const float slice = std::min(std::max(length - hitSide * inverseHitCosine, 0.0f), std::min(length, tp + shift));
        const float radius = maskedSelect(sliced, h0 + dh * slice, maskedSelect(tp <= length ? 1 : 0, h0 + dh * tp, hitRadius));
        const float r2 = radius * radius;
        const float cosine = -(dx * nxs[k] + dy * nys[k] + dz * nzs[k]);
        const float originSide = x * onx + y * ony + z * onz;
        const float hitDistance2 = hx * hx + hy * hy + hz * hz;
        const int insideCap = (hemisphere & (hitDistance2 > r2 ? 0 : 1)) |
                              ((hemisphere ^ 1) & (hitSide < hitPlaneLimit ? 0 : 1));
        const int feasible = (tp < 0.0f ? 0 : 1) & (tp > reach ? 0 : 1) & (radius > 0.0f ? 1 : 0) &
                             (d2 < r2 ? 1 : 0) & (cosine > 0.0f ? 1 : 0) &
                             (anyOriginSide | (originSide > 0.0f ? 1 : 0)) &
                             ((tp > length ? 0 : 1) | insideCap);
        const float weight = 2.0f * kInvPi / r2 * (1.0f - d2 / r2) * cosine;
        out[k] = maskedSelect(feasible, weight, 0.0f);
    }
}

FG_SPLAT_WEIGHT_CLONES void SplatSphere::weights(const SplatVertexColumns& vertices, std::uint32_t first,
                                                 std::uint32_t count, float* out) const {
    const float cx = centre.x, cy = centre.y, cz = centre.z;
    const float dx = direction.x, dy = direction.y, dz = direction.z;
    const float r2 = radius * radius;
    const int positive = radius > 0.0f ? 1 : 0;
    for (std::uint32_t k = 0; k < count; ++k) {
        const float x = vertices.x[first + k] - cx, y = vertices.y[first + k] - cy, z = vertices.z[first + k] - cz;
        const float d2 = x * x + y * y + z * z;
        const float facing = dx * vertices.nx[first + k] + dy * vertices.ny[first + k] + dz * vertices.nz[first + k];
        const int feasible = positive & (d2 < r2 ? 1 : 0) & (facing < 0.0f ? 1 : 0);
        out[k] = SplatFrustum::maskedSelect(feasible, 2.0f * kInvPi / r2 * (1.0f - d2 / r2), 0.0f);
    }
}

namespace {

// Memory for the per-block films; at least one block, at most 64.
constexpr std::size_t kAccumulatorBudget = std::size_t{256} << 20;

// What every mapped vertex sums, whichever bands the map keeps: 20 bytes
// side by side, so that a deposit touches one cache line where the
// coefficients of all bands span four.
struct MapSums {
    Rgb c00{0.0f};
    float weight = 0.0f;
    float inverseDistance = 0.0f;
};
using HigherBands = std::array<Rgb, sh::kCoefficients - 1>;  // c_1-1 ... c_33

struct BlockFilm {
    std::vector<Rgb> pixels;
    std::vector<MapSums> map;               // per mapped vertex
    std::vector<HigherBands> mapHigherBands;  // per mapped vertex, when the map keeps them
    std::int64_t deposits = 0;
    std::int64_t candidates = 0;
    std::int64_t leafVertices = 0;
    std::int64_t splatted = 0;
};

// The mean radius R(t_hit) at the hits of the rays that splat and meet a
// surface, in millionths of the scene diagonal: the bandwidth to compare
// with photon mapping's mean gather radius, as the paper chooses C for equal
// mean bandwidths (§9, Fig. 10). Summed in integers, so the figure does not
// depend on the order.
std::int64_t meanHitRadiusPpm(const Scene& scene, const SplatRayBuffer& rays, bool withDirect) {
    const auto h0 = rays.column<RayH0>();
    const auto dh = rays.column<RayDh>();
    const auto length = rays.column<RayLength>();
    const auto endNormal = rays.column<RayEndNormal>();
    const auto rayClass = rays.column<RayClassColumn>();
    const double scale = 1e6 / static_cast<double>(glm::length(scene.boundsMax - scene.boundsMin));
    std::int64_t sum = 0, count = 0;
    for (std::size_t r = 0; r < rays.size(); ++r) {
        if (rayClass[r] == PhotonRayClass::Direct && !withDirect) continue;
        const float radius = h0[r] + dh[r] * length[r];
        if (endNormal[r] == Vec3(0.0f) || !(radius > 0.0f)) continue;
        sum += std::llround(scale * static_cast<double>(radius));
        ++count;
    }
    return count > 0 ? sum / count : 0;
}

class RaySplatPass final : public Pass {
public:
    void run(PassContext& ctx) override {
        const Scene& scene = ctx.scene();
        const EyeVertexBuffer::View eye = ctx.input<EyeVertices>("eye_vertices").vertices.view();
        const SplatIndex& index = ctx.input<SplatIndex>("splat_index");
        const SplatRays& splatRays = ctx.input<SplatRays>("splat_rays");
        if (index.tree.size() != eye.size()) throw std::logic_error("ray_splat: the index was not built from these eye vertices");
        const SplatEndCap cap = ctx.params().getString("end_cap") == "hemisphere" ? SplatEndCap::Hemisphere
                                                                                  : SplatEndCap::TangentPlane;
        const bool withDirect = ctx.params().getString("classes") == "all";
        const bool useCullNodes = ctx.params().getBool("cull_nodes");
        const bool tightBoxes = ctx.params().getString("traversal") == "tight_boxes";
        const bool shMap = ctx.params().getString("glossy") == "sh_map";
        const bool lambertianToMap = ctx.params().getString("lambertian") == "sh_map";
        const bool sphere = ctx.params().getString("footprint") == "sphere";
        const bool renormalise = ctx.params().getString("origin_boundary") == "renormalise";
        const SplatSlices slices =
            ctx.params().getString("slices") == "hit_plane" ? SplatSlices::HitPlane : SplatSlices::Perpendicular;
        if (sphere && !tightBoxes) throw InputError("ray_splat: footprint = \"sphere\" needs traversal = \"tight_boxes\"");

        Film& image = ctx.createOutput<Film>("radiance", ctx.filmSettings());
        const std::size_t pixelCount = image.pixelCount();
        for (std::uint32_t pixel : eye.column<EyePixel>())
            if (pixel >= pixelCount) throw std::logic_error("ray_splat: eye vertex outside the film");
        prepareTargets(scene, eye, index.tree, shMap, lambertianToMap);
        const std::size_t glossyCount = glossyVertices_.size();
        const bool higherBands = glossyCount > 0 && (ctx.params().getString("map_bands") == "all" || mapHasGlossy_);

        const SplatRayBuffer& rays = splatRays.rays;
        const auto origin = rays.column<RayOrigin>();
        const auto direction = rays.column<RayDirection>();
        const auto length = rays.column<RayLength>();
        const auto power = rays.column<RayPower>();
        const auto h0 = rays.column<RayH0>();
        const auto dh = rays.column<RayDh>();
        const auto rayClass = rays.column<RayClassColumn>();
        const auto originNormal = rays.column<RayOriginNormal>();
        const auto endNormal = rays.column<RayEndNormal>();

        // Blocks sized as if every band were kept: the block count fixes the
        // order of the sums, so map_bands changes no bit of the image.
        const std::size_t blockBytes =
            std::max<std::size_t>(1, pixelCount * sizeof(Rgb) + glossyCount * (sizeof(MapSums) + sizeof(HigherBands)));
        std::vector<BlockFilm> blocks(std::clamp<std::size_t>(kAccumulatorBudget / blockBytes, 1, 64));
        jobs::parallelForBlocks(rays.size(), blocks.size(), [&](std::size_t b, jobs::IndexRange range) {
            BlockFilm& acc = blocks[b];
            acc.pixels.assign(pixelCount, Rgb(0.0f));
            acc.map.assign(glossyCount, MapSums{});
            if (higherBands) {
                HigherBands zero;
                zero.fill(Rgb(0.0f));
                acc.mapHigherBands.assign(glossyCount, zero);
            }
            // Raw pointers and per-ray counts in locals: the deposit runs once per
            // candidate, and through the block's vectors and the tree the compiler
            // reloads every pointer and counter each time.
            const Vec3* const slotPositions = index.tree.slotPositions().data();
            const Vec3* const slotNormals = index.tree.slotNormals().data();
            const Target* const targets = targets_.data();
            Rgb* const pixels = acc.pixels.data();
            for (std::size_t r = range.begin; r != range.end; ++r) {
                if (rayClass[r] == PhotonRayClass::Direct && !withDirect) continue;
                const SplatRay ray{origin[r], direction[r], h0[r], dh[r], length[r], originNormal[r], endNormal[r]};
                if (!(ray.h0 > 0.0f || ray.dh > 0.0f)) continue;
                ++acc.splatted;
                const Vec3 incident = -ray.direction;
                const SplatFrustum frustum(ray, cap, sphere ? SplatSlices::Perpendicular : slices);
                // Every deposit of a ray arrives from the same direction, so
                // Phi Y_lm(incident) is worked out once per ray and a deposit
                // adds it times its weight: 48 independent multiply-adds the
                // compiler can vectorise.
                const Rgb rayPower = power[r] * frustum.hitPlaneGain();
                std::array<float, 3 * sh::kCoefficients> poweredBasis{};
                if (glossyCount > 0) {
                    float y[sh::kCoefficients];
                    sh::evaluate(incident, y);
                    for (std::size_t k = 0; k < sh::kCoefficients; ++k)
                        for (int channel = 0; channel < 3; ++channel)
                            poweredBasis[3 * k + static_cast<std::size_t>(channel)] = rayPower[channel] * y[k];
                }
                std::int64_t candidates = 0, deposits = 0;
                const auto deposit = [&](std::uint32_t slot, float weight) __attribute__((always_inline)) {
                    const Vec3& position = slotPositions[slot];
                    const Target& target = targets[slot];
                    Rgb f;
                    if (target.glossy != kNotGlossy) {
                        // Shading normals must not let light through the geometric surface.
                        if (!(glm::dot(incident, target.geometricNormal) > 0.0f)) return;
                        const Rgb value = rayPower * weight;
                        if (!isFinite(value)) return;
                        MapSums& sums = acc.map[target.glossy];
                        sums.c00.x += weight * poweredBasis[0];
                        sums.c00.y += weight * poweredBasis[1];
                        sums.c00.z += weight * poweredBasis[2];
                        if (higherBands) {
                            HigherBands& c = acc.mapHigherBands[target.glossy];
                            for (std::size_t k = 1; k < sh::kCoefficients; ++k) {
                                c[k - 1].x += weight * poweredBasis[3 * k];
                                c[k - 1].y += weight * poweredBasis[3 * k + 1];
                                c[k - 1].z += weight * poweredBasis[3 * k + 2];
                            }
                        }
                        sums.weight += weight;
                        // Feasible vertices lie in front of the origin's surface, so the distance is positive.
                        const float distance = glm::length(position - ray.origin);
                        if (distance > 0.0f) sums.inverseDistance += weight / distance;
                        ++deposits;
                        return;
                    }
                    if (target.lambertian) {
                        if (!(glm::dot(incident, target.geometricNormal) > 0.0f)) return;
                        f = target.weight;
                    } else {
                        f = VertexBrdf(scene, eye, target.vertex)(incident) *
                            eye.column<EyeThroughput>()[target.vertex];
                    }
                    const Rgb value = f * rayPower * weight;
                    if (!isFinite(value)) return;
                    pixels[target.pixel] += value;
                    ++deposits;
                };
                if (sphere) {
                    const SplatSphere footprint(ray);
                    if (footprint.radius > 0.0f) {
                        candidates = static_cast<std::int64_t>(
                            forEachWeightedVertex(index.tree, footprint, footprint.cone(), deposit, useCullNodes));
                        acc.leafVertices += candidates;
                    }
                } else if (const SplatCone cone = splatCone(ray, cap, slices); tightBoxes) {
                    if (renormalise && frustum.hasOriginSurface) {
                        const auto renormalised = [&](std::uint32_t slot, float weight) {
                            deposit(slot, weight * frustum.originBoundaryGain(slotPositions[slot]));
                        };
                        candidates = static_cast<std::int64_t>(
                            forEachWeightedVertex(index.tree, frustum, cone, renormalised, useCullNodes));
                    } else {
                        candidates = static_cast<std::int64_t>(
                            forEachWeightedVertex(index.tree, frustum, cone, deposit, useCullNodes));
                    }
                    acc.leafVertices += candidates;
                } else {
                    index.tree.forEachCandidate(
                        cone,
                        [&](std::uint32_t slot) {
                            ++candidates;
                            float weight = frustum.weight(slotPositions[slot], slotNormals[slot]);
                            if (weight > 0.0f && renormalise) weight *= frustum.originBoundaryGain(slotPositions[slot]);
                            if (weight > 0.0f) deposit(slot, weight);
                        },
                        useCullNodes);
                    acc.leafVertices += candidates;
                }
                acc.candidates += candidates;
                acc.deposits += deposits;
            }
        });
        std::vector<Rgb> total(pixelCount, Rgb(0.0f));
        RadianceMap& map = ctx.createOutput<RadianceMap>("radiance_map");
        map.vertices.resize(glossyCount);
        std::vector<MapSums> mapTotal(glossyCount);
        HigherBands zeroBands;
        zeroBands.fill(Rgb(0.0f));
        std::vector<HigherBands> higherBandsTotal(higherBands ? glossyCount : 0, zeroBands);
        std::int64_t deposits = 0, candidates = 0, leafVertices = 0, splatted = 0;
        for (const BlockFilm& block : blocks) {
            for (std::size_t i = 0; i < block.pixels.size(); ++i) total[i] += block.pixels[i];
            for (std::size_t g = 0; g < block.map.size(); ++g) {
                mapTotal[g].c00 += block.map[g].c00;
                mapTotal[g].weight += block.map[g].weight;
                mapTotal[g].inverseDistance += block.map[g].inverseDistance;
            }
            for (std::size_t g = 0; g < block.mapHigherBands.size(); ++g)
                for (std::size_t k = 0; k < zeroBands.size(); ++k) higherBandsTotal[g][k] += block.mapHigherBands[g][k];
            deposits += block.deposits;
            candidates += block.candidates;
            leafVertices += block.leafVertices;
            splatted += block.splatted;
        }
        image.addToPixels(total, 1.0f);
        storeMap(map.vertices, mapTotal, higherBandsTotal);
        ctx.addItems(static_cast<std::int64_t>(rays.size()));
        ctx.addCounter("splatted_rays", splatted);
        ctx.addCounter("leaf_vertices", leafVertices);
        ctx.addCounter("vertex_candidates", candidates);
        ctx.addCounter("vertex_deposits", deposits);
        ctx.addCounter("mean_hit_radius_ppm", meanHitRadiusPpm(scene, rays, withDirect));
        ctx.addCounter("map_coefficients", glossyCount == 0 ? 0 : higherBands ? sh::kCoefficients : 1);
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

    // Bands the map did not keep are stored as zeros.
    void storeMap(RadianceMapBuffer& out, const std::vector<MapSums>& sums,
                  const std::vector<HigherBands>& higherBands) const {
        const auto columns = radianceMapShColumns(out);
        const auto vertex = out.column<MapVertex>();
        const auto weightSum = out.column<MapWeightSum>();
        const auto inverseDistanceSum = out.column<MapInverseDistanceSum>();
        for (std::size_t g = 0; g < glossyVertices_.size(); ++g) {
            vertex[g] = glossyVertices_[g];
            weightSum[g] = sums[g].weight;
            inverseDistanceSum[g] = sums[g].inverseDistance;
            columns[0][g] = sums[g].c00;
            for (std::size_t k = 1; k < sh::kCoefficients; ++k)
                columns[k][g] = higherBands.empty() ? Rgb(0.0f) : higherBands[g][k - 1];
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
        mapHasGlossy_ = false;
        if (!shMap && !lambertianToMap) return;
        for (Target& t : targets_) {
            if (t.lambertian ? !lambertianToMap : !shMap) continue;
            mapHasGlossy_ = mapHasGlossy_ || !t.lambertian;
            t.glossy = static_cast<std::uint32_t>(glossyVertices_.size());
            glossyVertices_.push_back(t.vertex);
        }
    }

    std::vector<Target> targets_;
    std::vector<std::uint32_t> glossyVertices_;
    bool mapHasGlossy_ = false;
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
        {"splat_rays", "SplatRays", "photon rays with bandwidths (ray_bandwidth)"},
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
        {"footprint", ParamType::String, std::string("frustum"), 0, 0, {"frustum", "sphere"},
         "the ray's conical frustum (§4, §7.2), or a sphere of radius R(t_hit) around its hit with the surface "
         "kernel, as photon splatting (§9's timing comparison; rays that escape splat nothing)"},
        {"origin_boundary", ParamType::String, std::string("renormalise"), 0, 0, {"cut", "renormalise"},
         "the kernel where its disk reaches behind the surface the ray leaves (a concave corner's adjacent wall): "
         "renormalised over the part in front of it, or cut there, as the paper (that wall's light is "
         "underestimated, by half at the corner line)"},
        {"slices", ParamType::String, std::string("hit_plane"), 0, 0, {"perpendicular", "hit_plane"},
         "where the growing radius R(t) is read at a vertex: where the plane through the vertex parallel to the "
         "hit's tangent plane crosses the ray (every vertex on that plane gets R(t_hit): exact on planes; applies "
         "with end_cap = tangent_plane), or at its foot on the ray, the kernel normalised across the ray (the "
         "paper; a surface met obliquely gets less than the ray's flux)"},
        {"classes", ParamType::String, std::string("indirect"), 0, 0, {"indirect", "all"},
         "which rays splat: indirect (caustic and global; the eye pass has the direct light) or all"},
        {"cull_nodes", ParamType::Bool, true, 0, 0, {}, "use the index's backface-culling nodes"},
        {"traversal", ParamType::String, std::string("tight_boxes"), 0, 0, {"tight_boxes", "cells"},
         "kd search: nodes by their vertices' tight boxes and leaf vertices by the cone, four at a time, or "
         "Algorithm 1's cells (§7.2); the same deposits in the same order"},
        {"glossy", ParamType::String, std::string("direct"), 0, 0, {"direct", "sh_map"},
         "glossy vertices: f_s evaluated per ray (Eq. 6) into the film, or projected into the SH radiance map for "
         "radiance_integrate (§8.1)"},
        {"lambertian", ParamType::String, std::string("film"), 0, 0, {"film", "sh_map"},
         "Lambertian vertices: straight into the film, or into the SH radiance map too, for the radiance cache (§8.3)"},
        {"map_bands", ParamType::String, std::string("used"), 0, 0, {"used", "all"},
         "SH bands the map keeps: used (c_00 alone when every mapped vertex is Lambertian, as nothing downstream "
         "reads the others; all 16 otherwise) or all (always 16, to inspect the map)"},
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
