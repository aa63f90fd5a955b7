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

// Densities of free-flight sampling along one straight segment that may cross
// several homogeneous media (null boundaries between them), seen from either
// end: what multiple importance sampling needs to compare strategies that
// sample the segment from opposite ends. Each medium the segment crosses is a
// piece; a path passes a piece with probability P = mean_c exp(-sigma_t,c l)
// and scatters at its far end with density mean_c sigma_t,c exp(-sigma_t,c l).
// The channels are weighted equally, where sampleDistance weights them by the
// throughput of the path being traced: a weight needs one density per vertex
// and direction, the same whichever subpath sampled the vertex, and the
// throughput of the subpath coming from the other end is not known there. For
// grey media (all sigma_t,c equal) both are the sampler's density exactly.
class FreeFlightSegment {
public:
    // Appends the next piece along the segment (vacuum needs none: it passes with probability 1).
    void add(const HomogeneousMedium& medium, float length);
    // Lengthens the last piece, e.g. to the end of a segment whose walk stopped short of it.
    void extendEnd(float length);
    // Density of sampling the end from the start: per unit length when the end
    // is a scattering event in a medium (endInMedium), the probability of
    // passing every piece otherwise; 1 for a segment that crosses no medium.
    float towardEnd(bool endInMedium) const;
    // The same for sampling the start from the end.
    float towardStart(bool startInMedium) const;
    bool empty() const { return pieces_ == 0; }

private:
    static float pass(const Rgb& sigmaT, float length);
    static float scatter(const Rgb& sigmaT, float length);
    int pieces_ = 0;
    Rgb firstSigmaT_{0.0f}, lastSigmaT_{0.0f};
    float firstLength_ = 0.0f, lastLength_ = 0.0f;
    float innerPass_ = 1.0f;  // pieces between the first and the last
};

}  // namespace fg
