// Homogeneous participating media and the Henyey-Greenstein phase function.
// Phase-function convention: wo points back towards the previous vertex, wi
// towards the next one, so forward scattering (g > 0) favours wi = -wo.
#pragma once

#include "engine/core/math.h"

#include <optional>

namespace fg {

struct PhaseSample {
    Vec3 wi{0.0f};
    float pdf = 0.0f;  // equals eval(): sampling is exact, so the weight is 1
};

class HenyeyGreenstein {
public:
    explicit HenyeyGreenstein(float g = 0.0f) : g_(g) {}
    float g() const { return g_; }
    float eval(const Vec3& wo, const Vec3& wi) const;
    PhaseSample sample(const Vec3& wo, const Vec2& u) const;

private:
    float g_;
};

// Result of free-flight sampling along a ray segment [0, tMax].
struct DistanceSample {
    float t = 0.0f;
    bool scattered = false;  // true: a real scattering event at t < tMax
    // Throughput factor: sigma_s * Tr(t) / pdf(t) on scattering, Tr(tMax) / P(t >= tMax) otherwise.
    Rgb weight{1.0f};
};

class HomogeneousMedium {
public:
    HomogeneousMedium() = default;
    HomogeneousMedium(const Rgb& sigmaA, const Rgb& sigmaS, float g) : sigmaA_(sigmaA), sigmaS_(sigmaS), phase_(g) {}

    const Rgb& sigmaA() const { return sigmaA_; }
    const Rgb& sigmaS() const { return sigmaS_; }
    Rgb sigmaT() const { return sigmaA_ + sigmaS_; }
    const HenyeyGreenstein& phase() const { return phase_; }

    Rgb transmittance(float distance) const;
    // Chromatic free-flight sampling: a channel is chosen with probability proportional
    // to `throughput` (uniform if black), the distance from its exponential, and the
    // weight uses the one-sample MIS density over all channels (spectral MIS).
    DistanceSample sampleDistance(float tMax, float uChannel, float u, const Rgb& throughput) const;

private:
    Rgb sigmaA_{0.0f};
    Rgb sigmaS_{0.0f};
    HenyeyGreenstein phase_;
};

}  // namespace fg
