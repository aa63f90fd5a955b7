// Photon differentials after Frisvad, Schjøth, Erleben and Sporring 2014,
// "Photon Differential Splatting for Rendering Caustics" (§3.1-3.3).
//
// Emission (Eqs. 2-3) picks the positional pair (tangent to the source) and
// the directional pair (perpendicular to w) so that D_u x and D_theta w share
// the direction n x w, and D_v x = D_u x x n, D_phi w = D_theta w x w. Both of
// the latter are perpendicular to n x w, so they lie in the plane spanned by n
// and w; a transfer (Eqs. 8-9) moves vectors of that plane along w onto the
// receiving plane, which keeps them in one line: the pairs are parallel after
// the first transfer (Appendix A), and the photon can be carried as Igehy's
// two-vector ray differential with D_u x' = (D_u + D_theta) x' (Eq. 7). Where
// n x w vanishes (emission along the normal, or a source without a surface)
// the basis comes from Frisvad 2012 instead. Lengths follow Eqs. 5-6.
//
// Specular reflection and refraction change the directional vectors as in
// Igehy 1999, "Tracing Ray Differentials", §3.2, including the derivative of
// the shading normal; both formulas were derived again for unit directions:
//   reflection  r = w - 2 (w.n) n,
//     dr = dw - 2 [ (dw.n + w.dn) n + (w.n) dn ];
//   refraction  t = eta w + (eta c_i - c_t) n,  n facing the incident side,
//     c_i = -w.n,  c_t = sqrt(1 - eta^2 (1 - c_i^2)) = -t.n,
//     dc_i = -(dw.n + w.dn),  dc_t = eta^2 c_i dc_i / c_t,
//     dt = eta dw + (eta dc_i - dc_t) n + (eta c_i - c_t) dn,
// with eta = eta_incident / eta_transmitted (Igehy writes t = eta w - mu n
// with mu = eta (w.n) - (t.n) = -(eta c_i - c_t): the same vector).
//
// Eq. 12 was checked against the inverse of A = [a b n] with a = D_u x / 2,
// b = D_v x / 2: the rows of A^-1 are (b x n, n x a, a x b) / (a . (b x n)),
// which for the first two rows is exactly 2 / (D_u x . (D_v x x n)) times
// (D_v x x n, n x D_u x), as transcribed.
#include "engine/shading/differentials.h"

#include <cmath>

namespace fg {

namespace {

// |n x w| below this counts as "w along the normal" (about 0.06 degrees):
// Eq. 2 would normalise a vector dominated by rounding.
constexpr float kParallelThreshold = 1e-3f;

// Footprints whose parallelogram is thinner than this fraction of |D_u x||D_v x|
// are collapsed: Eq. 12 would be dominated by rounding.
constexpr double kCollapseThreshold = 1e-6;

}  // namespace

void frisvadBasis(const Vec3& n, Vec3* b1, Vec3* b2) {
    // Frisvad's formula divides by 1 + n.z and loses accuracy as n.z -> -1
    // (Max 2017, "Improved accuracy when building an orthonormal basis"); in the
    // lower hemisphere the same construction is mirrored through the xy-plane
    // (Duff et al. 2017), so the divisor stays >= 1.
    const float sign = n.z >= 0.0f ? 1.0f : -1.0f;
    const float a = 1.0f / (sign + n.z);
    const float b = -n.x * n.y * a;
    *b1 = Vec3(1.0f - sign * n.x * n.x * a, sign * b, -sign * n.x);
    *b2 = Vec3(b, sign - n.y * n.y * a, -n.y);
}

float initialPositionalLength(float smoothing, float emitterArea, double photonsFromSource) {
    if (!(photonsFromSource > 0.0) || !(emitterArea > 0.0f)) return 0.0f;
    return static_cast<float>(2.0 * smoothing * std::sqrt(static_cast<double>(emitterArea) / (M_PI * photonsFromSource)));
}

float initialDirectionalLength(float smoothing, float emitterSolidAngle, double photonsFromSource) {
    if (!(photonsFromSource > 0.0) || !(emitterSolidAngle > 0.0f)) return 0.0f;
    return static_cast<float>(2.0 * smoothing *
                              std::sqrt(static_cast<double>(emitterSolidAngle) / (M_PI * photonsFromSource)));
}

PhotonDifferential emitPhotonDifferential(const Vec3& direction, const Vec3& normal, float emitterArea,
                                          float emitterSolidAngle, double photonsFromSource, float smoothing) {
    const float positional = initialPositionalLength(smoothing, emitterArea, photonsFromSource);
    const float directional = initialDirectionalLength(smoothing, emitterSolidAngle, photonsFromSource);
    const float normalLength = glm::length(normal);
    const bool hasNormal = normalLength > 0.0f;
    const Vec3 n = hasNormal ? normal / normalLength : Vec3(0.0f);

    PhotonDifferential d;
    const Vec3 nCrossW = glm::cross(n, direction);
    const float nCrossWLength = glm::length(nCrossW);
    if (hasNormal && nCrossWLength > kParallelThreshold) {
        const Vec3 u = nCrossW / nCrossWLength;  // Eq. 2
        d.dxU = positional * u;
        d.dxV = positional * glm::cross(u, n);  // Eq. 3, left
        d.dwU = directional * u;
        d.dwV = directional * glm::cross(u, direction);  // Eq. 3, right
        return d;
    }
    // The uv-plane and the theta-phi-plane (nearly) coincide, or there is no
    // uv-plane: any orthonormal pair will do, as long as the two pairs agree.
    Vec3 b1, b2;
    frisvadBasis(hasNormal ? n : direction, &b1, &b2);
    if (hasNormal) {
        d.dxU = positional * b1;
        d.dxV = positional * glm::cross(b1, n);
    }
    const Vec3 t = glm::normalize(b1 - glm::dot(b1, direction) * direction);
    d.dwU = directional * t;
    d.dwV = directional * glm::cross(t, direction);
    return d;
}

Vec3 transferPositional(const Vec3& dx, const Vec3& direction, const Vec3& normal) {
    return dx - (glm::dot(normal, dx) / glm::dot(normal, direction)) * direction;
}

Vec3 transferDirectional(const Vec3& dw, float distance, const Vec3& direction, const Vec3& normal) {
    return distance * (dw - (glm::dot(normal, dw) / glm::dot(normal, direction)) * direction);
}

void transferDifferential(PhotonDifferential& d, const Vec3& direction, float distance, const Vec3& normal) {
    d.dxU = transferPositional(d.dxU, direction, normal) + transferDirectional(d.dwU, distance, direction, normal);
    d.dxV = transferPositional(d.dxV, direction, normal) + transferDirectional(d.dwV, distance, direction, normal);
}

namespace {

Vec3 reflectedDirectionDifferential(const Vec3& w, const Vec3& n, const Vec3& dw, const Vec3& dn) {
    const float wn = glm::dot(w, n);
    const float dwn = glm::dot(dw, n) + glm::dot(w, dn);
    return dw - 2.0f * (dwn * n + wn * dn);
}

Vec3 refractedDirectionDifferential(const Vec3& w, const Vec3& n, float cosI, float cosT, float eta, const Vec3& dw,
                                    const Vec3& dn) {
    const float dCosI = -(glm::dot(dw, n) + glm::dot(w, dn));
    const float dCosT = eta * eta * cosI * dCosI / cosT;
    return eta * dw + (eta * dCosI - dCosT) * n + (eta * cosI - cosT) * dn;
}

}  // namespace

void reflectDifferential(PhotonDifferential& d, const Vec3& direction, const Vec3& normal, const Vec3& dnU,
                         const Vec3& dnV) {
    d.dwU = reflectedDirectionDifferential(direction, normal, d.dwU, dnU);
    d.dwV = reflectedDirectionDifferential(direction, normal, d.dwV, dnV);
}

void refractDifferential(PhotonDifferential& d, const Vec3& direction, const Vec3& refracted, const Vec3& normal,
                         const Vec3& dnU, const Vec3& dnV, float etaRatio) {
    // The formulas want the normal on the incident side.
    const float side = glm::dot(direction, normal) > 0.0f ? -1.0f : 1.0f;
    const Vec3 n = side * normal;
    const float cosI = -glm::dot(direction, n);
    // The cosine of the direction actually taken, so that the derivative belongs to it.
    const float cosT = std::max(-glm::dot(refracted, n), 1e-6f);
    d.dwU = refractedDirectionDifferential(direction, n, cosI, cosT, etaRatio, d.dwU, side * dnU);
    d.dwV = refractedDirectionDifferential(direction, n, cosI, cosT, etaRatio, d.dwV, side * dnV);
}

bool scatterDifferential(PhotonDifferential& d, const Vec3& direction, const Vec3& scattered, const Vec3& normal,
                         const Vec3& dnU, const Vec3& dnV, const BsdfSample& sample) {
    if (!sample.isSpecular()) return false;
    if (sample.lobe & BsdfLobe::Transmission) {
        const float etaRatio = sample.eta > 0.0f ? 1.0f / sample.eta : 1.0f;
        refractDifferential(d, direction, scattered, normal, dnU, dnV, etaRatio);
    } else {
        reflectDifferential(d, direction, normal, dnU, dnV);
    }
    return true;
}

float footprintArea(const Vec3& dxU, const Vec3& dxV) { return 0.25f * kPi * glm::length(glm::cross(dxU, dxV)); }

float photonSolidAngle(const Vec3& dwU, const Vec3& dwV) { return 0.25f * kPi * glm::length(glm::cross(dwU, dwV)); }

float footprintMajorRadius(const Vec3& dxU, const Vec3& dxV) {
    return 0.5f * std::max(glm::length(dxU), glm::length(dxV));
}

bool footprintCollapsed(const Vec3& dxU, const Vec3& dxV, const Vec3& normal) {
    // In double: the product of two small lengths may underflow in float.
    const glm::dvec3 u(dxU), v(dxV), n(normal);
    const double lengths = glm::length(u) * glm::length(v) * glm::length(n);
    const double determinant = std::abs(glm::dot(u, glm::cross(v, n)));
    if (!std::isfinite(lengths) || !std::isfinite(determinant) || !(lengths > 0.0)) return true;
    return determinant <= kCollapseThreshold * lengths;
}

FootprintFilter footprintFilter(const Vec3& dxU, const Vec3& dxV, const Vec3& normal) {
    const Vec3 vCrossN = glm::cross(dxV, normal);
    const float scale = 2.0f / glm::dot(dxU, vCrossN);
    return {scale * vCrossN, scale * glm::cross(normal, dxU)};
}

}  // namespace fg
