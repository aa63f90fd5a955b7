// Bandwidth selection for photon ray splatting (Herzog et al. 2007, §6,
// Eq. 8), separated from its pass so tests can apply it to hand-made paths.
//
// Eq. 8 as transcribed is garbled ("C / ᴹ√M", "⁵√10⁵", "p̄⁵"); what the text
// around it states fixes it: the bandwidth falls as the sixth root of the
// photon count M (Silverman's MISE-optimal rate), the square root turns an
// area density into a radius, and S is the sensitivity exponent. So
//   h(x_0) = 0,   h(x_i) = C M^(-1/6) w p~(x_i | x_{i-1})^(-S/2),
//   w = m_0 mu_C / <r>,   r = p~^(-S/2),   m_0 = 10^(5/6),
// which makes the pilot's mean unclamped h exactly C mu_C at M = 10^5 (m_0
// calibrates for 10^5 photons). mu_C = a <sqrt(D)>, a = 0.2: the text's
// "<D(x, y)>" is a length ("average path segment lengths"), and D of Eq. 7 is
// a squared one, so the mean clamped segment length. The paper clamps h to
// bounds "derived from mu_C and R" without giving them; here h is held to
// [R h̄, h̄ / R] around h̄ = C mu_C (M / 10^5)^(-1/6), the typical bandwidth at
// this M, so doubling M scales every h, clamped or not, by 2^(-1/6).
#pragma once

#include "engine/buffers/photon_ray_buffers.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>

namespace fg {

struct BandwidthSettings {
    double smoothness = 1.0;   // C
    double sensitivity = 0.4;  // S
    double maxScaling = 0.2;   // R, in (0, 1]
    std::uint64_t pilotPaths = 16384;
};

inline constexpr double kBandwidthSceneScaleFactor = 0.2;  // a of mu_C = a <sqrt(D)>

// Eq. 7's density of a ray as the model reads it. The densities are stored as
// floats, and on deep paths in scenes measured in millimetres they fall below
// FLT_MIN (each bounce multiplies by about p_s / D ~ 1e-6): a subnormal then
// reads as itself or as zero depending on the thread's floating-point mode
// (denormals-are-zero). Passes run with DAZ set (jobs/ sets it for every
// chunk and task), but the model is also fitted by callers outside jobs/, and
// before jobs/ fixed the mode w came out 0.00111 or 0.000286 for the same
// rays depending on what other tests had left in the thread. Every density
// below FLT_MIN counts as zero, in either mode, as under DAZ.
inline double readDensity(float density) {
    return density >= std::numeric_limits<float>::min() ? static_cast<double>(density) : 0.0;
}
inline constexpr double kBandwidthCalibrationCount = 1e5;  // m_0 = (10^5)^(1/6) normalises h at M = 10^5

struct BandwidthModel {
    BandwidthSettings settings;
    double normalisation = 0.0;  // w
    double sceneScale = 0.0;     // mu_C
    std::array<std::uint64_t, PhotonRayClass::Count> countPerClass{};

    // h(x) for a vertex reached with bounded density p~ by a ray of class c (Eq. 8).
    double unclamped(double density, std::uint8_t rayClass) const {
        if (!(density > 0.0)) return 0.0;
        const double m = static_cast<double>(std::max<std::uint64_t>(1, countPerClass[rayClass]));
        return settings.smoothness * std::pow(m, -1.0 / 6.0) * normalisation *
               std::pow(density, -0.5 * settings.sensitivity);
    }
    // h̄: the clamping range's centre, C mu_C (M / 10^5)^(-1/6).
    double typical(std::uint8_t rayClass) const {
        const double m = static_cast<double>(std::max<std::uint64_t>(1, countPerClass[rayClass]));
        return settings.smoothness * sceneScale * std::pow(m / kBandwidthCalibrationCount, -1.0 / 6.0);
    }
    double clamped(double density, std::uint8_t rayClass) const {
        const double centre = typical(rayClass);
        return std::clamp(unclamped(density, rayClass), settings.maxScaling * centre, centre / settings.maxScaling);
    }
    // h at a ray's origin: 0 on the light (Eq. 8, i = 0).
    double atOrigin(double originDensity, std::uint16_t vertex, std::uint8_t rayClass) const {
        return vertex == 0 ? 0.0 : clamped(originDensity, rayClass);
    }
};

// Counts M per class and estimates w and mu_C from the rays of the first
// settings.pilotPaths paths (all rays if there are fewer paths).
inline BandwidthModel fitBandwidthModel(const PhotonRayBuffer& rays, float clampDistance,
                                        const BandwidthSettings& settings) {
    BandwidthModel model;
    model.settings = settings;
    const auto rayClass = rays.column<RayClassColumn>();
    const auto path = rays.column<RayPath>();
    const auto density = rays.column<RayDensity>();
    const auto length = rays.column<RayLength>();
    double sumR = 0.0, sumLength = 0.0;
    std::uint64_t pilotRays = 0, densityRays = 0;
    for (std::size_t i = 0; i < rays.size(); ++i) {
        ++model.countPerClass[rayClass[i]];
        if (path[i] >= settings.pilotPaths) continue;
        ++pilotRays;
        sumLength += std::max(static_cast<double>(clampDistance), static_cast<double>(length[i]));
        if (const double p = readDensity(density[i]); p > 0.0) {
            sumR += std::pow(p, -0.5 * settings.sensitivity);
            ++densityRays;
        }
    }
    if (pilotRays == 0 || densityRays == 0) return model;
    model.sceneScale = kBandwidthSceneScaleFactor * sumLength / static_cast<double>(pilotRays);
    const double meanR = sumR / static_cast<double>(densityRays);
    model.normalisation = std::pow(kBandwidthCalibrationCount, 1.0 / 6.0) * model.sceneScale / meanR;
    return model;
}

struct RayBandwidth {
    float h0 = 0.0f;
    float dh = 0.0f;
};

// h_0 and dh of one ray (§6): h_0 = min(h(x_i), h(x_{i+1})),
// dh = max(0, h(x_{i+1}) - h(x_i)) / |x_{i+1} - x_i|.
inline RayBandwidth rayBandwidth(const BandwidthModel& model, float originDensity, float density, std::uint16_t vertex,
                                 std::uint8_t rayClass, float length) {
    const double start = model.atOrigin(readDensity(originDensity), vertex, rayClass);
    const double end = model.clamped(readDensity(density), rayClass);
    return {static_cast<float>(std::min(start, end)),
            length > 0.0f ? static_cast<float>(std::max(0.0, end - start) / length) : 0.0f};
}

// Fills h_0 and dh of every ray in place.
inline void assignBandwidths(PhotonRayBuffer& rays, const BandwidthModel& model) {
    const auto rayClass = rays.column<RayClassColumn>();
    const auto vertex = rays.column<RayVertex>();
    const auto density = rays.column<RayDensity>();
    const auto originDensity = rays.column<RayOriginDensity>();
    const auto length = rays.column<RayLength>();
    auto h0 = rays.column<RayH0>();
    auto dh = rays.column<RayDh>();
    for (std::size_t i = 0; i < rays.size(); ++i) {
        const RayBandwidth b = rayBandwidth(model, originDensity[i], density[i], vertex[i], rayClass[i], length[i]);
        h0[i] = b.h0;
        dh[i] = b.dh;
    }
}

}  // namespace fg
