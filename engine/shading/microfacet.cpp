// GGX / Trowbridge-Reitz microfacet distribution (Trowbridge & Reitz 1975;
// Walter et al. 2007, "Microfacet Models for Refraction through Rough Surfaces",
// Eqs. 33-34) with Smith masking in the closed form for GGX (Heitz 2014,
// "Understanding the Masking-Shadowing Function", Eq. 72 for Lambda), and
// sampling of the distribution of visible normals following Heitz 2018,
// "Sampling the GGX Distribution of Visible Normals" (JCGT 7(4)): the view
// vector is stretched to the unit-roughness configuration, a point is drawn on
// the projected hemisphere (a half disk warped onto the visible half), and the
// resulting normal is unstretched.
// Beckmann distribution with the exact Smith masking and visible-normal
// sampling in slope space (references at BeckmannDistribution in the header).
#include "engine/shading/microfacet.h"

#include <cmath>

namespace fg {

std::optional<MicrofacetType> microfacetTypeFromName(std::string_view name) {
    if (name == "ggx") return MicrofacetType::Ggx;
    if (name == "beckmann") return MicrofacetType::Beckmann;
    return std::nullopt;
}

std::string_view microfacetTypeName(MicrofacetType type) {
    return type == MicrofacetType::Ggx ? "ggx" : "beckmann";
}

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

// ---------------------------------------------------------------------------

namespace {

constexpr double kSqrtPi = 1.7724538509055160273;

// Unnormalised cumulative distribution of the x slope of the unit-roughness
// Beckmann surface seen from a direction at polar angle theta (azimuth 0):
// the visible slope density is proportional to (cos - x sin) exp(-x^2 - y^2)
// (Heitz & d'Eon 2014, Eq. 18 with the Gaussian slope density P22 of
// Beckmann at alpha = 1). Dividing by cos and writing w = tan(theta),
//   integral_{-inf}^{x} (1 - w t) exp(-t^2) dt = sqrt(pi)/2 erfc(-x) + w/2 exp(-x^2),
// valid for x <= 1 / w, beyond which the facets face away. With w = 0 this is
// the CDF of the y slope (and of x at normal incidence), a Gaussian of variance 1/2.
double visibleSlopeCdf(double x, double w) {
    return 0.5 * kSqrtPi * std::erfc(-x) + 0.5 * w * std::exp(-x * x);
}

// Inverts visibleSlopeCdf for u in [0, 1) by Newton's method safeguarded with
// bisection (the CDF is monotonic on [lo, hi], so the bracket always shrinks).
// Slopes beyond +-8 carry less than exp(-64) of the mass and are cut off.
double sampleVisibleSlope(double u, double w) {
    constexpr double kSlopeLimit = 8.0;
    double lo = -kSlopeLimit;
    double hi = w > 1.0 / kSlopeLimit ? 1.0 / w : kSlopeLimit;
    const double floorValue = visibleSlopeCdf(lo, w);
    const double target = floorValue + u * (visibleSlopeCdf(hi, w) - floorValue);
    double x = std::clamp(0.0, lo, hi);
    for (int iteration = 0; iteration < 64; ++iteration) {
        const double f = visibleSlopeCdf(x, w) - target;
        if (f > 0.0) hi = x;
        else lo = x;
        const double derivative = (1.0 - w * x) * std::exp(-x * x);
        double next = derivative > 0.0 ? x - f / derivative : 0.5 * (lo + hi);
        if (!(next > lo && next < hi)) next = 0.5 * (lo + hi);
        // Well below single precision, which is what the normal is returned in.
        if (std::abs(next - x) <= 1e-8 * (1.0 + std::abs(x))) return next;
        x = next;
    }
    return x;
}

}  // namespace

BeckmannDistribution::BeckmannDistribution(float alpha) : alpha_(std::max(alpha, kMinAlpha)) {}

float BeckmannDistribution::D(const Vec3& m) const {
    if (m.z <= 0.0f) return 0.0f;
    // exp(-tan^2 / a^2) / (pi a^2 cos^4); the exponential reaches 0 long
    // before cos^4 does, so grazing normals give 0 rather than 0/0.
    const float c2 = cos2Theta(m);
    const float a2 = alpha_ * alpha_;
    const float tan2 = sin2Theta(m) / c2;
    return std::exp(-tan2 / a2) / (kPi * a2 * c2 * c2);
}

float BeckmannDistribution::lambda(const Vec3& w) const {
    // Lambda = (erf(a) - 1) / 2 + exp(-a^2) / (2 a sqrt(pi)) with a = 1 / (alpha tan(theta)).
    // Mitsuba 3 uses Walter's rational approximation of G1 (within 0.35 %);
    // the exact form is kept here because only with it does the visible-normal
    // density that sampleVisibleNormal draws from integrate to one.
    const double c = std::abs(static_cast<double>(w.z));
    const double s = std::sqrt(std::max(0.0, 1.0 - c * c));
    if (s == 0.0) return 0.0f;
    if (c == 0.0) return kInfinity;
    const double a = c / (static_cast<double>(alpha_) * s);
    // Lambda decays like exp(-a^2) / (4 sqrt(pi) a^3): below 3e-10 from a = 4
    // on, where G1 rounds to 1 in single precision, so the common case of a
    // direction well above a smooth surface skips erfc.
    if (a >= 4.0) return 0.0f;
    const double value = 0.5 * (std::exp(-a * a) / (a * kSqrtPi) - std::erfc(a));
    return static_cast<float>(std::max(value, 0.0));
}

float BeckmannDistribution::G1(const Vec3& w) const {
    if (w.z == 0.0f) return 0.0f;
    return 1.0f / (1.0f + lambda(w));
}

float BeckmannDistribution::visibleNormalPdf(const Vec3& wo, const Vec3& m) const {
    if (wo.z <= 0.0f) return 0.0f;
    const float cosOM = glm::dot(wo, m);
    if (cosOM <= 0.0f) return 0.0f;
    return G1(wo) * cosOM * D(m) / wo.z;
}

Vec3 BeckmannDistribution::sampleVisibleNormal(const Vec3& wo, const Vec2& u) const {
    // Stretch to unit roughness: there the slope distribution is the standard
    // Beckmann one, and the view direction keeps its azimuth.
    const glm::dvec3 stretched = glm::normalize(glm::dvec3(alpha_ * wo.x, alpha_ * wo.y, wo.z));
    const double sinTheta = std::sqrt(stretched.x * stretched.x + stretched.y * stretched.y);
    const double tanTheta = sinTheta / stretched.z;
    const double cosPhi = sinTheta > 0.0 ? stretched.x / sinTheta : 1.0;
    const double sinPhi = sinTheta > 0.0 ? stretched.y / sinTheta : 0.0;

    // In the frame where the view has azimuth 0 the visible slopes factor into
    // the marginal of x (weighted by the projected area) and a Gaussian y.
    const double slopeX = sampleVisibleSlope(u.x, tanTheta);
    const double slopeY = sampleVisibleSlope(u.y, 0.0);

    // Rotate to the view's azimuth, unstretch, and turn the slope into a normal.
    const double x = alpha_ * (cosPhi * slopeX - sinPhi * slopeY);
    const double y = alpha_ * (sinPhi * slopeX + cosPhi * slopeY);
    return Vec3(glm::normalize(glm::dvec3(-x, -y, 1.0)));
}

}  // namespace fg
