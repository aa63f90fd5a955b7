// Spectrum to RGB conversion: normalisation, hue of narrow bands, exactness of
// the integration, and agreement with the RGB values Mitsuba derived from the
// Cornell box's measured reflectance spectra.
#include "engine/scene/spectrum.h"

#include <gtest/gtest.h>

#include <sstream>
#include <string>
#include <vector>

namespace fg {
namespace {

// "400:0.1, 404:0.2, ..." as in Mitsuba scenes.
std::vector<SpectrumSample> parsePairs(const std::string& text) {
    std::vector<SpectrumSample> samples;
    std::stringstream stream(text);
    for (std::string item; std::getline(stream, item, ',');) {
        const auto colon = item.find(':');
        samples.push_back({std::stof(item.substr(0, colon)), std::stof(item.substr(colon + 1))});
    }
    return samples;
}

// The measured reflectances of Mitsuba's cbox (fragments/bsdfs-spectral.xml) and
// the RGB values Mitsuba lists for them in fragments/bsdfs-rgb.xml.
const char* kCboxRed =
    "400:0.04, 404:0.046, 408:0.048, 412:0.053, 416:0.049, 420:0.05, 424:0.053, 428:0.055, 432:0.057, "
    "436:0.056, 440:0.059, 444:0.057, 448:0.061, 452:0.061, 456:0.06, 460:0.062, 464:0.062, 468:0.062, "
    "472:0.061, 476:0.062, 480:0.06, 484:0.059, 488:0.057, 492:0.058, 496:0.058, 500:0.058, 504:0.056, "
    "508:0.055, 512:0.056, 516:0.059, 520:0.057, 524:0.055, 528:0.059, 532:0.059, 536:0.058, 540:0.059, "
    "544:0.061, 548:0.061, 552:0.063, 556:0.063, 560:0.067, 564:0.068, 568:0.072, 572:0.08, 576:0.09, "
    "580:0.099, 584:0.124, 588:0.154, 592:0.192, 596:0.255, 600:0.287, 604:0.349, 608:0.402, 612:0.443, "
    "616:0.487, 620:0.513, 624:0.558, 628:0.584, 632:0.62, 636:0.606, 640:0.609, 644:0.651, 648:0.612, "
    "652:0.61, 656:0.65, 660:0.638, 664:0.627, 668:0.62, 672:0.63, 676:0.628, 680:0.642, 684:0.639, "
    "688:0.657, 692:0.639, 696:0.635, 700:0.642";
const Rgb kCboxRedMitsuba(0.570068f, 0.0430135f, 0.0443706f);

const char* kCboxGreen =
    "400:0.092, 404:0.096, 408:0.098, 412:0.097, 416:0.098, 420:0.095, 424:0.095, 428:0.097, 432:0.095, "
    "436:0.094, 440:0.097, 444:0.098, 448:0.096, 452:0.101, 456:0.103, 460:0.104, 464:0.107, 468:0.109, "
    "472:0.112, 476:0.115, 480:0.125, 484:0.14, 488:0.16, 492:0.187, 496:0.229, 500:0.285, 504:0.343, "
    "508:0.39, 512:0.435, 516:0.464, 520:0.472, 524:0.476, 528:0.481, 532:0.462, 536:0.447, 540:0.441, "
    "544:0.426, 548:0.406, 552:0.373, 556:0.347, 560:0.337, 564:0.314, 568:0.285, 572:0.277, 576:0.266, "
    "580:0.25, 584:0.23, 588:0.207, 592:0.186, 596:0.171, 600:0.16, 604:0.148, 608:0.141, 612:0.136, "
    "616:0.13, 620:0.126, 624:0.123, 628:0.121, 632:0.122, 636:0.119, 640:0.114, 644:0.115, 648:0.117, "
    "652:0.117, 656:0.118, 660:0.12, 664:0.122, 668:0.128, 672:0.132, 676:0.139, 680:0.144, 684:0.146, "
    "688:0.15, 692:0.152, 696:0.157, 700:0.159";
const Rgb kCboxGreenMitsuba(0.105421f, 0.37798f, 0.076425f);

const char* kCboxWhite =
    "400:0.343, 404:0.445, 408:0.551, 412:0.624, 416:0.665, 420:0.687, 424:0.708, 428:0.723, 432:0.715, "
    "436:0.71, 440:0.745, 444:0.758, 448:0.739, 452:0.767, 456:0.777, 460:0.765, 464:0.751, 468:0.745, "
    "472:0.748, 476:0.729, 480:0.745, 484:0.757, 488:0.753, 492:0.75, 496:0.746, 500:0.747, 504:0.735, "
    "508:0.732, 512:0.739, 516:0.734, 520:0.725, 524:0.721, 528:0.733, 532:0.725, 536:0.732, 540:0.743, "
    "544:0.744, 548:0.748, 552:0.728, 556:0.716, 560:0.733, 564:0.726, 568:0.713, 572:0.74, 576:0.754, "
    "580:0.764, 584:0.752, 588:0.736, 592:0.734, 596:0.741, 600:0.74, 604:0.732, 608:0.745, 612:0.755, "
    "616:0.751, 620:0.744, 624:0.731, 628:0.733, 632:0.744, 636:0.731, 640:0.712, 644:0.708, 648:0.729, "
    "652:0.73, 656:0.727, 660:0.707, 664:0.703, 668:0.729, 672:0.75, 676:0.76, 680:0.751, 684:0.739, "
    "688:0.724, 692:0.73, 696:0.74, 700:0.737";
const Rgb kCboxWhiteMitsuba(0.885809f, 0.698859f, 0.666422f);

TEST(Spectrum, ColourMatchingTableIsTheCie1931Observer) {
    // Spot values of the standard table and its peak normalisation.
    EXPECT_FLOAT_EQ(cie1931Xyz(555.0f).y, 1.0f);
    EXPECT_NEAR(cie1931Xyz(600.0f).x, 1.0622f, 1e-6f);
    EXPECT_NEAR(cie1931Xyz(445.0f).z, 1.7826f, 1e-6f);
    EXPECT_NEAR(cie1931Xyz(555.5f).y, 0.5f * (1.0f + 0.9998567f), 1e-6f);
    EXPECT_EQ(cie1931Xyz(379.0f), Vec3(0.0f));
    EXPECT_EQ(cie1931Xyz(781.0f), Vec3(0.0f));
    // The three functions have (almost) equal integrals: equal-energy white sits at x = y = 1/3.
    const SpectrumSample flat[] = {{380.0f, 1.0f}, {780.0f, 1.0f}};
    const Vec3 xyz = spectrumToXyz(flat);
    EXPECT_NEAR(xyz.y, 1.0f, 1e-6f);
    EXPECT_NEAR(xyz.x / (xyz.x + xyz.y + xyz.z), 1.0f / 3.0f, 2e-4f);
    EXPECT_NEAR(xyz.z / (xyz.x + xyz.y + xyz.z), 1.0f / 3.0f, 2e-4f);
}

TEST(Spectrum, SrgbMatrixMapsD65ToWhite) {
    const Rgb white = xyzToLinearSrgb(Vec3(0.95047f, 1.0f, 1.08883f));
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(white[c], 1.0f, 1e-3f) << c;
    // The unadapted equal-energy white is pink in sRGB, as Mitsuba's RGB values show.
    const Rgb e = equalEnergyWhiteSrgb();
    EXPECT_NEAR(e.x, 1.2049f, 2e-3f);
    EXPECT_NEAR(e.y, 0.9484f, 2e-3f);
    EXPECT_NEAR(e.z, 0.9087f, 2e-3f);
}

TEST(Spectrum, ConstantSpectrumIsGrey) {
    for (const float level : {1.0f, 0.25f}) {
        const SpectrumSample flat[] = {{380.0f, level}, {500.0f, level}, {780.0f, level}};
        const Rgb rgb = spectrumToRgb(flat);
        for (int c = 0; c < 3; ++c) EXPECT_NEAR(rgb[c], level, 1e-5f) << "channel " << c << " level " << level;
        const SpectrumSample single[] = {{0.0f, level}};
        const Rgb grey = spectrumToRgb(single);
        for (int c = 0; c < 3; ++c) EXPECT_NEAR(grey[c], level, 1e-5f);
    }
    // Wider than the table: the same.
    const SpectrumSample wide[] = {{300.0f, 1.0f}, {900.0f, 1.0f}};
    const Rgb rgb = spectrumToRgb(wide);
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(rgb[c], 1.0f, 1e-5f);
}

TEST(Spectrum, NarrowBandsHaveTheirHue) {
    auto band = [](float centre) {
        const std::vector<SpectrumSample> s = {{centre - 5.0f, 0.0f}, {centre, 1.0f}, {centre + 5.0f, 0.0f}};
        return spectrumToRgb(s);
    };
    const Rgb red = band(610.0f);
    EXPECT_GT(red.x, 0.0f);
    EXPECT_GT(red.x, 4.0f * std::abs(red.y)) << red.x << " " << red.y << " " << red.z;
    EXPECT_GT(red.x, 4.0f * std::abs(red.z));
    const Rgb green = band(530.0f);
    EXPECT_GT(green.y, green.x);
    EXPECT_GT(green.y, green.z);
    const Rgb blue = band(450.0f);
    EXPECT_GT(blue.z, blue.x);
    EXPECT_GT(blue.z, blue.y);
}

TEST(Spectrum, IntegrationIsExactForSpikesBetweenTableEntries) {
    // A triangle of width 0.6 nm and height 1 between 610 and 611 nm: area 0.3,
    // and the colour matching functions are linear under it.
    const SpectrumSample spike[] = {{610.2f, 0.0f}, {610.5f, 1.0f}, {610.8f, 0.0f}};
    const Vec3 xyz = spectrumToXyz(spike);
    const SpectrumSample flat[] = {{380.0f, 1.0f}, {780.0f, 1.0f}};
    const Vec3 cmf = cie1931Xyz(610.5f);
    // Y of the flat spectrum is 1, so its unnormalised Y is the y-bar integral.
    const float yIntegral = 1.0f / spectrumToXyz(flat).y;  // = 1 by construction; keeps the expression honest
    ASSERT_NEAR(yIntegral, 1.0f, 1e-6f);
    const float yBarIntegral = 106.8564f;
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(xyz[c], 0.3f * cmf[c] / yBarIntegral, 1e-3f * cmf[c]) << c;
    // Linearity in the values.
    const SpectrumSample doubled[] = {{610.2f, 0.0f}, {610.5f, 2.0f}, {610.8f, 0.0f}};
    EXPECT_NEAR(spectrumToXyz(doubled).x, 2.0f * xyz.x, 1e-7f);
}

// Mitsuba's cbox-rgb values are the same spectra converted without the white
// adaptation; undo it and compare. The measured difference is below 0.17 % of
// the largest channel for all three materials (largest: green's red channel,
// 0.1048 against 0.1054; Mitsuba integrates with a 1000-step Riemann sum, we
// integrate exactly), so 0.5 % of the largest channel is the tolerance.
TEST(Spectrum, CornellBoxReflectancesMatchMitsubasRgb) {
    const struct {
        const char* name;
        const char* spectrum;
        Rgb mitsuba;
    } cases[] = {{"red", kCboxRed, kCboxRedMitsuba}, {"green", kCboxGreen, kCboxGreenMitsuba},
                 {"white", kCboxWhite, kCboxWhiteMitsuba}};
    for (const auto& c : cases) {
        const Rgb ours = spectrumToRgb(parsePairs(c.spectrum));
        const Rgb unadapted = ours * equalEnergyWhiteSrgb();
        const float scale = maxComponent(c.mitsuba);
        for (int ch = 0; ch < 3; ++ch) {
            EXPECT_NEAR(unadapted[ch], c.mitsuba[ch], 0.005f * scale) << c.name << " channel " << ch;
        }
        // Reflectances stay reflectances after the adaptation.
        EXPECT_LE(maxComponent(ours), 1.0f) << c.name;
    }
    const Rgb red = spectrumToRgb(parsePairs(kCboxRed));
    EXPECT_GT(red.x, 5.0f * red.y);
}

}  // namespace
}  // namespace fg

namespace fg {
namespace {

// A constant emission spectrum v in Mitsuba 3's RGB mode is v * sRGB(XYZ = 1):
// the rows of the IEC 61966-2-1 matrix summed, by hand
// (3.2406 - 1.5372 - 0.4986, -0.9689 + 1.8758 + 0.0415, 0.0557 - 0.2040 + 1.0570).
TEST(Spectrum, UniformEmissionIsNotWhiteBalanced) {
    const Rgb expected = 2.5f * Rgb(1.2048f, 0.9484f, 0.9087f);
    const Rgb rgb = uniformEmissionToRgb(2.5f);
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(rgb[c], expected[c], 1e-5f) << c;
}

// An emission spectrum goes to sRGB without the white balance: a flat list
// converts as its single value does (the CIE 1931 functions have equal
// integrals, so XYZ = (1, 1, 1) per unit), and a list is the white-balanced
// conversion times the equal-energy white.
TEST(Spectrum, EmissionSpectrumIsTheUnbalancedConversion) {
    const SpectrumSample flat[] = {{380.0f, 2.0f}, {780.0f, 2.0f}};
    const Rgb fromList = emissionSpectrumToRgb(flat);
    const Rgb fromValue = uniformEmissionToRgb(2.0f);
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(fromList[c], fromValue[c], 2e-3f * fromValue[c]) << c;
    const SpectrumSample luminaire[] = {{400.0f, 0.0f}, {500.0f, 8.0f}, {600.0f, 15.6f}, {700.0f, 18.4f}};
    const Rgb ours = emissionSpectrumToRgb(luminaire);
    const Rgb balanced = spectrumToRgb(luminaire) * equalEnergyWhiteSrgb();
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(balanced[c], ours[c], 1e-4f * maxComponent(ours)) << c;
    // The luminaire is reddish: the balanced conversion (the reflectance one) scales it by
    // 1 / (1.205, 0.948, 0.909) = (0.83, 1.06, 1.10), the per-channel error seen against Mitsuba.
    const Rgb ratio = spectrumToRgb(luminaire) / ours;
    EXPECT_NEAR(ratio.x, 0.83f, 0.01f);
    EXPECT_NEAR(ratio.y, 1.055f, 0.01f);
    EXPECT_NEAR(ratio.z, 1.10f, 0.01f);
}

}  // namespace
}  // namespace fg
