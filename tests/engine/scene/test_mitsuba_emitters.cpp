// The Mitsuba importer's projector, textured spot and textured area emitters:
// what each parameter becomes, and one clear error per bad value.
#include "engine/core/error.h"
#include "engine/image/image_io.h"
#include "engine/scene/scene_xml.h"
#include "tests/support/cli_helpers.h"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <string>

namespace fg {
namespace {

namespace fs = std::filesystem;

fs::path scratchDir() { return test::scratchDirectory("mitsuba_emitters"); }

fs::path writeFile(const fs::path& path, const std::string& text) {
    test::writeText(path, text);
    return path;
}

std::string sceneText(const std::string& body) {
    return "<scene version=\"3.0.0\">\n"
           "    <sensor type=\"perspective\"><film type=\"hdrfilm\"><integer name=\"width\" value=\"16\"/>"
           "<integer name=\"height\" value=\"16\"/></film></sensor>\n"
           "    <shape type=\"rectangle\"/>\n" +
           body + "</scene>\n";
}

// An 8 x 4 linear EXR with a constant value (the mean is that value).
void writeTexture(const fs::path& path, float value) {
    ImageChannels image;
    image.width = 8;
    image.height = 4;
    image.rgb.assign(32, Rgb(value));
    writeExr(path.string(), image, {});
}

TEST(MitsubaEmitters, ProjectorFieldOfViewAndScaleFromTheTexture) {
    const fs::path dir = scratchDir();
    writeTexture(dir / "slide.exr", 2.0f);
    const std::string text = sceneText(R"(    <emitter type="projector">
        <float name="fov" value="90"/><float name="scale" value="3"/>
        <texture type="bitmap" name="irradiance"><string name="filename" value="slide.exr"/></texture>
        <transform name="to_world"><lookat origin="0, 0, 5" target="0, 0, 0" up="0, 1, 0"/></transform>
    </emitter>
)");
    const Scene scene = loadXmlScene(writeFile(dir / "scene.xml", text).string());
    ASSERT_EQ(scene.lights.size(), 1u);
    // fov 90 along x over an 8 x 4 texture: a plane 2 x 1 at unit distance; power = pi * scale * area * mean.
    const float power = kPi * 3.0f * 2.0f * 1.0f * 2.0f;
    EXPECT_NEAR(scene.lights[0]->power().x, power, 1e-3f * power);
    // Irradiance on the plane z = 0 (5 units away) straight below: pi * scale * E / 25.
    const auto s = scene.lights[0]->sampleLi(Vec3(0.0f), Vec2(0.5f));
    ASSERT_TRUE(s.has_value());
    EXPECT_NEAR(s->value.x, kPi * 3.0f * 2.0f / 25.0f, 1e-4f);
    // x edge at 45 degrees: inside at 4.9 units off-axis, outside at 5.1.
    EXPECT_TRUE(scene.lights[0]->sampleLi(Vec3(4.9f, 0.0f, 0.0f), Vec2(0.5f)).has_value());
    EXPECT_FALSE(scene.lights[0]->sampleLi(Vec3(5.1f, 0.0f, 0.0f), Vec2(0.5f)).has_value());
    EXPECT_FALSE(scene.lights[0]->sampleLi(Vec3(0.0f, 2.6f, 0.0f), Vec2(0.5f)).has_value()) << "y spans half of x";
}

TEST(MitsubaEmitters, TexturedSpotAndArea) {
    const fs::path dir = scratchDir();
    writeTexture(dir / "t.exr", 0.5f);
    const std::string text = sceneText(R"(    <emitter type="spot">
        <rgb name="intensity" value="4"/><float name="cutoff_angle" value="30"/>
        <texture type="bitmap" name="texture"><string name="filename" value="t.exr"/></texture>
    </emitter>
    <shape type="rectangle">
        <emitter type="area"><texture type="bitmap" name="radiance"><string name="filename" value="t.exr"/></texture></emitter>
    </shape>
)");
    const Scene scene = loadXmlScene(writeFile(dir / "scene.xml", text).string());
    ASSERT_EQ(scene.lights.size(), 2u);
    const auto spot = scene.lights[0]->sampleLi(Vec3(0.0f, 0.0f, 2.0f), Vec2(0.5f));
    ASSERT_TRUE(spot.has_value());
    EXPECT_NEAR(spot->value.x, 4.0f * 0.5f / 4.0f, 1e-5f) << "intensity x texture / d^2 on the axis";
    EXPECT_EQ(scene.lightShape[1], 1);
    EXPECT_NEAR(scene.lights[1]->emittedAt(Vec3(0, 0, 1), Vec3(0, 0, 1), Vec2(0.3f, 0.7f)).x, 0.5f, 1e-6f);
}

TEST(MitsubaEmitters, NextEventEstimationPicksEveryEmitterAlike) {
    const fs::path dir = scratchDir();
    // A dim environment carries far more power (over the scene's bounding disk)
    // than a spot or a point light; Mitsuba picks each of the four alike.
    const std::string text = sceneText(R"(    <emitter type="constant"><rgb name="radiance" value="0.1"/></emitter>
    <emitter type="spot"><rgb name="intensity" value="5"/></emitter>
    <emitter type="point"><rgb name="intensity" value="50"/></emitter>
    <shape type="rectangle"><emitter type="area"><rgb name="radiance" value="1"/></emitter></shape>
)");
    const Scene scene = loadXmlScene(writeFile(dir / "choice.xml", text).string());
    ASSERT_EQ(scene.lights.size(), 4u);
    for (std::size_t i = 0; i < scene.lights.size(); ++i) {
        EXPECT_FLOAT_EQ(scene.lightChoice.discretePmf(i), 0.25f) << "light " << i;
    }
    // Photons still leave the lights in proportion to power.
    EXPECT_GT(scene.lightPower.discretePmf(2), 4.0f * scene.lightPower.discretePmf(1));
}

TEST(MitsubaEmitters, BadParametersAreOneLineErrors) {
    const fs::path dir = scratchDir();
    struct Case {
        const char* name;
        std::string body, expected;
    };
    const Case cases[] = {
        {"scaled", R"(<emitter type="projector"><transform name="to_world"><scale value="2"/></transform></emitter>)",
         "may only rotate and translate"},
        {"fov", R"(<emitter type="projector"><float name="fov" value="180"/></emitter>)", "fov must lie in (0, 180)"},
        {"both", R"(<emitter type="projector"><float name="fov" value="30"/><string name="focal_length" value="50mm"/></emitter>)",
         "either fov or focal_length"},
        {"wide", R"(<emitter type="spot"><float name="cutoff_angle" value="95"/><texture type="checkerboard" name="texture"/></emitter>)",
         "below 90 degrees"},
        {"notexture", R"(<emitter type="spot"><bsdf type="diffuse" name="texture"/></emitter>)", "expected a <texture>"},
    };
    for (const Case& c : cases) {
        const fs::path path = writeFile(dir / (std::string(c.name) + ".xml"), sceneText("    " + c.body + "\n"));
        try {
            loadXmlScene(path.string());
            ADD_FAILURE() << c.name << ": no error";
        } catch (const InputError& e) {
            const std::string message = e.what();
            EXPECT_NE(message.find(path.string() + ":4:"), std::string::npos) << c.name << ": " << message;
            EXPECT_NE(message.find(c.expected), std::string::npos) << c.name << ": " << message;
            EXPECT_EQ(message.find('\n'), std::string::npos) << message;
        }
    }
}

}  // namespace
}  // namespace fg
