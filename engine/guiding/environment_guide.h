// Guided environment emission (Vorba et al. 2014, §4.4, Fig. 6): a model,
// trained by the importons that leave the scene, of where photons from an
// environment light are worth emitting. It factors the emission density
// p(x, ω) = p(ω) p(x|ω) as the paper does:
//
// - p_W(ω), the directional distribution of the importance that leaves the
//   scene, is a bitmap over the sphere (§4.4 "Directional distribution"). Its
//   cells are equal-area: rows of equal height in z = cos θ (world +z axis)
//   and columns of equal width in φ, so each covers 4π / (rows × columns) sr
//   (Archimedes' hat-box theorem) and a point drawn uniformly in (z, φ) within
//   a cell is uniform in solid angle. A cell's value is a progressive kernel
//   density estimate at its centre, summed over the training passes (the
//   pass's estimate, Hachisuka et al. 2008's progressive idea applied to
//   directions): each pass adds Σ_i w_i K_r(ω_c · ω_i) with the normalised
//   cone kernel K_r(μ) = max(0, μ − cos r) / (π (1 − cos r)²), and the cap
//   the kernel covers shrinks from pass to pass as the area of a progressive
//   photon mapping disc does, (1 − cos r_{t+1}) = (1 − cos r_t)(t + α)/(t + 1)
//   (Knaus and Zwicker 2011's per-pass form of that reduction). The paper
//   gives neither the kernel nor the schedule.
// - p(x|ω), the position on the disk perpendicular to ω from which a photon
//   starts (§4.4 "Position distributions"), is a GMM on the unit square
//   (directional_gmm.h, stepwise_em.h) taken to the unit disk by the
//   concentric map of Shirley and Chiu (area preserving: pdf_disk =
//   pdf_square / π on the unit disk). The paper keeps these in a cache on the
//   unit sphere indexed by ω; here there is one per bitmap cell, trained by the
//   importons that left within a window around the cell's centre (the paper's
//   1°; see the environment_update pass for the window used and why).
//
// The disk is the photon pass's emission disk for infinite lights
// (engine/shading/light.cpp, SceneDisk): radius R of the scene's bounding
// sphere, tangent to it on the light's side. A line along ω has disk
// coordinates ((x − c)·s, (x − c)·t) / R for any point x on it, in a frame
// (s, t, ω). That frame must vary smoothly with ω inside a cell, or nearby
// directions would put the same line at different disk points: it is the
// cell centre's frame turned by the smallest rotation taking the centre to ω.
#pragma once

#include "engine/core/math.h"
#include "engine/core/pass.h"
#include "engine/core/soa.h"
#include "engine/guiding/stepwise_em.h"
#include "engine/shading/distribution.h"

#include <cstdint>
#include <optional>
#include <vector>

namespace fg {

class Light;
struct Scene;

// Environment emitters are the lights §4.4 guides: infinite and not delta
// (environment maps, constant skies; not directional lights).
bool isEnvironmentEmitter(const Light& light);
bool hasEnvironmentEmitter(const Scene& scene);

FG_SOA_COLUMN(EnvCellDensity, float, "density");  // the passes' kernel estimates of p_W at the centre, summed
FG_SOA_COLUMN(EnvCellMixture, DirectionalGmm, "disk_gmm");
FG_SOA_COLUMN(EnvCellStatistics, GmmStatistics, "disk_statistics");
FG_SOA_COLUMN(EnvCellFitted, std::uint32_t, "disk_fitted");  // 1 once the disk GMM has been fitted (and is usable)

using EnvironmentCellBuffer = SoaBuffer<EnvCellDensity, EnvCellMixture, EnvCellStatistics, EnvCellFitted>;

// Unit square <-> unit disk by the concentric map, as the directional GMM's
// square is mapped (directional_gmm.h: the same map, without the lift to the
// hemisphere), so the two stay exact inverses.
Vec2 squareToUnitDisk(const Vec2& s);
Vec2 unitDiskToSquare(const Vec2& d);
inline constexpr float kSquareToUnitDiskJacobian = kPi;

struct EnvironmentGuide {
    std::uint32_t columns = 0, rows = 0;  // 0 x 0: the empty model (a scene without an environment emitter)
    Vec3 center{0.0f};                    // the scene's bounding sphere, as the lights' emission disks use it
    float radius = 0.0f;
    std::uint64_t passes = 0;           // training passes folded in
    float kernelCap = 0.0f;             // 1 − cos r of the next pass's kernel
    EnvironmentCellBuffer cells;        // rows × columns, row-major, row 0 at z = +1

    std::size_t bytes() const { return cells.bytes(); }
    std::size_t cellCount() const { return static_cast<std::size_t>(columns) * rows; }
    float cellSolidAngle() const { return 4.0f * kPi / static_cast<float>(cellCount()); }
    // Whether any cell has importance: otherwise photons are emitted as without the model.
    bool guides() const;

    std::uint32_t cellOf(const Vec3& w) const;
    Vec3 cellCentre(std::uint32_t cell) const;
    // Uniform in solid angle over the cell.
    Vec3 directionInCell(std::uint32_t cell, const Vec2& u) const;
    // The disk frame (s, t, n = w) of a direction w in `cell` (see above).
    Frame diskFrame(std::uint32_t cell, const Vec3& w) const;
    // Disk coordinates, on the unit disk, of the line along w through x.
    Vec2 diskPoint(std::uint32_t cell, const Vec3& w, const Vec3& x) const;
    // Where a photon travelling along −w from unit-disk point d starts.
    Vec3 diskOrigin(std::uint32_t cell, const Vec3& w, const Vec2& d) const;
    // The fitted disk GMM of a cell, or null.
    const DirectionalGmm* diskMixture(std::uint32_t cell) const;
};
template <>
struct BufferTypeName<EnvironmentGuide> {
    static constexpr const char* value = "EnvironmentGuide";
};

// p_W(ω) p_L(ω) of one environment light, normalised, as a density over
// directions towards the light. An environment map's p_L is piecewise constant
// over its patches (Light::samplingPatchCount): each patch is given to the
// cell holding its centre, a cell is chosen with probability
// p_W(c) P_L(c) / Σ_c' p_W(c') P_L(c'), P_L(c) the light's own sampling mass of
// the patches given to c, then a patch with probability its mass / P_L(c), then
// a direction within the patch as the light samples it, so the density is
// p_W(c(ω)) p_L(ω) / Σ_c' p_W(c') P_L(c'): p_L exactly (a sun smaller than a
// cell is hit as the light's own sampling hits it) and p_W at the bitmap's
// resolution, read at the patch's centre. A light without patches (a constant
// sky, whose p_L is uniform) is sampled per cell in proportion to p_W times its
// luminance averaged over 4 points of the cell, then uniformly within the
// cell, which for a uniform p_L is the same product. Directions where p_W is
// zero have density 0 here; the photon pass mixes this with p_L, which is what
// keeps them reachable.
class EnvironmentSampler {
public:
    EnvironmentSampler() = default;
    EnvironmentSampler(const EnvironmentGuide& guide, const Light& light);
    bool usable() const { return usable_; }
    // None only at a pole of an environment map, where p_L is 0 (a set of
    // measure zero). The density is written where asked for.
    std::optional<Vec3> sample(const Vec2& u, float* pdf = nullptr) const;
    float pdf(const Vec3& towardsLight) const;
    // The same, given the light's pdfLi of the direction (the photon pass has it).
    float pdf(const Vec3& towardsLight, float lightPdf) const;

private:
    const EnvironmentGuide* guide_ = nullptr;
    const Light* light_ = nullptr;
    Distribution1D cells_;
    bool usable_ = false;
    // With patches: the cell each patch is given to, and per cell the patches
    // given to it (patchStart_[c] .. patchStart_[c + 1] in patches_) and the
    // distribution over them by mass (whose total is P_L(c)).
    bool patched_ = false;
    std::vector<std::uint32_t> patchCell_;
    std::vector<std::uint32_t> patchStart_, patches_;
    std::vector<Distribution1D> withinCell_;
};

// Solid-angle density of the photon pass's direction mixture (one-sample MIS
// with the balance heuristic, Veach 1997 §9.2.4): β p_LW + (1 − β) p_L.
inline float environmentDirectionPdf(float beta, float productPdf, float lightPdf) {
    return beta * productPdf + (1.0f - beta) * lightPdf;
}

// Area density, on the emission disk of radius R, of the position mixture
// γ p(x|ω) + (1 − γ) / (π R²); without a GMM the uniform density alone.
float environmentPositionPdf(const DirectionalGmm* gmm, float gamma, const Vec2& unitDisk, float radius);

}  // namespace fg
