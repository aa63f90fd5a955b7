// The start medium of each light's subpaths (passes/common/light_media): the
// photon and bdpt passes start their light paths there, so a wrong answer makes
// them disagree with the path tracer. Scenes are written inline: a fog cube
// with lights inside and outside it, a second medium nested in a global one,
// and emitters that declare media themselves.
#include "passes/common/light_media.h"

#include "engine/accel/ray_query.h"
#include "engine/scene/scene_toml.h"
#include "tests/support/cli_helpers.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <string>

namespace fg {
namespace {

namespace fs = std::filesystem;

Scene loadInline(const std::string& name, const std::string& text) {
    const fs::path path = test::scratchDirectory("light_media") / (name + ".toml");
    test::writeText(path, text);
    return loadTomlScene(path.string());
}

// A cube [-1, 1]³ of fog behind a null boundary; the camera is outside, and
// its probe escapes (so "outside" is the camera's own medium).
std::string fogCubeScene(const std::string& cameraMedium, const std::string& cubeMedia, const std::string& extra) {
    return R"([camera]
eye = [0, 0, 6]
target = [0, 0, 0]
up = [0, 1, 0]
fov = 40
width = 8
height = 8
)" + cameraMedium + R"(

[[medium]]
name = "fog"
sigma_s = 0.5
sigma_a = 0.1

[[medium]]
name = "ink"
sigma_s = 2.0
sigma_a = 1.0

[[material]]
name = "boundary"
type = "null"

[[material]]
name = "grey"
type = "diffuse"
reflectance = [0.5, 0.5, 0.5]

[[shape]]
name = "cube"
type = "cube"
material = "boundary"
)" + cubeMedia + "\n" + extra;
}

// A diffuse square at y = 0 inside the cube, facing +y: opaque, but it declares
// no media, so probes pass it by.
const std::string kOpaqueSquare = R"(
[[shape]]
name = "shelf"
type = "rectangle"
material = "grey"
transform = [{ rotate = { axis = [1, 0, 0], angle = -90 } }, { scale = 0.5 }]
)";

std::string pointLight(const std::string& position) {
    return "\n[[light]]\ntype = \"point\"\nposition = " + position + "\nintensity = [1, 1, 1]\n";
}

TEST(LightMedia, LightsInsideAndOutsideAFogCube) {
    const Scene scene = loadInline(
        "cube", fogCubeScene("", "interior = \"fog\"",
                             kOpaqueSquare + pointLight("[0, -0.5, -0.3]") + pointLight("[5, 0, 0]") +
                                 "\n[[light]]\ntype = \"constant\"\nradiance = [0.1, 0.1, 0.1]\n"));
    const RayQuery rays(scene);
    const int fog = 0;
    // Beneath the opaque square: the probe crosses it and still finds the fog boundary from inside.
    ASSERT_TRUE(probeMedium(scene, rays, Vec3(0.0f, -0.5f, -0.3f)).has_value());
    EXPECT_EQ(*probeMedium(scene, rays, Vec3(0.0f, -0.5f, -0.3f)), fog);
    // Outside, the probe direction leads away from the cube: nothing is found.
    EXPECT_FALSE(probeMedium(scene, rays, Vec3(5.0f, 0.0f, 0.0f)).has_value());
    // Below the cube the probe enters it, so it reports the outside of the boundary.
    ASSERT_TRUE(probeMedium(scene, rays, Vec3(-0.5f, -3.0f, -2.0f)).has_value());
    EXPECT_EQ(*probeMedium(scene, rays, Vec3(-0.5f, -3.0f, -2.0f)), -1);

    const std::vector<int> media = lightStartMedia(scene, rays);
    ASSERT_EQ(media.size(), 3u);
    EXPECT_EQ(media[0], fog);
    EXPECT_EQ(media[1], -1);
    EXPECT_EQ(media[2], -1);  // the environment surrounds the clear space the camera is in
}

TEST(LightMedia, GlobalMediumReachesLightsOutsideEveryBoundary) {
    // The camera sits in fog that fills the scene; the cube holds ink in fog.
    const Scene scene = loadInline("nested", fogCubeScene("medium = \"fog\"", "interior = \"ink\"\nexterior = \"fog\"",
                                                          pointLight("[0, 0, 0]") + pointLight("[5, 0, 0]") +
                                                              "\n[[light]]\ntype = \"constant\"\nradiance = [0.1, 0.1, 0.1]\n"));
    const RayQuery rays(scene);
    const std::vector<int> media = lightStartMedia(scene, rays);
    ASSERT_EQ(media.size(), 3u);
    EXPECT_EQ(media[0], 1);  // ink
    EXPECT_EQ(media[1], 0);  // fog, the camera's medium, since its probe meets no boundary
    EXPECT_EQ(media[2], 0);
}

TEST(LightMedia, EmittersThatDeclareMediaStartBySide) {
    const std::string emitters = R"(
[[shape]]
name = "lamp-in-fog"
type = "rectangle"
material = "grey"
emission = [1, 1, 1]
transform = [{ scale = 0.2 }, { translate = [0, 0, 0.5] }]

[[shape]]
name = "lamp-with-media"
type = "rectangle"
material = "grey"
emission = [1, 1, 1]
interior = "ink"
transform = [{ scale = 0.2 }, { translate = [3, 0, 0] }]
)";
    const Scene scene = loadInline("emitters", fogCubeScene("", "interior = \"fog\"", emitters));
    const RayQuery rays(scene);
    const std::vector<int> media = lightStartMedia(scene, rays);
    ASSERT_EQ(media.size(), 2u);
    EXPECT_EQ(media[0], 0);  // probed from its centre, inside the fog cube
    EXPECT_EQ(media[1], kMediumBySide);
}

TEST(LightMedia, SceneWithoutMediaStartsEveryLightInVacuum) {
    const Scene scene = loadInline("vacuum", fogCubeScene("", "", pointLight("[0, 0, 0]")));
    const RayQuery rays(scene);
    EXPECT_EQ(lightStartMedia(scene, rays), std::vector<int>{-1});
}

}  // namespace
}  // namespace fg
