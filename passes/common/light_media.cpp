#include "passes/common/light_media.h"

namespace fg {

namespace {

// Null boundaries a probe crosses; the bound only guards against degenerate geometry.
constexpr int kMaxProbeCrossings = 1024;

}  // namespace

std::optional<int> probeMedium(const Scene& scene, const RayQuery& rays, const Vec3& p) {
    // Any fixed direction works; this one is off the axes that scene walls tend to align with.
    const Vec3 direction = glm::normalize(Vec3(0.267f, 0.803f, 0.535f));
    Ray ray{p, direction, kInfinity};
    for (int crossing = 0; crossing < kMaxProbeCrossings; ++crossing) {
        const Hit hit = rays.intersect(ray);
        if (!hit.valid()) return std::nullopt;
        const SurfacePoint sp = rays.surface(ray, hit);
        const Shape& shape = scene.shapes[sp.shape];
        if (shape.interiorMedium >= 0 || shape.exteriorMedium >= 0)
            return glm::dot(direction, sp.ng) > 0.0f ? shape.interiorMedium : shape.exteriorMedium;
        ray.origin = offsetRayOrigin(sp.p, sp.ng, direction);
    }
    return std::nullopt;
}

std::vector<int> lightStartMedia(const Scene& scene, const RayQuery& rays) {
    std::vector<int> media(scene.lights.size(), -1);
    if (scene.media.empty()) return media;
    const std::optional<int> cameraProbe = probeMedium(scene, rays, scene.camera.eye);
    const int outside = cameraProbe ? -1 : scene.camera.medium;
    for (std::size_t l = 0; l < scene.lights.size(); ++l) {
        const int shapeIndex = l < scene.lightShape.size() ? scene.lightShape[l] : -1;
        if (shapeIndex >= 0) {
            const Shape& shape = scene.shapes[static_cast<std::size_t>(shapeIndex)];
            if (shape.interiorMedium >= 0 || shape.exteriorMedium >= 0) {
                media[l] = kMediumBySide;
                continue;
            }
        }
        // Infinite lights have no position inside the scene: their paths start outside everything.
        if (scene.lights[l]->isInfinite()) {
            media[l] = outside;
            continue;
        }
        const std::optional<EmissionSample> sample = scene.lights[l]->sampleEmission(Vec2(0.5f), Vec2(0.5f));
        if (!sample) continue;
        const std::optional<int> found = probeMedium(scene, rays, sample->origin);
        media[l] = found ? *found : outside;
    }
    return media;
}

}  // namespace fg
