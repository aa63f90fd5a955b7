// GGX / Trowbridge-Reitz microfacet distribution (Trowbridge & Reitz 1975;
// Walter et al. 2007, "Microfacet Models for Refraction through Rough Surfaces",
// Eqs. 33-34) with Smith masking in the closed form for GGX (Heitz 2014,
// "Understanding the Masking-Shadowing Function", Eq. 72 for Lambda), and
// sampling of the distribution of visible normals following Heitz 2018,
// "Sampling the GGX Distribution of Visible Normals" (JCGT 7(4)): the view
// vector is stretched to the unit-roughness configuration, a point is drawn on
// the projected hemisphere (a half disk warped onto the visible half), and the
// resulting normal is unstretched.
#include "engine/shading/microfacet.h"

namespace fg {

GgxDistribution::GgxDistribution(float alpha) : alpha_(std::max(alpha, kMinAlpha)) {}

float GgxDistribution::D(const Vec3& m) const {
    if (m.z <= 0.0f) return 0.0f;
    // 1 / (pi a^2 cos^4 (1 + tan^2 / a^2)^2) rewritten without tan, which is
    // finite for every m and loses no precision near the pole.
    const float a2 = alpha_ * alpha_;
    const float denom = cos2Theta(m) * (a2 - 1.0f) + 1.0f;
    return a2 / (kPi * denom * denom);
}

float GgxDistribution::lambda(const Vec3& w) const {
    const float c2 = cos2Theta(w);
    if (c2 <= 0.0f) return kInfinity;
    const float a2Tan2 = alpha_ * alpha_ * sin2Theta(w) / c2;
    return 0.5f * (std::sqrt(1.0f + a2Tan2) - 1.0f);
}

float GgxDistribution::G1(const Vec3& w) const {
    // 2 / (1 + sqrt(1 + a^2 tan^2)) multiplied through by |cos| so that grazing
    // directions give 0 instead of 0/0.
    const float c = absCosTheta(w);
    const float root = std::sqrt(cos2Theta(w) + alpha_ * alpha_ * sin2Theta(w));
    const float denom = c + root;
    return denom > 0.0f ? 2.0f * c / denom : 0.0f;
}

float GgxDistribution::visibleNormalPdf(const Vec3& wo, const Vec3& m) const {
    if (wo.z <= 0.0f) return 0.0f;
    const float cosOM = glm::dot(wo, m);
    if (cosOM <= 0.0f) return 0.0f;
    return G1(wo) * cosOM * D(m) / wo.z;
}

Vec3 GgxDistribution::sampleVisibleNormal(const Vec3& wo, const Vec2& u) const {
    // Stretch: in this space the microsurface is a hemisphere of radius 1.
    const Vec3 vh = glm::normalize(Vec3(alpha_ * wo.x, alpha_ * wo.y, wo.z));
    const float lenSq = vh.x * vh.x + vh.y * vh.y;
    const Vec3 t1 = lenSq > 0.0f ? Vec3(-vh.y, vh.x, 0.0f) / std::sqrt(lenSq) : Vec3(1.0f, 0.0f, 0.0f);
    const Vec3 t2 = glm::cross(vh, t1);

    // Uniform point on the unit disk, then the half that is hidden behind the
    // hemisphere's silhouette is squeezed onto the visible part.
    const float r = std::sqrt(u.x);
    const float phi = 2.0f * kPi * u.y;
    const float p1 = r * std::cos(phi);
    float p2 = r * std::sin(phi);
    const float s = 0.5f * (1.0f + vh.z);
    p2 = (1.0f - s) * safeSqrt(1.0f - p1 * p1) + s * p2;

    // Project onto the hemisphere and unstretch back to the alpha configuration.
    const Vec3 nh = p1 * t1 + p2 * t2 + safeSqrt(1.0f - p1 * p1 - p2 * p2) * vh;
    const Vec3 m(alpha_ * nh.x, alpha_ * nh.y, std::max(nh.z, 1e-7f));
    return glm::normalize(m);
}

}  // namespace fg
