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
// Photons whose footprint has collapsed (zero area, or a normal lying in the
// footprint's plane: Eq. 12 singular) are skipped and counted. The optional
// topological-bias test of §3.3 discards vertices farther than
// `max_normal_distance` from the photon's tangent plane, |n_p . (x - x_p)|.
//
// f_r is Bsdf::eval / |cos theta_i| (eval includes the cosine). The splat is
// parallel over photons in fixed blocks whose per-pixel accumulators are
// merged in block order (jobs::deterministicReduce); the block count depends
// on the photon and pixel counts only, so the image is the same for any
// thread count.
#include "passes/passes.h"
#include "passes/photon_estimate.h"

#include "engine/error.h"
#include "engine/film.h"
#include "engine/photon_buffers.h"
#include "engine/point_index.h"
#include "engine/scene.h"
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
    if (!std::isfinite(f.searchRadius) || !std::isfinite(f.row0.x + f.row0.y + f.row0.z + f.row1.x + f.row1.y + f.row1.z))
        return std::nullopt;
    return f;
}

struct SplatAccumulator {
    std::vector<Rgb> pixels;
    std::int64_t splatted = 0;
    std::int64_t collapsed = 0;
    std::int64_t deposits = 0;
};

class PhotonSplatPass final : public Pass {
public:
    void run(PassContext& ctx) override {
        const Scene& scene = ctx.scene();
        const EyeVertices& eyeVertices = ctx.input<EyeVertices>("eye_vertices");
        const PointIndex& eyeIndex = ctx.input<PointIndex>("eye_index");
        const PhotonMap& caustics = ctx.input<PhotonMap>("caustic_photons");
        const Film& direct = ctx.input<Film>("direct");
        const float maxNormalDistance = static_cast<float>(ctx.params().getFloat("max_normal_distance"));

        if (!caustics.photons.empty() && !caustics.hasDifferentials) {
            throw InputError("pass '" + ctx.instanceName() +
                             "': the caustic photon map carries no photon differentials, which splatting needs; "
                             "enable them in the photon pass");
        }
        const EyeVertexView eye(eyeVertices.vertices);
        if (eyeIndex.size() != eye.size())
            throw std::logic_error("splat: the eye index was not built from these eye vertices");
        Film& image = ctx.createOutput<Film>("image", direct);
        const std::size_t pixelCount = image.pixelCount();
        for (std::uint32_t pixel : eye.pixel)
            if (pixel >= pixelCount) throw std::logic_error("splat: eye vertex outside the film");

        const auto position = caustics.photons.column<PhotonPosition>();
        const auto incident = caustics.photons.column<PhotonIncident>();
        const auto power = caustics.photons.column<PhotonPower>();
        const auto normal = caustics.photons.column<PhotonNormal>();
        const auto photonClass = caustics.photons.column<PhotonClassColumn>();
        const auto du = caustics.photons.column<PhotonDu>();
        const auto dv = caustics.photons.column<PhotonDv>();
        const std::size_t photonCount = position.size();

        const std::size_t blockBytes = std::max<std::size_t>(1, pixelCount * sizeof(Rgb));
        std::size_t blocks = std::clamp<std::size_t>(kAccumulatorBudget / blockBytes, 1, 64);
        blocks = std::min(blocks, std::max<std::size_t>(1, (photonCount + 1023) / 1024));

        const SplatAccumulator total = jobs::deterministicReduce<SplatAccumulator>(
            photonCount, blocks, [&] { return SplatAccumulator{std::vector<Rgb>(pixelCount, Rgb(0.0f))}; },
            [&](SplatAccumulator& acc, jobs::IndexRange range) {
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
                    eyeIndex.forEachInRadius(xp, footprint->searchRadius, [&](std::uint32_t v, float) {
                        const Vec3 offset = eye.position[v] - xp;
                        const float q0 = glm::dot(footprint->row0, offset);
                        const float q1 = glm::dot(footprint->row1, offset);
                        const float filterRadius2 = q0 * q0 + q1 * q1;
                        if (!(filterRadius2 < 1.0f)) return;
                        if (maxNormalDistance > 0.0f && std::abs(glm::dot(planeNormal, offset)) > maxNormalDistance)
                            return;
                        const Rgb f = VertexBrdf(scene, eye, v)(wi);
                        if (isBlack(f)) return;
                        const Rgb value = (kPi * silvermanKernel(filterRadius2)) * f * irradiance * eye.throughput[v];
                        if (!isFinite(value)) return;
                        acc.pixels[eye.pixel[v]] += value;
                        ++acc.deposits;
                    });
                }
            },
            [](SplatAccumulator& sum, const SplatAccumulator& part) {
                for (std::size_t i = 0; i < sum.pixels.size(); ++i) sum.pixels[i] += part.pixels[i];
                sum.splatted += part.splatted;
                sum.collapsed += part.collapsed;
                sum.deposits += part.deposits;
            });

        image.addToPixels(total.pixels, 1.0f);
        ctx.addItems(static_cast<std::int64_t>(photonCount));
        ctx.addCounter("splatted_photons", total.splatted);
        ctx.addCounter("collapsed_footprints", total.collapsed);
        ctx.addCounter("vertex_deposits", total.deposits);
    }
};

}  // namespace

PassRegistration splatPass() {
    PassSpec spec;
    spec.name = "splat";
    spec.doc = "Photon differential splatting of caustic photons onto the eye vertices their elliptic footprints "
               "cover (Frisvad et al. 2014), added to the direct film";
    spec.inputs = {
        {"eye_vertices", "EyeVertices", "the vertices photons are splatted to, with pixel and throughput"},
        {"eye_index", "PointIndex", "search structure over eye_vertices"},
        {"caustic_photons", "PhotonMap", "caustic photons with positional differentials D_u x, D_v x"},
        {"direct", "Film", "the film the splats are added to"},
    };
    spec.outputs = {{"image", "Film", "direct + splatted caustics"}};
    spec.params = {
        {"max_normal_distance", ParamType::Float, 0.0, 0.0, 1e30, {},
         "topological-bias test: skip eye vertices farther than this (scene units) from the photon's tangent "
         "plane, |n_p . (x - x_p)| (0 = off)"},
    };
    return {spec, [] { return std::make_unique<PhotonSplatPass>(); }};
}

}  // namespace fg
