// See airlight_scene.h.
#include "tests/support/airlight_scene.h"

#include "engine/shading/light.h"
#include "tests/support/airlight.h"
#include "tests/support/render_helpers.h"

#include <glm/gtc/matrix_transform.hpp>

namespace fg::test {

AirlightScene::AirlightScene() {
    scene.media.emplace_back(Rgb(sigmaA), Rgb(sigmaS), 0.0f);
    Shape wall;
    TriangleMesh plane = makeRectangleMesh();
    plane.transform(glm::translate(Mat4(1.0f), Vec3(0, 0, -wallDistance)) * glm::scale(Mat4(1.0f), Vec3(10.0f)));
    wall.geometry = plane;
    wall.bsdf = addDiffuse(scene, Rgb(0.0f));
    scene.shapes.push_back(wall);
    scene.lights.push_back(makePointLight(light(), Rgb(intensity)));
    scene.lightShape.push_back(-1);
    scene.camera.eye = Vec3(0.0f);
    scene.camera.target = Vec3(0, 0, -1);
    scene.camera.fovYDegrees = 30.0f;
    scene.camera.medium = 0;
    scene.finalize();
}

double AirlightScene::expected(int x, int y, int size) const {
    Camera cam = scene.camera;
    cam.width = cam.height = size;
    double sum = 0.0;
    for (int sy = 0; sy < 4; ++sy) {
        for (int sx = 0; sx < 4; ++sx) {
            const Ray ray = cam.generateRay(Vec2(x + (sx + 0.5f) / 4.0f, y + (sy + 0.5f) / 4.0f));
            const Vec3 d = glm::normalize(ray.direction);
            const double foot = glm::dot(light(), d);
            const double perp = glm::length(light() - static_cast<float>(foot) * d);
            sum += airlight(sigmaS, sigmaS + sigmaA, intensity, perp, foot, wallDistance / -d.z);
        }
    }
    return sum / 16.0;
}

}  // namespace fg::test
