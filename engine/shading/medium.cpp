// Homogeneous media: Henyey-Greenstein phase function (Henyey & Greenstein 1941)
// sampled by exact inversion of its cumulative distribution in cos(theta), and
// chromatic free-flight sampling with spectral MIS. The distance is drawn from
// the exponential of one colour channel, chosen in proportion to the path
// throughput (the history-aware choice of Kutz et al. 2017, "Spectral and
// decomposition tracking for rendering heterogeneous volumes"); the weight
// divides by the density of the whole mixture over channels, i.e. Veach's
// one-sample model with the balance heuristic (Veach 1997, Sec. 9.2.4):
//   p(t)          = sum_c P(c) sigma_t,c exp(-sigma_t,c t)      for t < tMax,
//   P(t >= tMax)  = sum_c P(c) exp(-sigma_t,c tMax),
// so the estimator stays unbiased in every channel, including channels with
// sigma_t = 0 (they only contribute through the "passed" event) and an infinite
// tMax (where only such channels can pass).
#include "engine/shading/medium.h"

#include <cmath>
#include <limits>

namespace fg {

float HenyeyGreenstein::eval(const Vec3& wo, const Vec3& wi) const {
    const float cosTheta = glm::dot(-wo, wi);
    const float g2 = g_ * g_;
    const float denom = std::max(1.0f + g2 - 2.0f * g_ * cosTheta, 1e-12f);
    return kInv4Pi * (1.0f - g2) / (denom * std::sqrt(denom));
}

PhaseSample HenyeyGreenstein::sample(const Vec3& wo, const Vec2& u) const {
    // Inverse CDF in double: the closed form cancels badly as g approaches 0.
    const double g = g_;
    double cosTheta;
    if (std::abs(g) < 1e-6) {
        cosTheta = 1.0 - 2.0 * u.x;
    } else {
        const double s = (1.0 - g * g) / (1.0 - g + 2.0 * g * u.x);
        cosTheta = (1.0 + g * g - s * s) / (2.0 * g);
    }
    cosTheta = std::clamp(cosTheta, -1.0, 1.0);
    const float cosT = static_cast<float>(cosTheta);
    const float sinT = static_cast<float>(std::sqrt(std::max(0.0, 1.0 - cosTheta * cosTheta)));
    const float phi = 2.0f * kPi * u.y;
    PhaseSample s;
    s.wi = glm::normalize(Frame(-wo).toWorld(Vec3(sinT * std::cos(phi), sinT * std::sin(phi), cosT)));
    // For g = 0 eval() is 1/(4 pi) exactly, whatever the directions.
    s.pdf = g_ == 0.0f ? kInv4Pi : eval(wo, s.wi);
    return s;
}

namespace {

// exp(-sigma d) that stays 1 for sigma = 0 even when d is infinite.
float channelTransmittance(float sigmaT, float distance) {
    if (sigmaT <= 0.0f) return 1.0f;
    return std::exp(-sigmaT * distance);
}

}  // namespace

Rgb HomogeneousMedium::transmittance(float distance) const {
    const float d = std::max(distance, 0.0f);
    const Rgb sigmaT = this->sigmaT();
    // Grey media (the common case) need one exponential, not three: the same value, bit for bit.
    if (sigmaT.x == sigmaT.y && sigmaT.y == sigmaT.z) return Rgb(channelTransmittance(sigmaT.x, d));
    return {channelTransmittance(sigmaT.x, d), channelTransmittance(sigmaT.y, d), channelTransmittance(sigmaT.z, d)};
}

DistanceSample HomogeneousMedium::sampleDistance(float tMax, float uChannel, float u, const Rgb& throughput) const {
    Rgb probability(std::max(throughput.x, 0.0f), std::max(throughput.y, 0.0f), std::max(throughput.z, 0.0f));
    const float sum = probability.x + probability.y + probability.z;
    if (sum > 0.0f && std::isfinite(sum)) {
        probability /= sum;
    } else {
        probability = Rgb(1.0f / 3.0f);
    }

    int channel = 2;
    if (uChannel < probability.x) {
        channel = 0;
    } else if (uChannel < probability.x + probability.y || probability.z <= 0.0f) {
        channel = probability.y > 0.0f ? 1 : 0;
    }

    const Rgb sigmaT = this->sigmaT();
    const float sigma = sigmaT[channel];
    const float t = sigma > 0.0f ? static_cast<float>(-std::log1p(-static_cast<double>(u)) / sigma)
                                 : std::numeric_limits<float>::infinity();

    DistanceSample result;
    if (t < tMax) {
        const Rgb tr = transmittance(t);
        const float pdf = glm::dot(probability, sigmaT * tr);
        result.t = t;
        result.scattered = true;
        result.weight = pdf > 0.0f ? sigmaS_ * tr / pdf : Rgb(0.0f);
    } else {
        const Rgb tr = transmittance(tMax);
        const float passProbability = glm::dot(probability, tr);
        result.t = tMax;
        result.scattered = false;
        result.weight = passProbability > 0.0f ? tr / passProbability : Rgb(0.0f);
    }
    return result;
}

float FreeFlightSegment::pass(const Rgb& sigmaT, float length) {
    const Rgb p = HomogeneousMedium(Rgb(0.0f), sigmaT, 0.0f).transmittance(length);
    return (p.x + p.y + p.z) / 3.0f;
}

float FreeFlightSegment::scatter(const Rgb& sigmaT, float length) {
    const Rgb p = sigmaT * HomogeneousMedium(Rgb(0.0f), sigmaT, 0.0f).transmittance(length);
    return (p.x + p.y + p.z) / 3.0f;
}

void FreeFlightSegment::add(const HomogeneousMedium& medium, float length) {
    if (pieces_ == 0) {
        firstSigmaT_ = medium.sigmaT();
        firstLength_ = length;
    } else {
        if (pieces_ >= 2) innerPass_ *= pass(lastSigmaT_, lastLength_);
        lastSigmaT_ = medium.sigmaT();
        lastLength_ = length;
    }
    ++pieces_;
}

void FreeFlightSegment::extendEnd(float length) {
    if (pieces_ == 1) firstLength_ += length;
    else if (pieces_ > 1) lastLength_ += length;
}

float FreeFlightSegment::towardEnd(bool endInMedium) const {
    if (pieces_ == 0) return 1.0f;
    if (pieces_ == 1) return endInMedium ? scatter(firstSigmaT_, firstLength_) : pass(firstSigmaT_, firstLength_);
    return pass(firstSigmaT_, firstLength_) * innerPass_ *
           (endInMedium ? scatter(lastSigmaT_, lastLength_) : pass(lastSigmaT_, lastLength_));
}

float FreeFlightSegment::towardStart(bool startInMedium) const {
    if (pieces_ == 0) return 1.0f;
    if (pieces_ == 1) return startInMedium ? scatter(firstSigmaT_, firstLength_) : pass(firstSigmaT_, firstLength_);
    return (startInMedium ? scatter(firstSigmaT_, firstLength_) : pass(firstSigmaT_, firstLength_)) * innerPass_ *
           pass(lastSigmaT_, lastLength_);
}

}  // namespace fg
