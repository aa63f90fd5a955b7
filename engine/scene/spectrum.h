// Spectra to linear sRGB, for scene formats that give colours as spectra
// (Mitsuba's <spectrum value="400:0.5, 500:0.7, ...">). fluxgraph renders in
// RGB, so every spectrum is reduced to three numbers when the scene is loaded.
//
// A spectrum is piecewise linear through its samples and zero outside them (as
// Mitsuba treats such lists). It is integrated against the CIE 1931 2-degree
// colour matching functions (1 nm table, 380-780 nm) under illuminant E, the
// result is normalised by the integral of y-bar, and XYZ becomes linear sRGB
// through the standard matrix. sRGB's white is D65, not E, so the equal-energy
// spectrum 1 would land on (1.205, 0.948, 0.909); every channel is divided by
// that white so that a constant spectrum 1 maps to (1, 1, 1) (a von Kries
// adaptation from E to the working space's white). Reflectances so stay within
// [0, 1] for any spectrum within [0, 1], and a grey spectrum stays grey.
//
// Emission spectra are converted as Mitsuba 3's RGB variants convert them, so
// that an emitter renders as it does there: the tristimulus values go to
// linear sRGB without that division (a flat emission spectrum is the slightly
// purple (1.205, 0.948, 0.909) times its value, not white), and a single value
// v on an emitter is v times the sRGB of XYZ = (1, 1, 1).
#pragma once

#include "engine/core/math.h"

#include <span>

namespace fg {

// CIE 1931 2-degree standard observer, x-bar, y-bar, z-bar at 1 nm from
// kCieFirstNm to kCieLastNm (tabulated in engine/scene/cie1931.cpp).
inline constexpr int kCieFirstNm = 380;
inline constexpr int kCieLastNm = 780;
inline constexpr int kCieSampleCount = kCieLastNm - kCieFirstNm + 1;
extern const float kCie1931Xyz[kCieSampleCount][3];

// Colour matching functions at a wavelength (linear between table entries, zero outside).
Vec3 cie1931Xyz(float wavelengthNm);

// XYZ (D65-relative, as sRGB defines it) to linear sRGB, IEC 61966-2-1.
Rgb xyzToLinearSrgb(const Vec3& xyz);

struct SpectrumSample {
    float wavelengthNm = 0.0f;
    float value = 0.0f;
};

// Tristimulus values of a spectrum under illuminant E, Y normalised so that a
// constant spectrum 1 over the whole table has Y = 1. Wavelengths must be
// strictly increasing (the caller checks); a single sample is a constant spectrum.
// The integral is exact for the piecewise-linear spectrum against the
// piecewise-linear colour matching functions.
Vec3 spectrumToXyz(std::span<const SpectrumSample> samples);

// Linear sRGB of XYZ(1, 1, 1) normalised as above: the RGB of the equal-energy spectrum.
Rgb equalEnergyWhiteSrgb();

// Linear sRGB, white-balanced so that a constant spectrum 1 maps to (1, 1, 1).
// Out-of-gamut results may have negative components; callers clamp as their use requires.
Rgb spectrumToRgb(std::span<const SpectrumSample> samples);

// Linear sRGB of an emission spectrum, not white-balanced (as Mitsuba 3's RGB
// mode); may be negative out of gamut.
Rgb emissionSpectrumToRgb(std::span<const SpectrumSample> samples);
// Linear sRGB of the constant emission spectrum `value`: value * sRGB(XYZ = 1, 1, 1).
Rgb uniformEmissionToRgb(float value);

}  // namespace fg
