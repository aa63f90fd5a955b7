// Pieces of the photon radiance estimate (Frisvad et al. 2014, Eq. 10) shared
// by the gather, splat and final-gather passes: Silverman's second-order
// kernel (Eq. 11), the BRDF at an eye vertex and the k-nearest-neighbour
// estimate of one photon map (the gather pass's equation).
#pragma once

#include "engine/accel/point_index.h"
#include "engine/core/math.h"
#include "engine/buffers/photon_buffers.h"
#include "engine/scene/scene.h"

#include <cmath>
#include <cstdint>
#include <span>
#include <string>

namespace fg {

// Silverman's second-order kernel K(x) = 3/pi (1 - x^2)^2 on the unit disk
// (Eq. 11), taken as a function of x^2; it integrates to 1 over the disk.
inline float silvermanKernel(float x2) { return x2 < 1.0f ? 3.0f * kInvPi * sqr(1.0f - x2) : 0.0f; }

// The BSDF of one eye vertex in its shading frame.
class VertexBrdf {
public:
    VertexBrdf(const Scene& scene, const EyeVertexBuffer::View& eye, std::size_t v)
        : bsdf_(*scene.bsdfs[eye.column<EyeBsdf>()[v]]), frame_(eye.column<EyeNormal>()[v]),
          geometricNormal_(eye.column<EyeGeometricNormal>()[v]), wo_(frame_.toLocal(eye.column<EyeOutgoing>()[v])),
          uv_(eye.column<EyeUv>()[v]) {}
    // At a surface point that is no stored vertex (secondary final gathering).
    VertexBrdf(const Bsdf& bsdf, const Vec3& shadingNormal, const Vec3& geometricNormal, const Vec3& outgoing,
               const Vec2& uv)
        : bsdf_(bsdf), frame_(shadingNormal), geometricNormal_(geometricNormal), wo_(frame_.toLocal(outgoing)),
          uv_(uv) {}

    // f_r(x, wi, wo) for light arriving from direction wi (world space, pointing
    // away from the surface). Bsdf::eval returns f_r |cos theta_i| (shading
    // frame), so the cosine is divided out here: the density estimate already
    // measures flux per area, which holds the incident cosine.
    Rgb operator()(const Vec3& wi) const {
        const Vec3 wiLocal = frame_.toLocal(wi);
        const float cosine = std::abs(wiLocal.z);
        // Shading normals must not let light through the geometric surface.
        if (!(cosine > 1e-6f) || glm::dot(wi, geometricNormal_) * wiLocal.z <= 0.0f) return Rgb(0.0f);
        return bsdf_.eval(wo_, wiLocal, uv_, TransportMode::Radiance) / cosine;
    }

private:
    const Bsdf& bsdf_;
    Frame frame_;
    Vec3 geometricNormal_;
    Vec3 wo_;
    Vec2 uv_;
};

// Photons of class Direct only are light the eye pass already estimates by
// next-event estimation; density estimates skip them.
inline bool countsAsIndirect(std::uint8_t photonClass) { return photonClass != PhotonClass::Direct; }

struct GatherSource {
    const PhotonMap& map;
    const PointIndex& index;
    std::size_t k;
    std::string layer;  // output slot of this map's radiance
};

// Radiance towards the eye at `position` from one photon map; `ids`/`dist2`
// hold at least k entries. `bandwidth2`, if given, receives h^2 (0 when no
// photon was found).
inline Rgb gatherRadiance(const Vec3& position, const VertexBrdf& brdf, const GatherSource& source, float maxRadius,
                          std::span<std::uint32_t> ids, std::span<float> dist2, std::int64_t& used,
                          float* bandwidth2 = nullptr) {
    if (bandwidth2) *bandwidth2 = 0.0f;
    const std::size_t found = source.index.nearest(position, source.k, maxRadius, ids, dist2);
    if (found == 0) return Rgb(0.0f);
    // Fewer than k inside a finite radius: the search disk is the support. With
    // no radius limit that only happens when the map is smaller than k.
    const float h2 = found == source.k || !std::isfinite(maxRadius) ? dist2[found - 1] : maxRadius * maxRadius;
    if (!(h2 > 0.0f) || !std::isfinite(h2)) return Rgb(0.0f);
    if (bandwidth2) *bandwidth2 = h2;
    const float inverseH2 = 1.0f / h2;
    const auto incident = source.map.photons.column<PhotonIncident>();
    const auto power = source.map.photons.column<PhotonPower>();
    Rgb sum(0.0f);
    for (std::size_t j = 0; j < found; ++j) {
        const float weight = silvermanKernel(dist2[j] * inverseH2);
        if (weight == 0.0f) continue;
        const std::uint32_t p = ids[j];
        const Rgb f = brdf(incident[p]);
        if (isBlack(f)) continue;
        sum += f * power[p] * weight;
        ++used;
    }
    return sum * inverseH2;
}

}  // namespace fg
