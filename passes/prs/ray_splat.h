// The density estimate of photon ray splatting at one eye vertex (Herzog et
// al. 2007, §4-5 and §7.2's feasibility test), shared by the ray_splat pass
// and its tests.
//
// Eqs. 4-6 as transcribed divide the flux by an area twice: the normalised
// kernel K_h already carries 1/area. The estimate implemented is
//   L(x, w_o) = sum_i f_s(w_i, x, w_o) Phi_i |cos theta_x| K_R(d_perp),
// K_R(d) = 2 / (pi R^2) (1 - d^2 / R^2), the Epanechnikov kernel on the disk
// of radius R perpendicular to the ray (it integrates to 1 there), so
// Phi K is the flux per area perpendicular to the ray and |cos theta_x|
// projects it onto the surface at x (Eq. 3).
//
// A vertex is feasible (§7.2) if it faces the ray (dir . n_x < 0), lies in
// front of the surface the ray leaves ((x - x_i) . n_i > 0) and inside the
// frustum: d_perp <= R(t_p) = h_0 + dh t_p for 0 <= t_p <= t_hit. Beyond the
// hit point the paper shrinks the footprint to a hemisphere,
// |x - x_hit| <= R(t_hit) (end cap "hemisphere", Fig. 4). That cap loses
// energy wherever the ray meets its surface obliquely: on a plane the
// footprint beyond the hit is cut to a half-disk of radius R around x_hit
// where the cylinder's footprint is a half-ellipse stretched by 1/cos theta;
// the estimate is E_0 cos theta (1/2 + cos theta (1/2 + sin^2 theta / 4))
// instead of E_0 cos theta, 0.90 of the truth under uniform radiance, at any
// bandwidth: the paper's estimator is not consistent. End cap
// "tangent_plane" keeps the cylinder of radius R(t_hit) beyond the hit for
// vertices not behind the tangent plane at x_hit, which is exact on planes.
// There the frustum is cut at t_hit + R(t_hit) tan theta_hit with tan theta
// held to kMaxTangentStretch (rays within 7 degrees of grazing lose the far
// end of their footprint; they carry little flux onto that surface).
//
// The frustum's radius grows along the ray (R(t) = h_0 + dh t, §6), and the
// paper reads it at t_p, the vertex's foot on the ray, while normalising the
// kernel over the disk perpendicular to the ray. On a surface the ray meets
// at theta from its normal, the half of the footprint before the hit then
// lies in thinner slices of the cone, and the ray's deposits integrate over
// that surface to less than its flux: 1 - (8 / 15 pi) dh tan theta to first
// order (PrsPlaneUnderDirectionalLight.GrowingRadius*; on the Cornell box
// it put the indirect light away from the edges 0.23 % below photon
// mapping's, README "Concave corners"). Slices "hit_plane" read R at
// t*, where the plane through the vertex parallel to the hit's tangent plane
// crosses the ray (t* = t_p on the ray's axis), so every vertex on that plane
// gets R(t_hit) and the footprint there is exactly normalised; a grazing
// ray's footprint cut at kMaxTangentStretch is renormalised over what is
// left (hitPlaneGain). Rays that escape keep the paper's slices.
#pragma once

#include "engine/accel/splat_kdtree.h"
#include "engine/core/math.h"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <immintrin.h>

namespace fg {

enum class SplatEndCap { Hemisphere, TangentPlane };
enum class SplatSlices { Perpendicular, HitPlane };

inline constexpr float kMaxTangentStretch = 8.0f;

struct SplatRay {
    Vec3 origin{0.0f};
    Vec3 direction{0.0f, 0.0f, 1.0f};
    float h0 = 0.0f;
    float dh = 0.0f;
    float length = 0.0f;
    Vec3 originNormal{0.0f};  // zero: no surface at the origin
    Vec3 endNormal{0.0f};     // facing the ray; zero: the ray escaped (no footprint beyond its end)
};

// Where along the ray the footprint ends.
inline float splatReach(const SplatRay& ray, SplatEndCap cap) {
    if (ray.endNormal == Vec3(0.0f)) return ray.length;
    const float hitRadius = ray.h0 + ray.dh * ray.length;
    if (cap == SplatEndCap::Hemisphere) return ray.length + hitRadius;
    const float cosine = std::clamp(-glm::dot(ray.direction, ray.endNormal), 0.0f, 1.0f);
    const float tangent = cosine > 0.0f ? std::sqrt(std::max(0.0f, 1.0f - cosine * cosine)) / cosine : kInfinity;
    return ray.length + hitRadius * std::min(tangent, kMaxTangentStretch);
}

// Whether slices "hit_plane" apply to a ray: it meets a surface, and the
// footprint beyond the hit is the tangent plane's.
inline bool slicesAlongHitPlane(const SplatRay& ray, SplatEndCap cap, SplatSlices slices) {
    return slices == SplatSlices::HitPlane && cap == SplatEndCap::TangentPlane && ray.endNormal != Vec3(0.0f);
}

// How far t* may lie beyond t_p: |q . n| / cos theta <= R(t_hit) tan theta for
// an offset q of at most R(t_hit), with tan theta held to the stretch cap.
inline float sliceShift(const SplatRay& ray) {
    const float hitRadius = ray.h0 + ray.dh * ray.length;
    const float cosine = std::clamp(-glm::dot(ray.direction, ray.endNormal), 0.0f, 1.0f);
    const float tangent = cosine > 0.0f ? std::sqrt(std::max(0.0f, 1.0f - cosine * cosine)) / cosine : kInfinity;
    return hitRadius * std::min(tangent, kMaxTangentStretch);
}

// The search cone holds every vertex the frustum can weigh. With slices
// "hit_plane" a vertex at t_p may get R(t*) for t* up to t_p + sliceShift,
// so the cone is the frustum's moved back by that much along the ray (never
// wider than R(t_hit)), widened by a relative 1e-5 for rounding.
inline SplatCone splatCone(const SplatRay& ray, SplatEndCap cap, SplatSlices slices = SplatSlices::Perpendicular) {
    if (!slicesAlongHitPlane(ray, cap, slices) || !(ray.dh > 0.0f))
        return SplatCone{ray.origin, ray.direction, ray.h0, ray.dh, ray.length, splatReach(ray, cap)};
    const float hitRadius = ray.h0 + ray.dh * ray.length;
    const float shift = sliceShift(ray);
    const float start = std::min(ray.h0 + ray.dh * shift, hitRadius) * (1.0f + 1e-5f);
    return SplatCone{ray.origin, ray.direction, start, ray.dh, std::max(0.0f, ray.length - shift), splatReach(ray, cap)};
}

// How far behind the hit's tangent plane a vertex may lie and still count as
// on it. The hit is rebuilt as origin + length * direction, but the photon
// was traced from an origin offset along the normal by offsetRayOrigin
// (kRayEpsilon (1 + max |p_i|)), so the rebuilt hit is off its surface by up
// to about that much (0.01 mm seen on the Cornell box, in mm): a tolerance
// relative to R alone dropped the half of the footprint beyond the hit on
// surfaces where the error fell behind the plane (the floor under the light
// got 55 % of its irradiance). Twice the offset at the larger end covers it;
// real surfaces behind the plane lie much farther back.
inline float endPlaneTolerance(const SplatRay& ray, float radius) {
    const Vec3 end = ray.origin + ray.length * ray.direction;
    const auto maxAbs = [](const Vec3& p) { return std::max(std::abs(p.x), std::max(std::abs(p.y), std::abs(p.z))); };
    return 2.0f * kRayEpsilon * (1.0f + std::max(maxAbs(ray.origin), maxAbs(end))) + 1e-4f * radius;
}

// A ray's frustum with what every vertex test needs worked out once: a ray
// meets hundreds to thousands of candidate vertices (1157 per ray on the
// Cornell box at 128 x 128, 2 spp, 100k photons), and the reach (a square
// root and a division), the hit point and its tolerance do not depend on
// the vertex.
struct SplatFrustum {
    SplatFrustum(const SplatRay& ray, SplatEndCap endCap, SplatSlices slices = SplatSlices::Perpendicular)
        : origin(ray.origin), direction(ray.direction), originNormal(ray.originNormal), endNormal(ray.endNormal),
          end(ray.origin + ray.length * ray.direction), h0(ray.h0), dh(ray.dh), length(ray.length),
          hitRadius(ray.h0 + ray.dh * ray.length), reach(splatReach(ray, endCap)),
          tolerance(endPlaneTolerance(ray, ray.h0 + ray.dh * ray.length)),
          inverseHitCosine(1.0f / std::max(-glm::dot(ray.direction, ray.endNormal), 1.0f / 64.0f)),
          shift(sliceShift(ray)), originReachBound(hitRadius * originSine(ray.direction, ray.originNormal)),
          cap(endCap), hasOriginSurface(ray.originNormal != Vec3(0.0f)),
          hitPlaneSlices(slicesAlongHitPlane(ray, endCap, slices)) {}

    // R at a vertex whose foot on the ray is t_p: R(t_p) (the paper), or
    // R(t*) with slices "hit_plane" (see the top of this file), t* clamped to
    // [0, min(t_hit, t_p + shift)] so that the search cone holds the vertex.
    float radiusAt(const Vec3& x, float tp) const {
        if (!hitPlaneSlices) return tp <= length ? h0 + dh * tp : hitRadius;
        const float hitSide = glm::dot(x - end, endNormal);
        const float slice = std::min(std::max(length - hitSide * inverseHitCosine, 0.0f), std::min(length, tp + shift));
        return h0 + dh * slice;
    }

    // The factor slices "hit_plane" multiply every deposit of a ray by: the
    // footprint on the hit plane ends at the reach, t_hit + R tan theta held
    // to kMaxTangentStretch R, which cuts the kernel's disk at c R =
    // kMaxTangentStretch R / tan theta across it; 1 / its mass before the cut.
    float hitPlaneGain() const {
        if (!hitPlaneSlices) return 1.0f;
        const float cosine = 1.0f / inverseHitCosine;
        const float tangent = std::sqrt(std::max(0.0f, 1.0f - cosine * cosine)) / cosine;
        if (!(tangent > kMaxTangentStretch)) return 1.0f;
        return 1.0f / (1.0f - epanechnikovMassBeyond(kMaxTangentStretch / tangent));
    }

    // K_R(d_perp) |cos theta_x| at vertex x with normal n, or 0 if x is not
    // feasible. The tests run from the most to the least selective: most
    // candidates lie outside the frustum's radius.
    float weight(const Vec3& x, const Vec3& n) const {
        const Vec3 offset = x - origin;
        const float tp = glm::dot(offset, direction);
        if (tp < 0.0f || tp > reach) return 0.0f;
        // |offset - tp dir|^2, not |offset|^2 - tp^2: the difference cancels
        // catastrophically on long rays (an error of 0.1 mm^2 at 1 m).
        const Vec3 perpendicular = offset - tp * direction;
        const float d2 = glm::dot(perpendicular, perpendicular);
        const float radius = radiusAt(x, tp);
        if (!(radius > 0.0f)) return 0.0f;
        const float r2 = radius * radius;
        if (!(d2 < r2)) return 0.0f;
        const float cosine = -glm::dot(direction, n);
        if (!(cosine > 0.0f)) return 0.0f;
        if (hasOriginSurface && !(glm::dot(offset, originNormal) > 0.0f)) return 0.0f;
        if (tp > length) {
            const Vec3 fromHit = x - end;
            if (cap == SplatEndCap::Hemisphere) {
                if (glm::dot(fromHit, fromHit) > r2) return 0.0f;
            } else if (glm::dot(fromHit, endNormal) < -tolerance) {
                return 0.0f;
            }
        }
        return 2.0f * kInvPi / r2 * (1.0f - d2 / r2) * cosine;
    }

    // The factor `origin_boundary = "renormalise"` multiplies weight() by:
    // 1 / the share of the kernel's disk at x (radius R(t_p), perpendicular
    // to the ray) that lies in front of the surface the ray leaves. Rays
    // exist only in front of it, so where that surface comes within R of x
    // (at a concave corner, the adjacent wall) the paper's estimate of the
    // light leaving it averages over a disk partly empty of rays: at the
    // corner line it gets exactly half of that wall's light. Renormalising
    // the kernel over the part where rays can be (the boundary correction
    // of kernel density estimation) takes that loss out; the factor lies in
    // [1, 2], as a feasible x lies in front of the surface.
    float originBoundaryGain(const Vec3& x) const {
        if (!hasOriginSurface) return 1.0f;
        const Vec3 offset = x - origin;
        const float height = glm::dot(offset, originNormal);
        // Most deposits lie farther from the surface than any disk of the ray
        // reaches (R <= R(t_hit) everywhere, and float rounding keeps that
        // order), so they skip the radius at x: the same factor, bit for bit.
        if (!(height < originReachBound)) return 1.0f;
        const float tp = glm::dot(offset, direction);
        const float radius = radiusAt(x, tp);
        // How far the disk reaches towards the surface: R sin of the angle between the ray and the normal.
        const float reachTowardsSurface = radius * originSine(direction, originNormal);
        if (!(height < reachTowardsSurface) || !(height >= 0.0f)) return 1.0f;
        return 1.0f / (1.0f - epanechnikovMassBeyond(height / reachTowardsSurface));
    }

    // sin of the angle between the ray and the normal of the surface it leaves.
    static float originSine(const Vec3& direction, const Vec3& originNormal) {
        const float leaving = glm::dot(direction, originNormal);
        return std::sqrt(std::max(0.0f, 1.0f - leaving * leaving));
    }

    // Share of the 2D Epanechnikov kernel's mass beyond a line at distance
    // c R from its centre, c in [0, 1]: (8 / 3 pi) ∫_c^1 (1 - u^2)^(3/2) du.
    static float epanechnikovMassBeyond(float c) {
        if (!(c < 1.0f)) return 0.0f;
        const float rest = std::sqrt(std::max(0.0f, 1.0f - c * c));
        return (1.5f * kPi - c * (5.0f - 2.0f * c * c) * rest - 3.0f * std::asin(c)) / (3.0f * kPi);
    }

    // weight() of the vertices [first, first + count) of `vertices`, bit for
    // bit: the same operations in the same order, with every test turned
    // into a mask, so that the compiler weighs four vertices at once from the
    // columns where weight() takes one vertex at a time through branches.
    // Defined in ray_splat_pass.cpp, once and not inline: inside the kd
    // traversal GCC 12 leaves such loops scalar, and clang gives an inline
    // function with target clones a dispatcher per translation unit, which
    // do not link. An AVX2 clone weighs eight at once where the processor
    // has it; AVX2 without FMA rounds every operation as SSE does, so the
    // bits are the same either way.
    void weights(const SplatVertexColumns& vertices, std::uint32_t first, std::uint32_t count, float* out) const;

    // `condition` (0 or 1) ? a : b by the bits: GCC 12 does not vectorise
    // loops with float selects of computed values ("control flow in loop").
    static float maskedSelect(int condition, float a, float b) {
        const std::uint32_t mask = 0u - static_cast<std::uint32_t>(condition);
        return std::bit_cast<float>((std::bit_cast<std::uint32_t>(a) & mask) | (std::bit_cast<std::uint32_t>(b) & ~mask));
    }

    Vec3 origin, direction, originNormal, endNormal, end;
    float h0, dh, length, hitRadius, reach, tolerance, inverseHitCosine, shift;
    float originReachBound;  // R(t_hit) sin(ray, origin normal): no disk of the ray reaches farther
    SplatEndCap cap;
    bool hasOriginSurface, hitPlaneSlices;
};

// The footprint §9 compares the frustum with: a sphere of radius R(t_hit)
// around the hit point, as photon splatting with a precomputed radius
// (`footprint = "sphere"`). A vertex facing the ray within the sphere gets
// the surface kernel K_R(|x - x_hit|) = 2 / (pi R^2) (1 - d^2 / R^2), without
// |cos theta_x|: the hits' density on the surface already holds the cosine.
// Rays that escape have no sphere.
struct SplatSphere {
    explicit SplatSphere(const SplatRay& ray)
        : centre(ray.origin + ray.length * ray.direction), direction(ray.direction),
          radius(ray.endNormal == Vec3(0.0f) ? 0.0f : ray.h0 + ray.dh * ray.length) {}

    float weight(const Vec3& x, const Vec3& n) const {
        const Vec3 offset = x - centre;
        const float d2 = glm::dot(offset, offset);
        const float r2 = radius * radius;
        if (!(radius > 0.0f) || !(d2 < r2) || !(glm::dot(direction, n) < 0.0f)) return 0.0f;
        return 2.0f * kInvPi / r2 * (1.0f - d2 / r2);
    }

    // weight() over columns, bit for bit (defined beside SplatFrustum::weights).
    void weights(const SplatVertexColumns& vertices, std::uint32_t first, std::uint32_t count, float* out) const;

    // A cylinder of radius R along the ray through the sphere: the tree's
    // cone search finds every vertex inside.
    SplatCone cone() const {
        return SplatCone{centre - radius * direction, direction, radius, 0.0f, 2.0f * radius, 2.0f * radius};
    }

    Vec3 centre, direction;
    float radius;
};

// Leaf vertices weighed at once (SplatFrustum::weights) before their deposits.
inline constexpr std::uint32_t kWeightChunk = 128;

// Calls deposit(slot, weight) for every vertex of `tree` that the frustum
// gives a positive weight, in Algorithm 1's order (§7.2): the leaves come
// from SplatKdTree::forEachLeafNearCone and their vertices are weighed from
// the tree's columns by SplatFrustum::weights, so the deposits and their
// weights are those of SplatFrustum::weight over forEachCandidate, bit for
// bit. Returns how many leaf vertices were weighed.
// (SplatSphere's weights the same way, for the sphere footprint.)
template <class Footprint, class Deposit>
std::uint64_t forEachWeightedVertex(const SplatKdTree& tree, const Footprint& frustum, const SplatCone& cone,
                                    Deposit&& deposit, bool useCullNodes) {
    const SplatVertexColumns columns = tree.slotColumns();
    const auto depositLeaf = [&](std::uint32_t first, std::uint32_t count) {
        for (std::uint32_t base = first; base < first + count; base += kWeightChunk) {
            const std::uint32_t n = std::min(kWeightChunk, first + count - base);
            alignas(16) float weights[kWeightChunk];
            frustum.weights(columns, base, n, weights);
            // The feasible ones as bits, four per comparison, taken lowest
            // first: about a third of the vertices weighed deposit, a coin
            // toss for a branch per vertex.
            std::uint64_t feasible[kWeightChunk / 64] = {};
            for (std::uint32_t k = 0; k < n; k += 4) {
                const auto bits = static_cast<std::uint64_t>(
                    _mm_movemask_ps(_mm_cmpgt_ps(_mm_load_ps(weights + k), _mm_setzero_ps())));
                feasible[k / 64] |= bits << (k % 64);
            }
            if (n % 64 != 0) feasible[(n - 1) / 64] &= ~std::uint64_t(0) >> (64 - n % 64);
            for (std::uint32_t word = 0; word * 64 < n; ++word)
                for (std::uint64_t bits = feasible[word]; bits != 0; bits &= bits - 1) {
                    const std::uint32_t k = word * 64 + static_cast<std::uint32_t>(std::countr_zero(bits));
                    deposit(base + k, weights[k]);
                }
        }
    };
    return tree.forEachLeafNearCone(cone, depositLeaf, useCullNodes);
}

// The same for one vertex (tests, and callers with a single vertex per ray).
inline float splatWeight(const SplatRay& ray, SplatEndCap cap, const Vec3& x, const Vec3& n,
                         SplatSlices slices = SplatSlices::Perpendicular) {
    return SplatFrustum(ray, cap, slices).weight(x, n);
}

}  // namespace fg
