// Photon differentials (Schjøth et al. 2007; Frisvad et al. 2014, §3): the
// first-order change of a photon's position and direction with respect to the
// parameters of its emission, which turns every photon into a beam with an
// elliptic footprint. Emission follows Frisvad et al. 2014 Eqs. 2-6, transfer
// Eqs. 7-9, and specular reflection and refraction Igehy 1999 ("Tracing Ray
// Differentials"); the footprint is Eq. 4 and the filter matrix Eq. 12.
#pragma once

#include "engine/shading/bsdf.h"
#include "engine/core/math.h"

namespace fg {

// Frisvad 2012, "Building an orthonormal basis from a 3D unit vector without
// normalization" (with the lower-hemisphere branch of Duff et al. 2017): b1, b2
// such that (b1, b2, n) is right-handed orthonormal.
void frisvadBasis(const Vec3& n, Vec3* b1, Vec3* b2);

// Differential vectors of one photon. Before the first transfer the positional
// pair is D_u x, D_v x (tangent to the source) and the directional pair
// D_theta w, D_phi w (perpendicular to w). Because emission chooses the pairs
// parallel (Eqs. 2-3), the photon is described by two parameters afterwards:
// dxU is (D_u + D_theta) x and dxV is (D_v + D_phi) x (Eq. 7); dwU and dwV stay
// the directional derivatives along the same two parameters.
struct PhotonDifferential {
    Vec3 dxU{0.0f};
    Vec3 dxV{0.0f};
    Vec3 dwU{0.0f};  // D_theta w
    Vec3 dwV{0.0f};  // D_phi w
};

// Initial lengths, Eqs. 5 and 6: the N_e initial footprints (areas pi/4 |D_u x|^2,
// solid angles pi/4 |D_theta w|^2) add up to s^2 A_e and s^2 omega_e.
float initialPositionalLength(float smoothing, float emitterArea, double photonsFromSource);
float initialDirectionalLength(float smoothing, float emitterSolidAngle, double photonsFromSource);

// Differential of a photon leaving a source point with unit direction w.
// `normal` is the source's normal at the point (zero for sources without a
// surface: point and spot lights). Directions per Eqs. 2-3, with the Frisvad
// 2012 basis when w is (nearly) along the normal or there is no normal.
PhotonDifferential emitPhotonDifferential(const Vec3& direction, const Vec3& normal, float emitterArea,
                                          float emitterSolidAngle, double photonsFromSource, float smoothing);

// Eq. 8: the change of the hit point x' = x + t' w on the plane with normal n
// caused by moving the origin by dx.
Vec3 transferPositional(const Vec3& dx, const Vec3& direction, const Vec3& normal);
// Eq. 9: the change of x' caused by turning the direction by dw, at distance t.
Vec3 transferDirectional(const Vec3& dw, float distance, const Vec3& direction, const Vec3& normal);
// Eq. 7 (= Igehy's transfer): moves the differential along `direction` over
// `distance` onto the surface with (geometric) normal `normal`.
void transferDifferential(PhotonDifferential& d, const Vec3& direction, float distance, const Vec3& normal);

// Igehy 1999 §3.2: the directional vectors after mirror reflection of the unit
// direction `direction` about the unit shading normal n, whose derivatives
// along the two parameters are dnU and dnV (RayQuery::shadingNormalDifferential
// of dxU and dxV). Either orientation of n works (the sign cancels).
void reflectDifferential(PhotonDifferential& d, const Vec3& direction, const Vec3& normal, const Vec3& dnU,
                         const Vec3& dnV);
// Igehy 1999 §3.2: the directional vectors after refraction into `refracted`;
// etaRatio = eta_incident / eta_transmitted.
void refractDifferential(PhotonDifferential& d, const Vec3& direction, const Vec3& refracted, const Vec3& normal,
                         const Vec3& dnU, const Vec3& dnV, float etaRatio);
// Dispatches a sampled specular event (reflection, or transmission with
// BsdfSample::eta = eta_transmitted / eta_incident) to the two above. Returns
// false for non-specular samples, after which the differential means nothing.
bool scatterDifferential(PhotonDifferential& d, const Vec3& direction, const Vec3& scattered, const Vec3& normal,
                         const Vec3& dnU, const Vec3& dnV, const BsdfSample& sample);

// Eq. 4: area of the maximum ellipse inscribed in the parallelogram spanned by
// the positional vectors, pi/4 |D_u x x D_v x| (semi-axes 1/2 D_u x, 1/2 D_v x).
float footprintArea(const Vec3& dxU, const Vec3& dxV);
// The directional analogue below Eq. 4: pi/4 |D_theta w x D_phi w|.
float photonSolidAngle(const Vec3& dwU, const Vec3& dwV);
// Range of a splat, 1/2 max(|D_u x|, |D_v x|) (§3.3).
float footprintMajorRadius(const Vec3& dxU, const Vec3& dxV);
// A footprint is collapsed when Eq. 12 is singular: the positional vectors are
// (numerically) parallel or zero, or not finite. Such photons are discarded.
bool footprintCollapsed(const Vec3& dxU, const Vec3& dxV, const Vec3& normal);

// Eq. 12: the top two rows of the inverse of [1/2 D_u x, 1/2 D_v x, n], which map
// an offset from the photon into filter space, where the footprint is the unit
// circle.
struct FootprintFilter {
    Vec3 row0{0.0f};
    Vec3 row1{0.0f};
    Vec2 apply(const Vec3& offset) const { return {glm::dot(row0, offset), glm::dot(row1, offset)}; }
};
FootprintFilter footprintFilter(const Vec3& dxU, const Vec3& dxV, const Vec3& normal);

// Eq. 11: Silverman's second-order kernel on the unit disk (integrates to 1).
inline float silvermanKernel(float x) { return x < 1.0f ? 3.0f * kInvPi * sqr(1.0f - x * x) : 0.0f; }

}  // namespace fg
