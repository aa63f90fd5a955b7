// Spectrum to colour conversion (see spectrum.h): tristimulus integration
// against the CIE 1931 2-degree observer (CIE 15:2004, Section 7), XYZ to
// linear sRGB with the matrix of IEC 61966-2-1:1999, and a von Kries scaling
// in sRGB from the equal-energy white to (1, 1, 1).
//
// Both the spectrum and the tabulated colour matching functions are piecewise
// linear, so on every interval between consecutive breakpoints of either their
// product is a quadratic, which Simpson's rule integrates exactly. A spectrum
// given as a narrow spike between table entries is therefore not lost.
#include "engine/scene/spectrum.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <vector>

namespace fg {

namespace {

using Xyzd = std::array<double, 3>;

Xyzd cmfAt(double wavelength) {
    if (!(wavelength >= kCieFirstNm && wavelength <= kCieLastNm)) return {0.0, 0.0, 0.0};
    const double offset = wavelength - kCieFirstNm;
    const int i = std::min(static_cast<int>(offset), kCieSampleCount - 2);
    const double t = offset - i;
    Xyzd result;
    for (int c = 0; c < 3; ++c) result[c] = (1.0 - t) * kCie1931Xyz[i][c] + t * kCie1931Xyz[i + 1][c];
    return result;
}

// Integrals of x-bar, y-bar, z-bar (trapezoid rule is exact for the linear interpolant).
const Xyzd& cmfIntegrals() {
    static const Xyzd integrals = [] {
        Xyzd sum{0.0, 0.0, 0.0};
        for (int i = 0; i + 1 < kCieSampleCount; ++i) {
            for (int c = 0; c < 3; ++c) sum[c] += 0.5 * (kCie1931Xyz[i][c] + kCie1931Xyz[i + 1][c]);
        }
        return sum;
    }();
    return integrals;
}

// The spectrum's linear interpolant; zero outside its first and last sample.
double spectrumAt(std::span<const SpectrumSample> samples, double wavelength) {
    if (wavelength < samples.front().wavelengthNm || wavelength > samples.back().wavelengthNm) return 0.0;
    const auto upper = std::upper_bound(samples.begin(), samples.end(), wavelength,
                                        [](double w, const SpectrumSample& s) { return w < s.wavelengthNm; });
    if (upper == samples.end()) return samples.back().value;
    const SpectrumSample& b = *upper;
    const SpectrumSample& a = *(upper - 1);
    const double t = (wavelength - a.wavelengthNm) / (static_cast<double>(b.wavelengthNm) - a.wavelengthNm);
    return (1.0 - t) * a.value + t * b.value;
}

}  // namespace

Vec3 cie1931Xyz(float wavelengthNm) {
    const Xyzd v = cmfAt(wavelengthNm);
    return {static_cast<float>(v[0]), static_cast<float>(v[1]), static_cast<float>(v[2])};
}

Rgb xyzToLinearSrgb(const Vec3& xyz) {
    return {3.2406f * xyz.x - 1.5372f * xyz.y - 0.4986f * xyz.z,
            -0.9689f * xyz.x + 1.8758f * xyz.y + 0.0415f * xyz.z,
            0.0557f * xyz.x - 0.2040f * xyz.y + 1.0570f * xyz.z};
}

Vec3 spectrumToXyz(std::span<const SpectrumSample> samples) {
    const Xyzd& integrals = cmfIntegrals();
    const double yNorm = integrals[1];
    if (samples.empty()) return Vec3(0.0f);
    if (samples.size() == 1) {
        const double v = samples.front().value;
        return {static_cast<float>(v * integrals[0] / yNorm), static_cast<float>(v), static_cast<float>(v * integrals[2] / yNorm)};
    }
    const double lo = std::max<double>(kCieFirstNm, samples.front().wavelengthNm);
    const double hi = std::min<double>(kCieLastNm, samples.back().wavelengthNm);
    if (!(lo < hi)) return Vec3(0.0f);

    std::vector<double> breaks = {lo, hi};
    for (int w = static_cast<int>(std::ceil(lo)); w < hi; ++w) breaks.push_back(w);
    for (const SpectrumSample& s : samples) {
        if (s.wavelengthNm > lo && s.wavelengthNm < hi) breaks.push_back(s.wavelengthNm);
    }
    std::sort(breaks.begin(), breaks.end());
    breaks.erase(std::unique(breaks.begin(), breaks.end()), breaks.end());

    Xyzd sum{0.0, 0.0, 0.0};
    for (std::size_t i = 0; i + 1 < breaks.size(); ++i) {
        const double a = breaks[i], b = breaks[i + 1], m = 0.5 * (a + b);
        const double sa = spectrumAt(samples, a), sm = spectrumAt(samples, m), sb = spectrumAt(samples, b);
        const Xyzd ca = cmfAt(a), cm = cmfAt(m), cb = cmfAt(b);
        for (int c = 0; c < 3; ++c) sum[c] += (b - a) / 6.0 * (sa * ca[c] + 4.0 * sm * cm[c] + sb * cb[c]);
    }
    return {static_cast<float>(sum[0] / yNorm), static_cast<float>(sum[1] / yNorm), static_cast<float>(sum[2] / yNorm)};
}

Rgb equalEnergyWhiteSrgb() {
    const SpectrumSample one{0.0f, 1.0f};
    return xyzToLinearSrgb(spectrumToXyz(std::span<const SpectrumSample>(&one, 1)));
}

Rgb spectrumToRgb(std::span<const SpectrumSample> samples) {
    return xyzToLinearSrgb(spectrumToXyz(samples)) / equalEnergyWhiteSrgb();
}

Rgb emissionSpectrumToRgb(std::span<const SpectrumSample> samples) { return xyzToLinearSrgb(spectrumToXyz(samples)); }

Rgb uniformEmissionToRgb(float value) { return value * xyzToLinearSrgb(Vec3(1.0f)); }

}  // namespace fg
