// Directional GMM of Vorba et al. 2014, §4.1 (Eq. 1 on the square, the
// Shirley–Chiu map to the hemisphere, pdf_ω = pdf_s / 2π).
#include "engine/guiding/directional_gmm.h"

#include <cmath>

namespace fg {

namespace {
// Below this, std::exp(float) is +0 (the smallest denormal is 2^-149 ~ e^-103.28).
constexpr float kExpUnderflow = -104.0f;

// atan(t) / (π/4) for |t| <= 1: the odd minimax polynomial of Abramowitz and
// Stegun 4.4.49 (absolute error of atan <= 2e-8, below float's half ulp at
// π/4), scaled by 4/π so that the wedge's ±1 edges come out as ±1.
inline float atanUnitOverQuarterPi(float t) {
    const float t2 = t * t;
    float p = 0.0028662257f;
    p = p * t2 - 0.0161657367f;
    p = p * t2 + 0.0429096138f;
    p = p * t2 - 0.0752896400f;
    p = p * t2 + 0.1065626393f;
    p = p * t2 - 0.1420889944f;
    p = p * t2 + 0.1999355085f;
    p = p * t2 - 0.3333314528f;
    p = p * t2 + 1.0f;
    return t * p * (4.0f / kPi);
}
}  // namespace

Vec3 squareToHemisphere(const Vec2& s) {
    const Vec2 d = sampleConcentricDisk(s);
    const float r2 = d.x * d.x + d.y * d.y;
    // The lift keeps areas: a disk of radius r (area πr²) becomes a cap of
    // height r², area 2πr², twice the disk's, everywhere.
    const float scale = std::sqrt(std::max(0.0f, 2.0f - r2));
    return {d.x * scale, d.y * scale, 1.0f - r2};
}

std::optional<Vec2> hemisphereToSquare(const Vec3& w) {
    if (!(w.z >= 0.0f)) return std::nullopt;
    const float r = std::sqrt(std::max(0.0f, 1.0f - w.z));
    const float planar = std::sqrt(w.x * w.x + w.y * w.y);
    if (planar <= 0.0f || r <= 0.0f) return Vec2(0.5f);
    // Inverse of the concentric map. In the wedge where |x| >= |y| the square
    // point is (a, b) = (±r, ±r·φ'/(π/4)), φ' = atan(y/x) the angle from the
    // wedge's axis, and symmetrically with x and y swapped in the other wedge.
    // The ratio lies in [-1, 1], where an odd polynomial gives atan without
    // atan2's quadrant handling (the pdf's most expensive step after exp).
    const bool xWedge = std::abs(w.x) >= std::abs(w.y);
    const float t = xWedge ? w.y / w.x : w.x / w.y;
    const float side = std::copysign(r, xWedge ? w.x : w.y);
    const float across = side * atanUnitOverQuarterPi(t);
    const float a = xWedge ? side : across;
    const float b = xWedge ? across : side;
    return Vec2(std::clamp(0.5f * (a + 1.0f), 0.0f, 1.0f), std::clamp(0.5f * (b + 1.0f), 0.0f, 1.0f));
}

bool DirectionalGmm::finalize() {
    bool ok = true;
    float total = 0.0f;
    for (GmmComponent& c : components) {
        const float det = c.covXX * c.covYY - c.covXY * c.covXY;
        if (!(det > 0.0f) || !(c.covXX > 0.0f) || !std::isfinite(det) || !std::isfinite(c.weight) ||
            !(c.weight >= 0.0f) || !std::isfinite(c.mean.x) || !std::isfinite(c.mean.y)) {
            ok = false;
            break;
        }
        c.invXX = c.covYY / det;
        c.invXY = -c.covXY / det;
        c.invYY = c.covXX / det;
        c.normalisation = 1.0f / (2.0f * kPi * std::sqrt(det));
        c.cholXX = std::sqrt(c.covXX);
        c.cholYX = c.covXY / c.cholXX;
        c.cholYY = std::sqrt(std::max(0.0f, c.covYY - c.cholYX * c.cholYX));
        total += c.weight;
    }
    if (!ok || !(total > 0.0f)) {
        for (GmmComponent& c : components) c.weight = 0.0f;
        return false;
    }
    // Sampling picks components by the running sum of weights; renormalising
    // here keeps the density it samples and the one pdfSquare reports the same.
    for (GmmComponent& c : components) c.weight /= total;
    return true;
}

bool DirectionalGmm::usable() const {
    float total = 0.0f;
    for (const GmmComponent& c : components) total += c.weight;
    return total > 0.0f;
}

float DirectionalGmm::pdfSquare(const Vec2& s) const {
    float sum = 0.0f;
    for (const GmmComponent& c : components) {
        if (c.weight <= 0.0f) continue;
        const float dx = s.x - c.mean.x, dy = s.y - c.mean.y;
        const float q = c.invXX * dx * dx + 2.0f * c.invXY * dx * dy + c.invYY * dy * dy;
        // expf rounds to +0 below ln(2^-150) ~ -103.97, so a far component adds
        // exactly nothing: skipping its exp leaves the sum bit for bit the same
        // (a NaN fails the test and still reaches the sum).
        const float exponent = -0.5f * q;
        if (exponent < kExpUnderflow) continue;
        sum += c.weight * c.normalisation * std::exp(exponent);
    }
    return sum;
}

float DirectionalGmm::pdfLocal(const Vec3& local) const {
    const std::optional<Vec2> s = hemisphereToSquare(local);
    if (!s) return 0.0f;
    return pdfSquare(*s) / kSquareToHemisphereJacobian;
}

Vec2 DirectionalGmm::samplePlane(float uComponent, const Vec2& uGauss) const {
    std::size_t chosen = 0;
    float cumulative = 0.0f;
    for (std::size_t j = 0; j < components.size(); ++j) {
        if (components[j].weight <= 0.0f) continue;
        chosen = j;
        cumulative += components[j].weight;
        if (uComponent < cumulative) break;
    }
    const GmmComponent& c = components[chosen];
    // Box-Muller; 1 - u keeps the logarithm's argument in (0, 1].
    const float radius = std::sqrt(-2.0f * std::log(1.0f - uGauss.x));
    const float angle = 2.0f * kPi * uGauss.y;
    const float z0 = radius * std::cos(angle), z1 = radius * std::sin(angle);
    return {c.mean.x + c.cholXX * z0, c.mean.y + c.cholYX * z0 + c.cholYY * z1};
}

std::optional<Vec3> DirectionalGmm::sampleLocal(float uComponent, const Vec2& uGauss) const {
    const Vec2 s = samplePlane(uComponent, uGauss);
    if (!(s.x >= 0.0f && s.x <= 1.0f && s.y >= 0.0f && s.y <= 1.0f)) return std::nullopt;
    return squareToHemisphere(s);
}

}  // namespace fg
