// Scene::finalize's light distributions: by power, and the loader's weights
// for next-event estimation.
#include "engine/scene/scene.h"
#include "engine/shading/light.h"

#include <gtest/gtest.h>

#include <stdexcept>

namespace fg {
namespace {

Scene twoPointLights() {
    Scene scene;
    scene.lights.push_back(makePointLight(Vec3(0.0f), Rgb(1.0f)));
    scene.lights.push_back(makePointLight(Vec3(1.0f), Rgb(3.0f)));
    scene.lightShape = {-1, -1};
    return scene;
}

TEST(SceneLightChoice, FollowsPowerWithoutWeights) {
    Scene scene = twoPointLights();
    scene.finalize();
    EXPECT_NEAR(scene.lightPower.discretePmf(1), 0.75f, 1e-6f);
    EXPECT_NEAR(scene.lightChoice.discretePmf(0), 0.25f, 1e-6f);
    EXPECT_NEAR(scene.lightChoice.discretePmf(1), 0.75f, 1e-6f);
}

TEST(SceneLightChoice, FollowsTheGivenWeights) {
    Scene scene = twoPointLights();
    scene.lightChoiceWeights = {3.0f, 1.0f};
    scene.finalize();
    EXPECT_NEAR(scene.lightChoice.discretePmf(0), 0.75f, 1e-6f);
    EXPECT_NEAR(scene.lightChoice.discretePmf(1), 0.25f, 1e-6f);
    EXPECT_NEAR(scene.lightPower.discretePmf(1), 0.75f, 1e-6f) << "power selection is unchanged";
}

TEST(SceneLightChoice, RejectsWeightsThatDoNotFitTheLights) {
    Scene wrongCount = twoPointLights();
    wrongCount.lightChoiceWeights = {1.0f};
    EXPECT_THROW(wrongCount.finalize(), std::invalid_argument);
    Scene negative = twoPointLights();
    negative.lightChoiceWeights = {1.0f, -1.0f};
    EXPECT_THROW(negative.finalize(), std::invalid_argument);
}

}  // namespace
}  // namespace fg
