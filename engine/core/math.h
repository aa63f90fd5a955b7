// Small numeric vocabulary shared by every module: vector aliases over GLM, an
// orthonormal shading frame and the elementary warps from [0,1)^2 to shapes.
// Colours are linear RGB triples (Rgb); directions in a Frame's local space put
// the normal on +z, so cos(theta) is simply v.z.
#pragma once

#include <glm/glm.hpp>

#include <algorithm>
#include <cmath>
#include <cstdint>

namespace fg {

using Vec2 = glm::vec2;
using Vec3 = glm::vec3;
using Vec4 = glm::vec4;
using Rgb = glm::vec3;
using Mat3 = glm::mat3;
using Mat4 = glm::mat4;

inline constexpr float kPi = 3.14159265358979323846f;
inline constexpr float kInvPi = 0.31830988618379067154f;
inline constexpr float kInv2Pi = 0.15915494309189533577f;
inline constexpr float kInv4Pi = 0.07957747154594766788f;
inline constexpr float kInfinity = 1e30f;
// Offset applied along the normal when spawning rays, relative to scene scale 1.
inline constexpr float kRayEpsilon = 1e-4f;

inline float luminance(const Rgb& c) { return 0.2126f * c.x + 0.7152f * c.y + 0.0722f * c.z; }
inline float maxComponent(const Rgb& c) { return std::max(c.x, std::max(c.y, c.z)); }
inline float average(const Rgb& c) { return (c.x + c.y + c.z) * (1.0f / 3.0f); }
inline bool isBlack(const Rgb& c) { return c.x == 0.0f && c.y == 0.0f && c.z == 0.0f; }
inline bool isFinite(const Rgb& c) { return std::isfinite(c.x) && std::isfinite(c.y) && std::isfinite(c.z); }
inline float sqr(float x) { return x * x; }
inline float safeSqrt(float x) { return std::sqrt(std::max(0.0f, x)); }
inline float clamp01(float x) { return std::clamp(x, 0.0f, 1.0f); }

// Orthonormal basis around a unit normal (Duff et al. 2017, branchless).
struct Frame {
    Vec3 s{1, 0, 0}, t{0, 1, 0}, n{0, 0, 1};

    Frame() = default;
    explicit Frame(const Vec3& normal) : n(normal) {
        const float sign = std::copysign(1.0f, n.z);
        const float a = -1.0f / (sign + n.z);
        const float b = n.x * n.y * a;
        s = Vec3(1.0f + sign * n.x * n.x * a, sign * b, -sign * n.x);
        t = Vec3(b, sign + n.y * n.y * a, -n.y);
    }
    Vec3 toLocal(const Vec3& v) const { return {glm::dot(v, s), glm::dot(v, t), glm::dot(v, n)}; }
    Vec3 toWorld(const Vec3& v) const { return s * v.x + t * v.y + n * v.z; }
};

// Local-frame trigonometry (normal = +z).
inline float cosTheta(const Vec3& w) { return w.z; }
inline float absCosTheta(const Vec3& w) { return std::abs(w.z); }
inline float cos2Theta(const Vec3& w) { return w.z * w.z; }
inline float sin2Theta(const Vec3& w) { return std::max(0.0f, 1.0f - w.z * w.z); }
inline float tan2Theta(const Vec3& w) { return sin2Theta(w) / cos2Theta(w); }
inline bool sameHemisphere(const Vec3& a, const Vec3& b) { return a.z * b.z > 0.0f; }

inline Vec3 reflect(const Vec3& wo, const Vec3& n) { return -wo + 2.0f * glm::dot(wo, n) * n; }

// Concentric disk mapping (Shirley & Chiu 1997): area preserving, low distortion.
inline Vec2 sampleConcentricDisk(const Vec2& u) {
    const Vec2 p = 2.0f * u - Vec2(1.0f);
    if (p.x == 0.0f && p.y == 0.0f) return Vec2(0.0f);
    float r, theta;
    if (std::abs(p.x) > std::abs(p.y)) {
        r = p.x;
        theta = (kPi / 4.0f) * (p.y / p.x);
    } else {
        r = p.y;
        theta = (kPi / 2.0f) - (kPi / 4.0f) * (p.x / p.y);
    }
    return r * Vec2(std::cos(theta), std::sin(theta));
}

inline Vec3 sampleCosineHemisphere(const Vec2& u) {
    const Vec2 d = sampleConcentricDisk(u);
    return {d.x, d.y, safeSqrt(1.0f - d.x * d.x - d.y * d.y)};
}
inline float cosineHemispherePdf(float cosTheta) { return std::max(cosTheta, 0.0f) * kInvPi; }

inline Vec3 sampleUniformSphere(const Vec2& u) {
    const float z = 1.0f - 2.0f * u.x;
    const float r = safeSqrt(1.0f - z * z);
    const float phi = 2.0f * kPi * u.y;
    return {r * std::cos(phi), r * std::sin(phi), z};
}
inline constexpr float uniformSpherePdf() { return kInv4Pi; }

// Uniform direction inside a cone of half-angle acos(cosThetaMax) around +z.
inline Vec3 sampleUniformCone(const Vec2& u, float cosThetaMax) {
    const float cosT = 1.0f - u.x * (1.0f - cosThetaMax);
    const float sinT = safeSqrt(1.0f - cosT * cosT);
    const float phi = 2.0f * kPi * u.y;
    return {sinT * std::cos(phi), sinT * std::sin(phi), cosT};
}
inline float uniformConePdf(float cosThetaMax) { return 1.0f / (2.0f * kPi * (1.0f - cosThetaMax)); }

// Barycentrics (b1, b2) of a uniform point on a triangle; b0 = 1 - b1 - b2.
inline Vec2 sampleUniformTriangle(const Vec2& u) {
    const float su = std::sqrt(u.x);
    return {1.0f - su, u.y * su};
}

// Power heuristic with beta = 2 (Veach 1997, Eq. 9.13).
inline float powerHeuristic(float pdfA, float pdfB) {
    const float a = pdfA * pdfA, b = pdfB * pdfB;
    return a + b > 0.0f ? a / (a + b) : 0.0f;
}

}  // namespace fg
