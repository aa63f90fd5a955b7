// Pieces of the photon radiance estimate (Frisvad et al. 2014, Eq. 10) shared
// by the gather and splat passes: Silverman's second-order kernel (Eq. 11) and
// the BRDF at an eye vertex.
#pragma once

#include "engine/core/math.h"
#include "engine/buffers/photon_buffers.h"
#include "engine/scene/scene.h"

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

}  // namespace fg
