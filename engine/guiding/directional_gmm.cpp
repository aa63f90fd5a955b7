// Directional GMM of Vorba et al. 2014, §4.1 (Eq. 1 on the square, the
// Shirley–Chiu map to the hemisphere, pdf_ω = pdf_s / 2π). Guided path
// tracing evaluates and samples a mixture at every guided vertex, and the
// paper's §6 budgets 5 % of the time for each: the density reads the
// components as lanes (GmmLanes) with precomputed inverse covariances and
// normalisers, takes 2^x by a polynomial and the exponent field, and the
// sampler, the map and its inverse use polynomials for log, sin, cos and atan
// on reduced ranges instead of the library's general routines.
#include "engine/guiding/directional_gmm.h"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>

namespace fg {

namespace {
// Below this, 2^x is taken as exactly zero: 2^-125 is still a normal float,
// so the exponent-field construction in exp2NonPositive stays valid down to
// it, and a component that far from the point adds nothing a float sum of
// the others could hold (e^-86.6 against a density of at least e^-20 or so
// wherever the mixture is sampled).
constexpr float kExp2Cutoff = -125.0f;
// Adding 1.5·2^23 to a float of magnitude below 2^22 rounds it to an integer
// held in the low mantissa bits (round to nearest even, SSE2's own rounding),
// with no conversion instruction, so the loops over lanes stay vector code.
constexpr float kRoundingShift = 12582912.0f;

// Four lanes at once in GCC's generic vector types: SSE2 on every x86-64
// CPU, lowered to whatever the target has elsewhere. A plain loop over the
// lanes is not vectorised here: under the default -ftrapping-math GCC will not
// turn the exponent's clamps and cutoff into selects, and keeps the branches.
typedef float Float4 __attribute__((vector_size(16)));
typedef std::int32_t Int4 __attribute__((vector_size(16)));

inline Float4 loadLanes(const GmmLanes::Lanes& lanes, std::size_t first) {
    Float4 v;
    std::memcpy(&v, lanes.data() + first, sizeof(v));
    return v;
}

// 2^x for x <= 0, exactly 0 below kExp2Cutoff: x = n + f with n an integer
// and |f| <= ½, 2^f by its Taylor series in f ln 2 to degree 7 (the remainder
// (½ ln 2)^8 / 8! ~ 5e-9 is below float's half ulp), 2^n added to the
// exponent field. A positive x can only be rounding in a quadratic form that
// is >= 0, and counts as 0.
inline Float4 exp2NonPositive(Float4 x) {
    const Float4 zero = {};
    const Float4 cutoff = zero + kExp2Cutoff;
    const Int4 inRange = x >= cutoff;
    Float4 clamped = inRange ? x : cutoff;
    clamped = clamped < zero ? clamped : zero;
    const Float4 shifted = clamped + kRoundingShift;
    const Float4 f = clamped - (shifted - kRoundingShift);
    const Int4 exponentBits = (std::bit_cast<Int4>(shifted) - std::bit_cast<std::int32_t>(kRoundingShift))
                              << 23;
    // c_k = ln(2)^k / k!, summed in Estrin's order: the pairs and the powers
    // of f are independent, so the chain of dependent steps is four long, not
    // Horner's fourteen.
    const Float4 f2 = f * f, f4 = f2 * f2;
    const Float4 p01 = f * 6.9314718055994531e-01f + 1.0f;
    const Float4 p23 = f * 5.5504108664821580e-02f + 2.4022650695910071e-01f;
    const Float4 p45 = f * 1.3333558146428443e-03f + 9.6181291076284772e-03f;
    const Float4 p67 = f * 1.5252733804059841e-05f + 1.5403530393381606e-04f;
    const Float4 p = (p01 + f2 * p23) + f4 * (p45 + f2 * p67);
    const Int4 valueBits = std::bit_cast<Int4>(p) + exponentBits;
    const Float4 value = std::bit_cast<Float4>(valueBits);
    return inRange ? value : zero;
}

// ln x for a normal float x > 0: x = m 2^e with m in [√½, √2), then
// ln m = 2 atanh(s), s = (m - 1) / (m + 1), |s| <= 0.172, by its odd series to
// s⁹ (the next term, 2 s¹¹ / 11, is below 7e-10).
inline float logPositive(float x) {
    constexpr std::int32_t kSqrtHalfBits = 0x3f3504f3;
    const std::int32_t bits = std::bit_cast<std::int32_t>(x);
    const std::int32_t e = (bits - kSqrtHalfBits) >> 23;
    const float m = std::bit_cast<float>(bits - e * (1 << 23));
    const float s = (m - 1.0f) / (m + 1.0f);
    const float s2 = s * s;
    float p = 1.0f / 9.0f;
    p = p * s2 + 1.0f / 7.0f;
    p = p * s2 + 1.0f / 5.0f;
    p = p * s2 + 1.0f / 3.0f;
    p = p * s2 + 1.0f;
    return static_cast<float>(e) * 0.69314718055994531f + 2.0f * s * p;
}

// sin and cos of |t| <= π/4 by their Taylor series to degree 9 and 10
// (remainders below 2e-9 and 2e-10).
struct SinCos {
    float sin, cos;
};
inline SinCos sinCosQuarterPi(float t) {
    const float t2 = t * t;
    float s = 1.0f / 362880.0f;
    s = s * t2 - 1.0f / 5040.0f;
    s = s * t2 + 1.0f / 120.0f;
    s = s * t2 - 1.0f / 6.0f;
    s = s * t2 + 1.0f;
    float c = -1.0f / 3628800.0f;
    c = c * t2 + 1.0f / 40320.0f;
    c = c * t2 - 1.0f / 720.0f;
    c = c * t2 + 1.0f / 24.0f;
    c = c * t2 - 0.5f;
    c = c * t2 + 1.0f;
    return {t * s, c};
}

// cos and sin of 2π v for v in [0, 1): the nearest quarter turn k is split
// off exactly (4v - k is exact in float), the rest, within ±π/4, goes to the
// polynomials, and the quarter turns swap and negate the pair.
inline SinCos sinCosOfTurn(float v) {
    const float quarters = 4.0f * v;
    const int k = static_cast<int>(quarters + 0.5f);
    const SinCos r = sinCosQuarterPi((quarters - static_cast<float>(k)) * (0.5f * kPi));
    switch (k & 3) {
        case 0: return r;
        case 1: return {r.cos, -r.sin};
        case 2: return {-r.sin, -r.cos};
        default: return {-r.cos, r.sin};
    }
}

// atan(t) / (π/4) for |t| <= 1: the odd minimax polynomial of Abramowitz and
// Stegun 4.4.49 (absolute error of atan <= 2e-8, below float's half ulp at
// π/4), scaled by 4/π so that the wedge's ±1 edges come out as ±1.
inline float atanUnitOverQuarterPi(float t) {
    // Estrin's order, as in exp2NonPositive: the pdf waits for this chain.
    const float t2 = t * t, t4 = t2 * t2, t8 = t4 * t4;
    const float p01 = -0.3333314528f * t2 + 1.0f;
    const float p23 = -0.1420889944f * t2 + 0.1999355085f;
    const float p45 = -0.0752896400f * t2 + 0.1065626393f;
    const float p67 = -0.0161657367f * t2 + 0.0429096138f;
    const float p = ((p01 + t4 * p23) + t8 * (p45 + t4 * p67)) + (t8 * t8) * 0.0028662257f;
    return t * p * (4.0f / kPi);
}
}  // namespace

Vec3 squareToHemisphere(const Vec2& s) {
    // The concentric map (Shirley and Chiu 1997) with its angle measured from
    // the wedge's axis: in the wedge where |a| > |b| the disk point is
    // a (cos t, sin t), t = (π/4) b/a, and in the other b (sin t, cos t),
    // t = (π/4) a/b, so |t| <= π/4 and the polynomials need no reduction.
    const float a = 2.0f * s.x - 1.0f, b = 2.0f * s.y - 1.0f;
    if (a == 0.0f && b == 0.0f) return {0.0f, 0.0f, 1.0f};
    const bool xWedge = std::abs(a) > std::abs(b);
    const float r = xWedge ? a : b;
    const SinCos t = sinCosQuarterPi((0.25f * kPi) * (xWedge ? b / a : a / b));
    const float r2 = r * r;
    // The lift keeps areas: a disk of radius r (area πr²) becomes a cap of
    // height r², area 2πr², twice the disk's, everywhere.
    const float scale = r * std::sqrt(std::max(0.0f, 2.0f - r2));
    return xWedge ? Vec3(t.cos * scale, t.sin * scale, 1.0f - r2) : Vec3(t.sin * scale, t.cos * scale, 1.0f - r2);
}

std::optional<Vec2> hemisphereToSquare(const Vec3& w) {
    if (!(w.z >= 0.0f)) return std::nullopt;
    const float r = std::sqrt(std::max(0.0f, 1.0f - w.z));
    if ((w.x == 0.0f && w.y == 0.0f) || r <= 0.0f) return Vec2(0.5f);
    // Inverse of the concentric map. In the wedge where |x| >= |y| the square
    // point is (a, b) = (±r, ±r·φ'/(π/4)), φ' = atan(y/x) the angle from the
    // wedge's axis, and symmetrically with x and y swapped in the other wedge.
    // The ratio's magnitude, min/max of |x| and |y|, lies in [0, 1], where an
    // odd polynomial gives atan without atan2's quadrant handling (the pdf's
    // most expensive step after exp). a and b take x's and y's signs, and the
    // wedge only decides which of them is ±r: written as max() with the
    // wedge's 0 or 1, not as a choice between two expressions, because GCC
    // compiles the choice into a branch that guided directions, spread over
    // both wedges, mispredict about every second time. The polynomial gives
    // exactly 1 at 1, so max(g, 1) is 1 and the result equals the two-branch
    // form bit for bit.
    const float absX = std::abs(w.x), absY = std::abs(w.y);
    const float inWedgeX = static_cast<float>(absX >= absY);
    const float g = atanUnitOverQuarterPi(std::min(absX, absY) / std::max(absX, absY));
    const float a = std::copysign(r * std::max(g, inWedgeX), w.x);
    const float b = std::copysign(r * std::max(g, 1.0f - inWedgeX), w.y);
    return Vec2(std::min(std::max(0.5f * (a + 1.0f), 0.0f), 1.0f), std::min(std::max(0.5f * (b + 1.0f), 0.0f), 1.0f));
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
    lanes = GmmLanes{};
    if (!ok || !(total > 0.0f)) {
        for (GmmComponent& c : components) c.weight = 0.0f;
        lanes.cdf.fill(0.0f);
        return false;
    }
    // Sampling picks components by the running sum of weights; renormalising
    // here keeps the density it samples and the one pdfSquare reports the same.
    for (GmmComponent& c : components) c.weight /= total;
    constexpr float kLog2E = 1.44269504088896341f;
    float cumulative = 0.0f;
    std::size_t last = 0;
    for (std::size_t j = 0; j < components.size(); ++j) {
        const GmmComponent& c = components[j];
        cumulative += c.weight;
        lanes.cdf[j] = cumulative;
        if (!(c.weight > 0.0f)) continue;
        last = j;
        lanes.meanX[j] = c.mean.x;
        lanes.meanY[j] = c.mean.y;
        lanes.cholXX[j] = c.cholXX;
        lanes.cholYX[j] = c.cholYX;
        lanes.cholYY[j] = c.cholYY;
        lanes.quadXX[j] = -0.5f * kLog2E * c.invXX;
        lanes.quadXY[j] = -kLog2E * c.invXY;
        lanes.quadYY[j] = -0.5f * kLog2E * c.invYY;
        lanes.scale[j] = c.weight * c.normalisation;
    }
    // The running sum may end a rounding error short of 1; the last non-empty
    // component takes every u beyond the one before it.
    std::fill(lanes.cdf.begin() + static_cast<std::ptrdiff_t>(last), lanes.cdf.end(),
              std::numeric_limits<float>::infinity());
    return true;
}

bool DirectionalGmm::usable() const {
    float total = 0.0f;
    for (const GmmComponent& c : components) total += c.weight;
    return total > 0.0f;
}

float DirectionalGmm::pdfSquare(const Vec2& s) const {
    // Eq. 1: four components' terms at a time (empty ones have scale 0), the
    // two halves added lane by lane and the four sums pairwise, an order that
    // does not depend on the compiler.
    static_assert(kGmmComponents % 4 == 0, "components are evaluated four at a time");
    const Float4 zero = {};
    const Float4 x = zero + s.x, y = zero + s.y;
    Float4 sum = zero;
    for (std::size_t first = 0; first < kGmmComponents; first += 4) {
        const Float4 dx = x - loadLanes(lanes.meanX, first), dy = y - loadLanes(lanes.meanY, first);
        const Float4 exponent2 = loadLanes(lanes.quadXX, first) * dx * dx + loadLanes(lanes.quadXY, first) * dx * dy +
                                 loadLanes(lanes.quadYY, first) * dy * dy;
        sum += loadLanes(lanes.scale, first) * exp2NonPositive(exponent2);
    }
    return (sum[0] + sum[2]) + (sum[1] + sum[3]);
}

float DirectionalGmm::pdfLocal(const Vec3& local) const {
    const std::optional<Vec2> s = hemisphereToSquare(local);
    if (!s) return 0.0f;
    return pdfSquare(*s) * (1.0f / kSquareToHemisphereJacobian);
}

Vec2 DirectionalGmm::samplePlane(float uComponent, const Vec2& uGauss) const {
    int below = 0;
    for (std::size_t j = 0; j < kGmmComponents; ++j) below += lanes.cdf[j] <= uComponent ? 1 : 0;
    const std::size_t j = static_cast<std::size_t>(std::min(below, kGmmComponents - 1));
    // Box-Muller; 1 - u for u in [0, 1) is at least 2^-24, and the bound keeps
    // the logarithm's argument a normal float for any u.
    const float radius = std::sqrt(-2.0f * logPositive(std::max(1.0f - uGauss.x, 0x1p-24f)));
    const SinCos angle = sinCosOfTurn(uGauss.y);
    const float z0 = radius * angle.cos, z1 = radius * angle.sin;
    return {lanes.meanX[j] + lanes.cholXX[j] * z0, lanes.meanY[j] + lanes.cholYX[j] * z0 + lanes.cholYY[j] * z1};
}
std::optional<Vec3> DirectionalGmm::sampleLocal(float uComponent, const Vec2& uGauss) const {
    const Vec2 s = samplePlane(uComponent, uGauss);
    if (!(s.x >= 0.0f && s.x <= 1.0f && s.y >= 0.0f && s.y <= 1.0f)) return std::nullopt;
    return squareToHemisphere(s);
}

}  // namespace fg
