// Mitsuba XML import of textures and material plugins: bitmap to_uv with
// offsets and rotations, wrap modes and filters, textured BSDF parameters,
// the named conductors, mask, bumpmap and normalmap, and a render of a mask.
#include "engine/scene/scene_xml.h"

#include "engine/core/error.h"
#include "engine/image/image_io.h"
#include "engine/scene/spectrum.h"
#include "engine/shading/bsdf.h"
#include "tests/support/render_helpers.h"
#include "tests/support/cli_helpers.h"
#include "tests/support/scene_text.h"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

namespace fg {
namespace {

namespace fs = std::filesystem;
using test::lineOf;

fs::path scratchDir() { return test::scratchDirectory("scene_xml_materials"); }

fs::path writeFile(const fs::path& path, const std::string& text) {
    test::writeText(path, text);
    return path;
}

// Loads `text` expecting an InputError on the line of `marker` that names `plugin`; returns the message.
std::string expectErrorAt(const fs::path& dir, const std::string& text, const std::string& marker,
                          const std::string& plugin, const std::string& name) {
    const fs::path path = writeFile(dir / name, text);
    std::string message;
    try {
        loadXmlScene(path.string());
        ADD_FAILURE() << "no InputError for " << name;
    } catch (const InputError& e) {
        message = e.what();
    }
    const std::string location = path.string() + ":" + std::to_string(lineOf(text, marker)) + ":";
    EXPECT_NE(message.find(location), std::string::npos) << "expected " << location << " in: " << message;
    EXPECT_NE(message.find(plugin), std::string::npos) << "expected " << plugin << " in: " << message;
    return message;
}

const Bsdf& shapeBsdf(const Scene& scene, std::size_t shape) {
    return *scene.bsdfs[static_cast<std::size_t>(scene.shapes[shape].bsdf)];
}

Rgb diffuseAlbedo(const Scene& scene, std::size_t shape, const Vec2& uv) {
    return kPi * shapeBsdf(scene, shape).eval(Vec3(0, 0, 1), Vec3(0, 0, 1), uv, TransportMode::Radiance);
}

void expectNear(const Vec3& a, const Vec3& b, float tolerance, const std::string& what) {
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(a[c], b[c], tolerance) << what << " component " << c;
}

// 4 x 2 texels, each its own colour: (0.1 (x + 1), 0.5 y, 0.25) with y = 0 the top row.
Rgb texelColour(int x, int yTop) { return Rgb(0.1f * static_cast<float>(x + 1), 0.5f * static_cast<float>(yTop), 0.25f); }

void writeTexels(const fs::path& path) {
    ImageChannels image;
    image.width = 4;
    image.height = 2;
    for (int y = 0; y < 2; ++y)
        for (int x = 0; x < 4; ++x) image.rgb.push_back(texelColour(x, y));
    writeExr(path.string(), image, {});
}

std::string bitmapShape(const std::string& wrap, const std::string& filter) {
    return "    <shape type=\"rectangle\"><bsdf type=\"diffuse\"><texture type=\"bitmap\" name=\"reflectance\">\n"
           "        <string name=\"filename\" value=\"texels.exr\"/>\n"
           "        <string name=\"wrap_mode\" value=\"" + wrap + "\"/><string name=\"filter_type\" value=\"" + filter + "\"/>\n"
           "        <transform name=\"to_uv\"><rotate z=\"1\" angle=\"90\"/><translate x=\"0.25\" y=\"0.5\"/></transform>\n"
           "    </texture></bsdf></shape>\n";
}

TEST(SceneXmlMaterials, BitmapToUvRotatesAndOffsetsBeforeWrapping) {
    const fs::path dir = scratchDir();
    writeTexels(dir / "texels.exr");
    const Scene scene = loadXmlScene(writeFile(dir / "scene.xml", test::mitsubaSceneText(bitmapShape("repeat", "nearest") +
                                                                              bitmapShape("mirror", "nearest") +
                                                                              bitmapShape("clamp", "nearest") +
                                                                              bitmapShape("clamp", "bilinear")))
                                         .string());
    ASSERT_EQ(scene.shapes.size(), 4u);
    // to_uv = translate(0.25, 0.5) * rotate_z(90 deg): uv' = (-v + 0.25, u + 0.5). Mitsuba
    // looks up texel column floor(4 u') and row floor(2 v') counted from the top.
    // uv (0.1, 0.2) -> uv' (0.05, 0.6) -> column 0, row 1, inside the image.
    for (std::size_t shape = 0; shape < 3; ++shape)
        expectNear(diffuseAlbedo(scene, shape, Vec2(0.1f, 0.2f)), texelColour(0, 1), 1e-6f, "inside");
    // uv (0.3, 0.7) -> uv' (-0.45, 0.8) -> column floor(-1.8) = -2, row 1:
    // repeat wraps -2 to 2, mirror reflects it to 1, clamp holds it at 0.
    expectNear(diffuseAlbedo(scene, 0, Vec2(0.3f, 0.7f)), texelColour(2, 1), 1e-6f, "repeat");
    expectNear(diffuseAlbedo(scene, 1, Vec2(0.3f, 0.7f)), texelColour(1, 1), 1e-6f, "mirror");
    expectNear(diffuseAlbedo(scene, 2, Vec2(0.3f, 0.7f)), texelColour(0, 1), 1e-6f, "clamp");
    // Bilinear: uv (-0.25, -0.125) maps to uv' (0.375, 0.25), the centre of texel (1, 0);
    // uv (-0.25, -0.25) maps to u' = 0.5, halfway between texels 1 and 2 of that row.
    expectNear(diffuseAlbedo(scene, 3, Vec2(-0.25f, -0.125f)), texelColour(1, 0), 1e-5f, "texel centre");
    expectNear(diffuseAlbedo(scene, 3, Vec2(-0.25f, -0.25f)), 0.5f * (texelColour(1, 0) + texelColour(2, 0)), 1e-5f,
               "between texels");
}

TEST(SceneXmlMaterials, LegacyOffsetsAndBadTextureOptions) {
    const fs::path dir = scratchDir();
    writeTexels(dir / "texels.exr");
    const std::string legacy = "<scene version=\"0.6.0\">\n"
                               "    <sensor type=\"perspective\"><float name=\"fov\" value=\"45\"/></sensor>\n"
                               "    <shape type=\"rectangle\"><bsdf type=\"diffuse\"><texture type=\"bitmap\" name=\"reflectance\">\n"
                               "        <string name=\"filename\" value=\"texels.exr\"/><string name=\"filterType\" value=\"nearest\"/>\n"
                               "        <float name=\"uscale\" value=\"2\"/><float name=\"uoffset\" value=\"0.25\"/>\n"
                               "    </texture></bsdf></shape>\n</scene>\n";
    const Scene scene = loadXmlScene(writeFile(dir / "legacy.xml", legacy).string());
    // u' = 2 u + 0.25: u = 0.2 -> 0.65 -> column 2; v = 0.8 -> row 1 from the top.
    expectNear(diffuseAlbedo(scene, 0, Vec2(0.2f, 0.8f)), texelColour(2, 1), 1e-6f, "uscale and uoffset");

    const std::string wrap = test::mitsubaSceneText(
        "    <texture type=\"bitmap\" id=\"t\">\n        <string name=\"filename\" value=\"texels.exr\"/>\n"
        "        <string name=\"wrap_mode\" value=\"zero\"/>\n    </texture>\n"
        "    <shape type=\"rectangle\"><bsdf type=\"diffuse\"><ref name=\"reflectance\" id=\"t\"/></bsdf></shape>\n");
    const std::string m1 = expectErrorAt(dir, wrap, "zero", "texture 'bitmap'", "wrap.xml");
    EXPECT_NE(m1.find("repeat, mirror, clamp"), std::string::npos) << m1;
    const std::string singular = test::mitsubaSceneText(
        "    <texture type=\"checkerboard\" id=\"t\">\n"
        "        <transform name=\"to_uv\"><matrix value=\"1 0 0 0  2 0 1 0  0 1 0 0  0 0 0 1\"/></transform>\n"
        "    </texture>\n"
        "    <shape type=\"rectangle\"><bsdf type=\"diffuse\"><ref name=\"reflectance\" id=\"t\"/></bsdf></shape>\n");
    // Invertible in 3D, but it folds uv onto a line.
    const std::string m2 = expectErrorAt(dir, singular, "to_uv", "texture 'checkerboard'", "singular.xml");
    EXPECT_NE(m2.find("singular"), std::string::npos) << m2;
}

TEST(SceneXmlMaterials, SpecularParametersTakeTextures) {
    const fs::path dir = scratchDir();
    const std::string text = test::mitsubaSceneText(R"(
    <shape type="rectangle"><bsdf type="roughconductor"><float name="alpha" value="0.1"/>
        <string name="distribution" value="ggx"/>
        <texture name="specular_reflectance" type="checkerboard">
            <rgb name="color0" value="0.8"/><rgb name="color1" value="0.2"/></texture>
        <rgb name="eta" value="0, 0, 0"/><rgb name="k" value="1, 1, 1"/></bsdf></shape>
    <shape type="rectangle"><bsdf type="conductor">
        <texture name="specular_reflectance" type="checkerboard">
            <rgb name="color0" value="0.6"/><rgb name="color1" value="0.3"/></texture></bsdf></shape>
    <shape type="rectangle"><bsdf type="dielectric">
        <texture name="specular_reflectance" type="checkerboard">
            <rgb name="color0" value="0.9"/><rgb name="color1" value="0.4"/></texture>
        <texture name="specular_transmittance" type="checkerboard">
            <rgb name="color0" value="0.7"/><rgb name="color1" value="0.5"/></texture></bsdf></shape>
)");
    const Scene scene = loadXmlScene(writeFile(dir / "scene.xml", text).string());
    const Vec2 even(0.1f, 0.1f), odd(0.6f, 0.1f);  // checker cells of half a unit
    const Vec3 wo(0.0f, 0.0f, 1.0f);
    // Perfect-mirror Fresnel (eta 0, k 1): the rough lobe's value scales with the texture.
    const Bsdf& rough = shapeBsdf(scene, 0);
    const Vec3 wi = glm::normalize(Vec3(0.05f, 0.0f, 1.0f));
    const Rgb ratio = rough.eval(wo, wi, even, TransportMode::Radiance) / rough.eval(wo, wi, odd, TransportMode::Radiance);
    expectNear(ratio, Rgb(4.0f), 1e-4f, "roughconductor 0.8 / 0.2");
    const auto mirrorWeight = [&](const Vec2& uv) {
        return shapeBsdf(scene, 1).sample(wo, uv, 0.5f, Vec2(0.5f), TransportMode::Radiance)->weight;
    };
    expectNear(mirrorWeight(even), Rgb(0.6f), 1e-6f, "conductor even");
    expectNear(mirrorWeight(odd), Rgb(0.3f), 1e-6f, "conductor odd");
    const Bsdf& glass = shapeBsdf(scene, 2);
    const auto reflected = glass.sample(wo, odd, 0.0f, Vec2(0.5f), TransportMode::Importance);
    const auto refracted = glass.sample(wo, odd, 0.999f, Vec2(0.5f), TransportMode::Importance);
    ASSERT_TRUE(reflected && refracted);
    expectNear(reflected->weight, Rgb(0.4f), 1e-6f, "dielectric reflectance");
    expectNear(refracted->weight, Rgb(0.5f), 1e-6f, "dielectric transmittance");
}

TEST(SceneXmlMaterials, EveryNamedConductorLoads) {
    const fs::path dir = scratchDir();
    std::string body;
    const std::vector<std::string_view> names = conductorPresetNames();
    EXPECT_GE(names.size(), 40u);
    for (std::string_view name : names)
        body += "    <shape type=\"rectangle\"><bsdf type=\"conductor\"><string name=\"material\" value=\"" +
                std::string(name) + "\"/></bsdf></shape>\n";
    const Scene scene = loadXmlScene(writeFile(dir / "scene.xml", test::mitsubaSceneText(body)).string());
    ASSERT_EQ(scene.shapes.size(), names.size());
    for (std::size_t i = 0; i < names.size(); ++i) {
        const ConductorIor ior = *conductorPreset(names[i]);
        const auto s = shapeBsdf(scene, i).sample(Vec3(0, 0, 1), Vec2(0.5f), 0.5f, Vec2(0.5f), TransportMode::Radiance);
        ASSERT_TRUE(s) << names[i];
        expectNear(s->weight, fresnelConductor(1.0f, ior.eta, ior.k), 1e-6f, std::string(names[i]));
    }
    const std::string unknown = test::mitsubaSceneText(
        "    <bsdf type=\"conductor\" id=\"c\">\n        <string name=\"material\" value=\"Unobtainium\"/>\n    </bsdf>\n");
    const std::string message = expectErrorAt(dir, unknown, "Unobtainium", "bsdf 'conductor'", "unknown.xml");
    EXPECT_NE(message.find("Cu2O"), std::string::npos) << "the message lists the names: " << message;
}

// Mitsuba's spectral tables, where the shared scenes checkout has them.
const fs::path kIorDir = fs::path(FLUXGRAPH_SOURCE_DIR) / ".." / "shared" / "scenes" / "mitsuba-tests" / "ior";

std::vector<SpectrumSample> readSpd(const fs::path& path) {
    std::ifstream in(path);
    std::vector<SpectrumSample> samples;
    std::string line;
    while (std::getline(in, line)) {
        if (line.empty() || line[0] == '#') continue;
        std::istringstream fields(line);
        SpectrumSample s;
        if (fields >> s.wavelengthNm >> s.value) samples.push_back(s);
    }
    return samples;
}

TEST(SceneXmlMaterials, ConductorTableIsTheIntegratedSpectra) {
    if (!fs::exists(kIorDir / "Au.eta.spd")) GTEST_SKIP() << "Mitsuba's ior tables are not at " << kIorDir.string();
    // The generated table must be what the project's spectrum conversion gives
    // (Mitsuba's RGB mode: no white balance for eta and k).
    for (const char* name : {"Au", "Cu", "Ag", "Al", "Cr", "W", "TiN", "a-C"}) {
        const ConductorIor ior = *conductorPreset(name);
        const std::vector<SpectrumSample> eta = readSpd(kIorDir / (std::string(name) + ".eta.spd"));
        const std::vector<SpectrumSample> k = readSpd(kIorDir / (std::string(name) + ".k.spd"));
        ASSERT_GT(eta.size(), 2u) << name;
        const Rgb expectedEta = xyzToLinearSrgb(spectrumToXyz(eta));
        const Rgb expectedK = xyzToLinearSrgb(spectrumToXyz(k));
        for (int c = 0; c < 3; ++c) {
            EXPECT_NEAR(ior.eta[c], expectedEta[c], 1e-4f * std::max(1.0f, std::abs(expectedEta[c]))) << name << " eta " << c;
            EXPECT_NEAR(ior.k[c], expectedK[c], 1e-4f * std::max(1.0f, std::abs(expectedK[c]))) << name << " k " << c;
        }
    }
}

TEST(SceneXmlMaterials, MaskBumpmapAndNormalmapWrapTheirMaterial) {
    const fs::path dir = scratchDir();
    const std::string text = test::mitsubaSceneText(R"(
    <shape type="rectangle"><bsdf type="mask"><float name="opacity" value="0.25"/>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.6"/></bsdf></bsdf></shape>
    <shape type="rectangle"><bsdf type="mask">
        <texture name="opacity" type="checkerboard"><float name="color0" value="1"/><float name="color1" value="0"/></texture>
        <bsdf type="twosided"><bsdf type="diffuse"/></bsdf></bsdf></shape>
    <shape type="rectangle"><bsdf type="bumpmap">
        <texture type="checkerboard" name="arbitrary"/><float name="scale" value="0.5"/>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.3"/></bsdf></bsdf></shape>
    <shape type="rectangle"><bsdf type="bumpmap">
        <texture type="checkerboard" name="bumpmap"/><float name="strength" value="2"/>
        <float name="epsilon" value="0.1"/><bsdf type="diffuse"/></bsdf></shape>
    <shape type="rectangle"><bsdf type="twosided"><bsdf type="normalmap">
        <texture type="checkerboard" name="normalmap"><rgb name="color0" value="0.5, 0.5, 1"/>
            <rgb name="color1" value="1, 0.5, 0.5"/></texture>
        <bsdf type="roughconductor"/></bsdf></bsdf></shape>
)");
    const Scene scene = loadXmlScene(writeFile(dir / "scene.xml", text).string());
    ASSERT_EQ(scene.shapes.size(), 5u);
    const Bsdf& mask = shapeBsdf(scene, 0);
    EXPECT_TRUE(mask.hasOpacity());
    EXPECT_NEAR(mask.opacity(Vec2(0.3f)), 0.25f, 1e-6f);
    expectNear(diffuseAlbedo(scene, 0, Vec2(0.3f)), Rgb(0.6f), 1e-6f, "mask scatters as its material");
    const Bsdf& checkerMask = shapeBsdf(scene, 1);
    EXPECT_NEAR(checkerMask.opacity(Vec2(0.1f, 0.1f)), 1.0f, 1e-6f);
    EXPECT_NEAR(checkerMask.opacity(Vec2(0.6f, 0.1f)), 0.0f, 1e-6f);
    const Bsdf& bump = shapeBsdf(scene, 2);
    EXPECT_TRUE(bump.perturbsNormal());
    EXPECT_FALSE(bump.hasOpacity());
    expectNear(diffuseAlbedo(scene, 2, Vec2(0.3f)), Rgb(0.3f), 1e-6f, "bumpmap scatters as its material");
    // Two-sided around a normal map: the map reaches the tracers through the adapter.
    EXPECT_TRUE(shapeBsdf(scene, 3).perturbsNormal());
    const Bsdf& normals = shapeBsdf(scene, 4);
    EXPECT_TRUE(normals.perturbsNormal());
    ShadingGeometry geometry;
    geometry.dpdu = Vec3(1, 0, 0);
    geometry.dpdv = Vec3(0, 1, 0);
    geometry.uv = Vec2(0.6f, 0.1f);  // the color1 cell: tangent-space normal (1, 0, 0)
    const Vec3 n = normals.perturbedNormal(geometry);
    // (1, 0, 0) lies in the surface; it is kept as given, on the geometric normal's side.
    expectNear(n, Vec3(1, 0, 0), 1e-6f, "normal map");

    expectErrorAt(dir, test::mitsubaSceneText("    <bsdf type=\"mask\" id=\"m\">\n        <float name=\"opacity\" value=\"0.5\"/>\n    </bsdf>\n"),
                  "type=\"mask\"", "bsdf 'mask'", "nonested.xml");
    const std::string twoTextures = test::mitsubaSceneText(
        "    <bsdf type=\"bumpmap\" id=\"b\">\n        <texture type=\"checkerboard\"/>\n"
        "        <texture type=\"checkerboard\"/>\n        <bsdf type=\"diffuse\"/>\n    </bsdf>\n");
    const fs::path path = writeFile(dir / "two.xml", twoTextures);
    try {
        loadXmlScene(path.string());
        ADD_FAILURE() << "two textures accepted";
    } catch (const InputError& e) {
        const std::string message = e.what();
        // Reported at the second texture.
        EXPECT_NE(message.find(path.string() + ":8:"), std::string::npos) << message;
        EXPECT_NE(message.find("bsdf 'bumpmap'"), std::string::npos) << message;
    }
}

TEST(SceneXmlMaterials, PrincipledThinReadsTextures) {
    const fs::path dir = scratchDir();
    const std::string text = test::mitsubaSceneText(R"(
    <shape type="rectangle"><bsdf type="principledthin">
        <rgb name="base_color" value="0.6, 0.5, 0.4"/>
        <texture name="diff_trans" type="checkerboard">
            <float name="color0" value="0"/><float name="color1" value="1"/></texture>
        <float name="eta" value="1.3"/><float name="flatness" value="0.5"/></bsdf></shape>
)");
    const Scene scene = loadXmlScene(writeFile(dir / "scene.xml", text).string());
    const Bsdf& sheet = shapeBsdf(scene, 0);
    EXPECT_NE(sheet.lobes() & BsdfLobe::Transmission, 0u);
    const Vec2 even(0.1f, 0.1f), odd(0.6f, 0.1f);
    const Vec3 wo(0.0f, 0.0f, 1.0f), through(0.0f, 0.0f, -1.0f);
    // diff_trans 1 (of Mitsuba's 0 to 2): half the diffuse light goes through,
    // as Lambert's base_color / pi. At normal incidence Burley's diffuse is
    // Lambert and the fake subsurface 1.25 / 2, mixed half and half by flatness.
    const Rgb lambert = Rgb(0.6f, 0.5f, 0.4f) * kInvPi;
    const float flattened = 0.5f * (1.0f + 0.625f);
    EXPECT_EQ(sheet.eval(wo, through, even, TransportMode::Radiance), Rgb(0.0f));
    expectNear(sheet.eval(wo, through, odd, TransportMode::Radiance), 0.5f * lambert, 1e-6f, "diffuse transmission");
    expectNear(sheet.eval(wo, wo, even, TransportMode::Radiance), flattened * lambert, 1e-6f, "diffuse reflection");
    expectNear(sheet.eval(wo, wo, odd, TransportMode::Radiance), 0.5f * flattened * lambert, 1e-6f,
               "halved reflection");
    const std::string unknown = expectErrorAt(
        dir, test::mitsubaSceneText("    <bsdf type=\"principledthin\" id=\"p\">\n        <float name=\"clearcoat\" value=\"0.5\"/>\n    </bsdf>\n"),
        "clearcoat", "bsdf 'principledthin'", "thin_unknown.xml");
    EXPECT_NE(unknown.find("unknown parameter 'clearcoat'"), std::string::npos) << unknown;
}

TEST(SceneXmlMaterials, PrincipledReadsTexturesAndDefaults) {
    const fs::path dir = scratchDir();
    const std::string text = test::mitsubaSceneText(R"(
    <shape type="rectangle"><bsdf type="principled">
        <texture name="base_color" type="checkerboard">
            <rgb name="color0" value="0.8"/><rgb name="color1" value="0.2"/></texture>
        <texture name="metallic" type="checkerboard">
            <float name="color0" value="1"/><float name="color1" value="0"/></texture>
        <float name="roughness" value="0.1"/>
        <float name="spec_trans" value="0.5"/>
        <float name="eta" value="1.33"/>
        <float name="clearcoat" value="0.5"/><float name="clearcoat_gloss" value="0.8"/>
        <float name="sheen" value="0.2"/><float name="sheen_tint" value="0.1"/>
        <float name="spec_tint" value="0.4"/><float name="anisotropic" value="0.3"/>
        <float name="flatness" value="0.2"/></bsdf></shape>
    <shape type="rectangle"><bsdf type="principled"/></shape>
)");
    const Scene scene = loadXmlScene(writeFile(dir / "scene.xml", text).string());
    const Vec2 even(0.1f, 0.1f), odd(0.6f, 0.1f);
    const Bsdf& textured = shapeBsdf(scene, 0);
    EXPECT_NE(textured.lobes() & BsdfLobe::Transmission, 0u);
    // The even cells are a pure metal with a narrow lobe: far from the mirror
    // direction only the faint clearcoat remains, where the odd cells' diffuse
    // base shows.
    const Vec3 wo(0.0f, 0.0f, 1.0f), wi = glm::normalize(Vec3(1.0f, 0.0f, 0.3f));
    const Rgb metal = textured.eval(wo, wi, even, TransportMode::Radiance);
    const Rgb dielectric = textured.eval(wo, wi, odd, TransportMode::Radiance);
    EXPECT_LT(metal.x, 0.1f * dielectric.x) << metal.x << " vs " << dielectric.x;
    // Refraction from outside crosses eta = 1.33.
    bool refracted = false;
    for (float uLobe = 0.0f; uLobe < 1.0f && !refracted; uLobe += 0.01f) {
        const auto s = textured.sample(wo, odd, uLobe, Vec2(0.3f, 0.6f), TransportMode::Radiance);
        if (s && s->wi.z < 0.0f) {
            refracted = true;
            EXPECT_NEAR(s->eta, 1.33f, 1e-6f);
        }
    }
    EXPECT_TRUE(refracted);
    // Mitsuba's defaults: base_color 0.5, roughness 0.5, specular 0.5, nothing
    // transmitted, a diffuse value at normal incidence of 0.5 / pi plus the
    // specular peak of F0 = 0.04.
    const Bsdf& plain = shapeBsdf(scene, 1);
    EXPECT_EQ(plain.lobes() & BsdfLobe::Transmission, 0u);
    const float alpha = 0.25f;
    const float specularPeak = 0.04f / (kPi * alpha * alpha * 4.0f);
    EXPECT_NEAR(diffuseAlbedo(scene, 1, even).x, 0.5f + kPi * specularPeak, 1e-3f);
}

TEST(SceneXmlMaterials, PrincipledRejectsUnknownAndConflictingParameters) {
    const fs::path dir = scratchDir();
    const std::string unknown = expectErrorAt(
        dir, test::mitsubaSceneText("    <bsdf type=\"principled\" id=\"p\">\n        <float name=\"subsurface\" value=\"0.5\"/>\n    </bsdf>\n"),
        "subsurface", "bsdf 'principled'", "unknown.xml");
    EXPECT_NE(unknown.find("unknown parameter 'subsurface'"), std::string::npos) << unknown;
    EXPECT_NE(unknown.find("clearcoat_gloss"), std::string::npos) << unknown;
    const std::string both = expectErrorAt(
        dir, test::mitsubaSceneText("    <bsdf type=\"principled\" id=\"p\">\n        <float name=\"eta\" value=\"1.4\"/>\n"
                       "        <float name=\"specular\" value=\"0.3\"/>\n    </bsdf>\n"),
        "type=\"principled\"", "bsdf 'principled'", "both.xml");
    EXPECT_NE(both.find("either eta or specular"), std::string::npos) << both;
}

// Floor in z = 0 seen from below a wide blocker at z = 2 that hides an area
// light at z = 4 from it. Direct light only, so the floor's brightness is the
// light that gets through the blocker.
std::string maskScene(const std::string& blocker) {
    return R"(<scene version="3.0.0">
    <sensor type="perspective">
        <float name="fov" value="30"/>
        <transform name="to_world"><lookat origin="0, 0, 1" target="0, 0, 0" up="0, 1, 0"/></transform>
        <film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="16"/></film>
    </sensor>
    <shape type="rectangle"><bsdf type="diffuse"><rgb name="reflectance" value="0.8"/></bsdf></shape>
    <shape type="rectangle">
        <transform name="to_world"><rotate x="1" angle="180"/><translate z="4"/></transform>
        <emitter type="area"><rgb name="radiance" value="5"/></emitter>
    </shape>
)" + blocker + "</scene>\n";
}

std::string blockerWith(const std::string& bsdf) {
    return "    <shape type=\"rectangle\">\n"
           "        <transform name=\"to_world\"><scale value=\"20\"/><translate z=\"2\"/></transform>\n" + bsdf +
           "    </shape>\n";
}

Rgb renderMean(const fs::path& path, std::uint64_t seed) {
    const Scene scene = loadXmlScene(path.string());
    FilmSettings film;
    film.width = 16;
    film.height = 16;
    const std::map<std::string, ParamValue> params = {{"pt.spp", std::int64_t{256}}, {"pt.max_depth", std::int64_t{1}}};
    return test::renderPipeline(scene, "pt", params, film, seed).mean();
}

TEST(SceneXmlMaterials, MaskLetsThroughOneMinusItsOpacity) {
    const fs::path dir = scratchDir();
    const std::string black = "<bsdf type=\"diffuse\"><rgb name=\"reflectance\" value=\"0\"/></bsdf>";
    const Rgb open = renderMean(writeFile(dir / "open.xml", maskScene("")), 1);
    const Rgb clear = renderMean(
        writeFile(dir / "clear.xml",
                  maskScene(blockerWith("<bsdf type=\"mask\"><float name=\"opacity\" value=\"0\"/>" + black + "</bsdf>"))),
        2);
    const Rgb half = renderMean(
        writeFile(dir / "half.xml",
                  maskScene(blockerWith("<bsdf type=\"mask\"><float name=\"opacity\" value=\"0.5\"/>" + black + "</bsdf>"))),
        3);
    const Rgb closed = renderMean(writeFile(dir / "closed.xml", maskScene(blockerWith(black))), 4);
    ASSERT_GT(open.x, 0.05f);
    EXPECT_EQ(closed.x, 0.0f);
    // Both strategies (light sampling through the mask's transmittance, BSDF
    // sampling across it with probability 1 - opacity) see the light; the
    // floor is flat and the light large, so a few hundred samples pin the mean
    // far closer than these bounds.
    EXPECT_NEAR(clear.x / open.x, 1.0f, 0.01f);
    EXPECT_NEAR(half.x / open.x, 0.5f, 0.01f);
}

// The camera looks through a half mask at a floor lit through the same mask:
// a quarter of the open scene's light, whether paths start at the camera (pt)
// or at the light (lt: photons cross the mask, their camera connections are
// attenuated by it).
std::string seenThroughScene(const std::string& sheet) {
    return R"(<scene version="3.0.0">
    <sensor type="perspective">
        <float name="fov" value="20"/>
        <transform name="to_world"><lookat origin="0, 0, 3" target="0, 0, 0" up="0, 1, 0"/></transform>
        <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/></film>
    </sensor>
    <shape type="rectangle"><bsdf type="diffuse"><rgb name="reflectance" value="0.8"/></bsdf></shape>
    <shape type="rectangle">
        <transform name="to_world"><rotate x="1" angle="180"/><scale value="2"/><translate z="4"/></transform>
        <emitter type="area"><rgb name="radiance" value="5"/></emitter>
    </shape>
    <shape type="rectangle">
        <transform name="to_world"><scale value="20"/><translate z="2"/></transform>
)" + sheet + "    </shape>\n</scene>\n";
}

TEST(SceneXmlMaterials, MaskIsSeenThroughByPathAndLightTracing) {
    const fs::path dir = scratchDir();
    const std::string black = "<bsdf type=\"diffuse\"><rgb name=\"reflectance\" value=\"0\"/></bsdf>";
    const Scene open = loadXmlScene(
        writeFile(dir / "open.xml", seenThroughScene("<bsdf type=\"mask\"><float name=\"opacity\" value=\"0\"/>" + black + "</bsdf>"))
            .string());
    const Scene half = loadXmlScene(
        writeFile(dir / "half.xml", seenThroughScene("<bsdf type=\"mask\"><float name=\"opacity\" value=\"0.5\"/>" + black + "</bsdf>"))
            .string());
    FilmSettings film;
    film.width = 8;
    film.height = 8;
    const std::map<std::string, ParamValue> pt = {{"pt.spp", std::int64_t{512}}, {"pt.max_depth", std::int64_t{1}}};
    const std::map<std::string, ParamValue> lt = {{"photon.photons", std::int64_t{3000000}},
                                                  {"photon.store", std::string("global")},
                                                  {"photon.store_direct", true},
                                                  {"photon.max_depth", std::int64_t{1}},
                                                  {"photon.differentials", false}};
    const Rgb ptOpen = test::renderPipeline(open, "pt", pt, film, 1).mean();
    const Rgb ptHalf = test::renderPipeline(half, "pt", pt, film, 2).mean();
    const Rgb ltOpen = test::renderPipeline(open, "lt", lt, film, 3).mean();
    const Rgb ltHalf = test::renderPipeline(half, "lt", lt, film, 4).mean();
    ASSERT_GT(ptOpen.x, 0.05f);
    EXPECT_NEAR(ptHalf.x / ptOpen.x, 0.25f, 0.01f);
    EXPECT_NEAR(ltOpen.x / ptOpen.x, 1.0f, 0.03f);
    EXPECT_NEAR(ltHalf.x / ltOpen.x, 0.25f, 0.0125f);  // about four standard errors
}

// A principled floor under an area light: path tracing (eval and sample with
// MIS) and light tracing (photons scattered by sample in importance mode,
// camera connections by eval) must agree.
TEST(SceneXmlMaterials, PrincipledRendersAlikeByPathAndLightTracing) {
    const fs::path dir = scratchDir();
    const Scene scene = loadXmlScene(writeFile(dir / "principled.xml", seenThroughScene(R"(
        <bsdf type="null"/>
    </shape>
    <shape type="rectangle">
        <transform name="to_world"><scale value="0.999"/><translate z="0.001"/></transform>
        <bsdf type="principled">
            <rgb name="base_color" value="0.7, 0.5, 0.3"/>
            <float name="roughness" value="0.4"/><float name="metallic" value="0.3"/>
            <float name="clearcoat" value="0.5"/><float name="sheen" value="0.5"/>
            <float name="anisotropic" value="0.5"/>
        </bsdf>
)")).string());
    FilmSettings film;
    film.width = 8;
    film.height = 8;
    const std::map<std::string, ParamValue> pt = {{"pt.spp", std::int64_t{512}}, {"pt.max_depth", std::int64_t{1}}};
    const std::map<std::string, ParamValue> lt = {{"photon.photons", std::int64_t{3000000}},
                                                  {"photon.store", std::string("global")},
                                                  {"photon.store_direct", true},
                                                  {"photon.max_depth", std::int64_t{1}},
                                                  {"photon.differentials", false}};
    const Rgb ptMean = test::renderPipeline(scene, "pt", pt, film, 1).mean();
    const Rgb ltMean = test::renderPipeline(scene, "lt", lt, film, 2).mean();
    ASSERT_GT(ptMean.x, 0.05f);
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(ltMean[c] / ptMean[c], 1.0f, 0.03f) << c;
}

// The camera sees the floor through a principledthin sheet that the light
// also crosses: path tracing and light tracing agree on light transmitted
// twice (diffusely and straight through) and on the sheet's own reflection.
TEST(SceneXmlMaterials, PrincipledThinRendersAlikeByPathAndLightTracing) {
    const fs::path dir = scratchDir();
    const Scene scene = loadXmlScene(writeFile(dir / "thin.xml", seenThroughScene(R"(
        <bsdf type="principledthin">
            <rgb name="base_color" value="0.9, 0.8, 0.7"/>
            <float name="spec_trans" value="0.5"/><float name="diff_trans" value="1"/>
            <float name="roughness" value="0.5"/>
        </bsdf>
)")).string());
    FilmSettings film;
    film.width = 8;
    film.height = 8;
    const std::map<std::string, ParamValue> pt = {{"pt.spp", std::int64_t{1024}}, {"pt.max_depth", std::int64_t{3}}};
    const std::map<std::string, ParamValue> lt = {{"photon.photons", std::int64_t{3000000}},
                                                  {"photon.store", std::string("global")},
                                                  {"photon.store_direct", true},
                                                  {"photon.max_depth", std::int64_t{3}},
                                                  {"photon.differentials", false}};
    const Rgb ptMean = test::renderPipeline(scene, "pt", pt, film, 1).mean();
    const Rgb ltMean = test::renderPipeline(scene, "lt", lt, film, 2).mean();
    ASSERT_GT(ptMean.x, 0.02f);
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(ltMean[c] / ptMean[c], 1.0f, 0.03f) << ptMean[c] << " " << ltMean[c];
}

}  // namespace
}  // namespace fg
