// Photon differential splatting (PDS; Frisvad et al. 2014 §3.3): instead of
// gathering photons at eye vertices, every caustic photon distributes its
// contribution to the eye vertices its elliptic footprint covers.
//
// A photon's positional differentials D_u x, D_v x span a parallelogram whose
// largest inscribed ellipse, centred on the photon with conjugate semi-axes
// D_u x / 2 and D_v x / 2, is the footprint, of area A_p = pi/4 |D_u x x D_v x|
// (Eq. 4). The photon's irradiance is E_p = Phi_p / A_p and it adds, at an eye
// vertex x,
//
//   L_r(x, w) += pi K(|M_p (x - x_p)|) f_r(x, w_p, w) E_p          (Eq. 10)
//
// with Silverman's kernel K (Eq. 11) and the 2x3 filter-space matrix
// M_p = 2 / (D_u x . (D_v x x n)) [D_v x x n ; n x D_u x] (Eq. 12), which maps
// the footprint to the unit disk. The kernel is normalised, so a photon's
// splat integrates to Phi_p over its surface. Vertices come from a range query
// on the eye-vertex index; those with |M_p (x - x_p)| >= 1 are discarded.
//
// The range is the footprint's major semi-axis, from the conjugate
// semi-diameters a, b: A^2 = (|a|^2 + |b|^2 + sqrt((|a|^2 + |b|^2)^2 - 4 |a x b|^2)) / 2.
// The paper's r_max = max(|D_u x|, |D_v x|) / 2 is this value when the two
// differentials are orthogonal; for skewed footprints it falls short and
// would miss vertices inside the ellipse, so the exact radius is used.
//
// The eye index is searched in the ellipse's bounding box (widened along the
// photon's normal up to the radius), and candidates are held to the radius
// too, so the vertices splatted are those of the sphere query, found with far
// fewer candidates for flat, elongated footprints.
//
// Photons whose footprint has collapsed (zero area, or a normal lying in the
// footprint's plane: Eq. 12 singular) are skipped and counted. The optional
// topological-bias test of §3.3 discards vertices farther than
// `max_normal_distance` from the photon's tangent plane, |n_p . (x - x_p)|.
//
// f_r is Bsdf::eval / |cos theta_i| (eval includes the cosine).
//
// Photons arrive in batches (§2: splatting needs no photon map; the photon
// pass streams its batches here and drops them). Each batch is split into a
// fixed number of blocks, block b splatting into per-pixel accumulator b, and
// the accumulators are merged in block order at the end. The block count
// depends on the pixel count only, so the image is the same for any thread
// count (and for a stored map, given whole, as one batch). The sum is the
// `caustics` radiance layer, a film from black; the composite pass adds it to
// the direct light and the gathered global light.
#include "passes/passes.h"
#include "passes/caustics/photon_estimate.h"

#include "engine/core/error.h"
#include "engine/image/film.h"
#include "engine/buffers/photon_buffers.h"
#include "engine/accel/point_index.h"
#include "engine/scene/scene.h"
#include "jobs/parallel.h"

#include <algorithm>
#include <optional>

namespace fg {

namespace {

// Bytes of per-block pixel accumulators the splat may hold at once.
constexpr std::size_t kAccumulatorBudget = std::size_t{256} << 20;

struct Footprint {
    Vec3 row0{0.0f}, row1{0.0f};  // M_p
    float area = 0.0f;            // A_p
    float searchRadius = 0.0f;    // major semi-axis
    Vec3 boxHalfExtent{0.0f};     // of the box around the ellipse that the eye index is searched in
};

std::optional<Footprint> photonFootprint(const Vec3& du, const Vec3& dv, const Vec3& normal) {
    const Vec3 spanned = glm::cross(du, dv);
    const float rayArea = glm::length(spanned);  // A_r of Eq. 4
    const float denominator = glm::dot(du, glm::cross(dv, normal));
    if (!(rayArea > 0.0f) || !std::isfinite(rayArea) ||
        !(std::abs(denominator) > 1e-6f * rayArea * glm::length(normal)))
        return std::nullopt;
    Footprint f;
    const float scale = 2.0f / denominator;
    f.row0 = glm::cross(dv, normal) * scale;
    f.row1 = glm::cross(normal, du) * scale;
    f.area = 0.25f * kPi * rayArea;
    const double sumSquares = 0.25 * (static_cast<double>(glm::dot(du, du)) + glm::dot(dv, dv));
    const double product = 0.25 * static_cast<double>(rayArea);
    const double major2 = 0.5 * (sumSquares + std::sqrt(std::max(0.0, sumSquares * sumSquares - 4.0 * product * product)));
    // Widened a little: the filter-space test, not the range, decides.
    f.searchRadius = static_cast<float>(std::sqrt(major2) * (1.0 + 1e-4));
    // Vertices that pass the filter-space test are x_p + alpha a + beta b + gamma n
    // with alpha^2 + beta^2 < 1 (a, b = D_u x / 2, D_v x / 2; M_p maps n to 0), and
    // within the search radius: |gamma| <= r / cos(n, a x b). Their box is the
    // ellipse's own, sqrt(a_i^2 + b_i^2) on axis i, widened by the normal
    // offsets, and never wider than the radius' cube. For a footprint on an
    // axis-aligned floor it is far smaller than the sphere's.
    const Vec3 unitNormal = glm::normalize(normal);
    const float normalCosine = std::abs(glm::dot(unitNormal, spanned)) / rayArea;
    for (int axis = 0; axis < 3; ++axis) {
        const float ellipse = 0.5f * std::sqrt(sqr(du[axis]) + sqr(dv[axis]));
        const float offNormal = normalCosine > 0.25f ? f.searchRadius * std::abs(unitNormal[axis]) / normalCosine
                                                     : f.searchRadius;
        f.boxHalfExtent[axis] = std::min(f.searchRadius, (ellipse + offNormal) * (1.0f + 1e-4f));
    }
    if (!std::isfinite(f.searchRadius) || !std::isfinite(f.row0.x + f.row0.y + f.row0.z + f.row1.x + f.row1.y + f.row1.z))
        return std::nullopt;
    return f;
}

struct SplatAccumulator {
    std::vector<Rgb> pixels;
    std::int64_t splatted = 0;
    std::int64_t collapsed = 0;
    std::int64_t deposits = 0;
    std::int64_t candidates = 0;  // eye vertices the box query returned
};

class PhotonSplatPass final : public Pass {
public:
    // One batch of caustic photons (all of them when the map is stored): block b
    // of the batch splats into accumulator b, which lives for the whole pass.
    void consumeBatch(PassContext& ctx, const std::string& slot) override {
        if (slot != "caustic_photons") return;
        const PhotonMap& caustics = ctx.input<PhotonMap>("caustic_photons");
        if (plannedPaths_ == 0) plannedPaths_ = caustics.emitted;
        tracedPaths_ = caustics.emitted;
        if (caustics.photons.empty()) return;
        if (!caustics.hasDifferentials) {
            throw InputError("pass '" + ctx.instanceName() +
                             "': the caustic photon map carries no photon differentials, which splatting needs; "
                             "enable them in the photon pass");
        }
        const Scene& scene = ctx.scene();
        const EyeVertexBuffer::View eye = ctx.input<EyeVertices>("eye_vertices").vertices.view();
        const PointIndex& eyeIndex = ctx.input<PointIndex>("eye_index");
        if (eyeIndex.size() != eye.size())
            throw std::logic_error("splat: the eye index was not built from these eye vertices");
        const FilmSettings& film = ctx.filmSettings();
        const std::size_t pixelCount = static_cast<std::size_t>(film.width) * static_cast<std::size_t>(film.height);
        if (blocks_.empty()) {
            for (std::uint32_t pixel : eye.column<EyePixel>())
                if (pixel >= pixelCount) throw std::logic_error("splat: eye vertex outside the film");
            const std::size_t blockBytes = std::max<std::size_t>(1, pixelCount * sizeof(Rgb));
            blocks_.resize(std::clamp<std::size_t>(kAccumulatorBudget / blockBytes, 1, 64));
            prepareTargets(scene, eye, eyeIndex);
        }
        const float maxNormalDistance = static_cast<float>(ctx.params().getFloat("max_normal_distance"));

        const auto position = caustics.photons.column<PhotonPosition>();
        const auto incident = caustics.photons.column<PhotonIncident>();
        const auto power = caustics.photons.column<PhotonPower>();
        const auto normal = caustics.photons.column<PhotonNormal>();
        const auto photonClass = caustics.photons.column<PhotonClassColumn>();
        const auto du = caustics.photons.column<PhotonDu>();
        const auto dv = caustics.photons.column<PhotonDv>();
        const std::size_t photonCount = position.size();

        jobs::parallelForBlocks(photonCount, blocks_.size(), [&](std::size_t block, jobs::IndexRange range) {
            SplatAccumulator& acc = blocks_[block];
            if (acc.pixels.empty()) acc.pixels.assign(pixelCount, Rgb(0.0f));
            for (std::size_t p = range.begin; p != range.end; ++p) {
                if (!countsAsIndirect(photonClass[p])) continue;
                const std::optional<Footprint> footprint = photonFootprint(du[p], dv[p], normal[p]);
                if (!footprint) {
                    ++acc.collapsed;
                    continue;
                }
                ++acc.splatted;
                const Rgb irradiance = power[p] / footprint->area;  // E_p
                const Vec3 xp = position[p];
                const Vec3 wi = incident[p];
                const Vec3 planeNormal = glm::normalize(normal[p]);
                const float radius2 = sqr(footprint->searchRadius);
                const Vec3 lo = xp - footprint->boxHalfExtent, hi = xp + footprint->boxHalfExtent;
                eyeIndex.forEachSlotInBox(lo, hi, [&](std::uint32_t treeSlot) {
                    ++acc.candidates;
                    const Vec3 offset = eyeIndex.slotPosition(treeSlot) - xp;
                    if (!(glm::dot(offset, offset) <= radius2)) return;
                    const float q0 = glm::dot(footprint->row0, offset);
                    const float q1 = glm::dot(footprint->row1, offset);
                    const float filterRadius2 = q0 * q0 + q1 * q1;
                    if (!(filterRadius2 < 1.0f)) return;
                    if (maxNormalDistance > 0.0f && std::abs(glm::dot(planeNormal, offset)) > maxNormalDistance)
                        return;
                    const SplatTarget& target = targets_[treeSlot];
                    Rgb weight;  // pi f_r times the vertex's throughput
                    if (target.lambertian) {
                        if (!(glm::dot(wi, target.normal) > 1e-6f) || !(glm::dot(wi, target.geometricNormal) > 0.0f))
                            return;
                        weight = target.weight;
                    } else {
                        weight = kPi * VertexBrdf(scene, eye, target.vertex)(wi) *
                                 eye.column<EyeThroughput>()[target.vertex];
                    }
                    if (isBlack(weight)) return;
                    const Rgb value = silvermanKernel(filterRadius2) * weight * irradiance;
                    if (!isFinite(value)) return;
                    acc.pixels[target.pixel] += value;
                    ++acc.deposits;
                });
            }
        });
        ctx.addItems(static_cast<std::int64_t>(photonCount));
    }

    void run(PassContext& ctx) override {
        Film& image = ctx.createOutput<Film>("caustics", ctx.filmSettings());
        SplatAccumulator total;
        total.pixels.assign(image.pixelCount(), Rgb(0.0f));
        for (const SplatAccumulator& part : blocks_) {
            for (std::size_t i = 0; i < part.pixels.size(); ++i) total.pixels[i] += part.pixels[i];
            total.splatted += part.splatted;
            total.collapsed += part.collapsed;
            total.deposits += part.deposits;
            total.candidates += part.candidates;
        }
        // Batches streamed before an interrupt carry powers for the planned
        // count of paths; fewer were traced (the last, empty batch says how many).
        // Their footprints stay those of the planned count (Eqs. 5-6 scale them
        // by 1 / sqrt(N)): the estimate is consistent, just smoothed more.
        const float plannedPerTraced = tracedPaths_ > 0 && tracedPaths_ < plannedPaths_
                                       ? static_cast<float>(static_cast<double>(plannedPaths_) /
                                                            static_cast<double>(tracedPaths_))
                                       : 1.0f;
        image.addToPixels(total.pixels, plannedPerTraced);
        ctx.addCounter("splatted_photons", total.splatted);
        ctx.addCounter("collapsed_footprints", total.collapsed);
        ctx.addCounter("vertex_deposits", total.deposits);
        ctx.addCounter("vertex_candidates", total.candidates);
    }

private:
    // What a deposit needs of its eye vertex, in the eye index's slot order, so
    // that the vertices of one leaf are read from contiguous memory. A vertex
    // splatted to thousands of times should not rebuild its shading frame and
    // call the BSDF each time either: at Lambertian vertices pi f_r times the
    // throughput is one constant, valid for light from the side where both
    // normals agree (VertexBrdf's conditions).
    struct SplatTarget {
        Vec3 normal{0.0f}, geometricNormal{0.0f};
        Rgb weight{0.0f};
        std::uint32_t pixel = 0;
        std::uint32_t vertex = 0;
        bool lambertian = false;
    };

    void prepareTargets(const Scene& scene, const EyeVertexBuffer::View& eye, const PointIndex& eyeIndex) {
        targets_.assign(eye.size(), SplatTarget{});
        jobs::parallelFor(eye.size(), 4096, [&](std::size_t slot) {
            SplatTarget& t = targets_[slot];
            const std::uint32_t v = eyeIndex.slotId(static_cast<std::uint32_t>(slot));
            t.vertex = v;
            const EyeVertexBuffer::Record vertex = eye.get(v);
            t.pixel = vertex.get<EyePixel>();
            t.normal = vertex.get<EyeNormal>();
            t.geometricNormal = vertex.get<EyeGeometricNormal>();
            const std::optional<Rgb> reflectance =
                scene.bsdfs[vertex.get<EyeBsdf>()]->constantReflectance(vertex.get<EyeUv>());
            if (!reflectance) return;
            t.lambertian = true;
            // Seen from below its shading normal, a Lambertian surface reflects nothing.
            if (glm::dot(vertex.get<EyeOutgoing>(), t.normal) > 0.0f)
                t.weight = kPi * *reflectance * vertex.get<EyeThroughput>();
        });
    }

    std::vector<SplatAccumulator> blocks_;
    // The photon paths the powers of the first and of the last batch were
    // divided by: they differ when an interrupt cut the photon pass short.
    std::uint64_t plannedPaths_ = 0, tracedPaths_ = 0;
    std::vector<SplatTarget> targets_;
};

}  // namespace

PassRegistration splatPass() {
    PassSpec spec;
    spec.name = "splat";
    spec.doc = "Photon differential splatting of caustic photons onto the eye vertices their elliptic footprints "
               "cover (Frisvad et al. 2014), as their own radiance layer";
    spec.inputs = {
        {"eye_vertices", "EyeVertices", "the vertices photons are splatted to, with pixel and throughput"},
        {"eye_index", "PointIndex", "search structure over eye_vertices"},
        {"caustic_photons", "PhotonMap", "caustic photons with positional differentials D_u x, D_v x (read in batches)",
         true},
    };
    spec.outputs = {{"caustics", "Film", "splatted caustics alone (a film from black)"}};
    spec.params = {
        {"max_normal_distance", ParamType::Float, 0.0, 0.0, 1e30, {},
         "topological-bias test: skip eye vertices farther than this (scene units) from the photon's tangent "
         "plane, |n_p . (x - x_p)| (0 = off)"},
    };
    // Splatting needs footprints: caught before any photon is traced.
    const auto preflight = [](const PreflightContext& pf) {
        const PassParams* photon = pf.producerParams("caustic_photons");
        if (photon && pf.producerPass("caustic_photons") == "photon" && !photon->getBool("differentials")) {
            throw InputError(pf.source + ": pass '" + pf.instance +
                             "': the caustic photons carry no photon differentials, which splatting needs; set "
                             "differentials = true in the photon pass");
        }
    };
    // The film, the summed image and the per-block accumulators (as many as
    // fit kAccumulatorBudget, at least one, at most 64).
    const auto memory = [](const PreflightContext& pf) {
        const std::uint64_t image =
            multiplyBytes(static_cast<std::uint64_t>(pf.film.width) * static_cast<std::uint64_t>(pf.film.height), sizeof(Rgb));
        const std::uint64_t blocks = std::clamp<std::uint64_t>(kAccumulatorBudget / std::max<std::uint64_t>(image, 1), 1, 64);
        return MemoryEstimate{addBytes(addBytes(filmBytes(pf.film), image), multiplyBytes(image, blocks)),
                              "film " + std::to_string(pf.film.width) + " x " + std::to_string(pf.film.height) + " and " +
                                  std::to_string(blocks) + " splat accumulators",
                              {}};
    };
    return {spec, [] { return std::make_unique<PhotonSplatPass>(); }, preflight, memory};
}

}  // namespace fg
