// The pinhole camera (look-at frame, vertical field of view, raster y pointing
// down, near and far clip planes, as Mitsuba's perspective sensor with
// fov_axis = "y"), its orthographic variant (Mitsuba's orthographic sensor) and the scene-wide bookkeeping done once after loading:
// bounds, the bounding sphere that infinite lights need, and light selection in
// proportion to emitted power (luminance of Light::power(), as pbrt-v3's
// PowerLightDistribution), or for next-event estimation by the loader's weights.
#include "engine/scene/scene.h"

#include <cmath>
#include <stdexcept>
#include <limits>
#include <vector>

namespace fg {

namespace {

struct CameraFrame {
    Vec3 forward, right, up;
    float tanHalfFovY;
    float aspect;
};

CameraFrame cameraFrame(const Camera& camera) {
    CameraFrame frame;
    frame.forward = glm::normalize(camera.target - camera.eye);
    // right = forward x up keeps the world's handedness on screen: with up = +y
    // and forward = +z, screen right is world -x, as in Mitsuba's look-at.
    frame.right = glm::normalize(glm::cross(frame.forward, camera.up));
    frame.up = glm::cross(frame.right, frame.forward);
    if (camera.mirrored) frame.right = -frame.right;
    frame.tanHalfFovY = std::tan(0.5f * camera.fovYDegrees * kPi / 180.0f);
    frame.aspect = static_cast<float>(camera.width) / static_cast<float>(camera.height);
    return frame;
}

// cameraFrame of the last camera this thread generated rays for. A render asks
// for one ray per sample from the same camera; the frame's normalisations and
// tangent cost about as much as the rest of the ray.
const CameraFrame& cachedCameraFrame(const Camera& camera) {
    struct Cache {
        Vec3 eye{0.0f}, target{0.0f}, up{0.0f};
        float fovYDegrees = 0.0f;
        int width = 0, height = 0;
        bool mirrored = false;
        bool valid = false;
        CameraFrame frame{};
    };
    thread_local Cache cache;
    if (!cache.valid || cache.eye != camera.eye || cache.target != camera.target || cache.up != camera.up ||
        cache.fovYDegrees != camera.fovYDegrees || cache.width != camera.width || cache.height != camera.height ||
        cache.mirrored != camera.mirrored) {
        cache = {camera.eye, camera.target, camera.up, camera.fovYDegrees, camera.width, camera.height,
                 camera.mirrored, true, cameraFrame(camera)};
    }
    return cache.frame;
}

}  // namespace

Ray Camera::generateRay(const Vec2& raster) const {
    const CameraFrame& frame = cachedCameraFrame(*this);
    if (orthographic) {
        const float x = (2.0f * raster.x / static_cast<float>(width) - 1.0f) * orthoHalfHeight * frame.aspect;
        const float y = (1.0f - 2.0f * raster.y / static_cast<float>(height)) * orthoHalfHeight;
        Ray ray;
        ray.direction = frame.forward;
        ray.origin = eye + x * frame.right + y * frame.up + nearClip * frame.forward;
        ray.tMax = farClip < kInfinity ? farClip - nearClip : kInfinity;
        return ray;
    }
    const float x = (2.0f * raster.x / static_cast<float>(width) - 1.0f) * frame.tanHalfFovY * frame.aspect;
    const float y = (1.0f - 2.0f * raster.y / static_cast<float>(height)) * frame.tanHalfFovY;
    Ray ray;
    ray.direction = glm::normalize(frame.forward + x * frame.right + y * frame.up);
    // Clip planes are perpendicular to the viewing axis, so the distances along
    // this ray grow by 1 / cos of its angle to the axis.
    const float invCos = 1.0f / glm::dot(ray.direction, frame.forward);
    const float tNear = nearClip * invCos;
    ray.origin = eye + tNear * ray.direction;
    ray.tMax = farClip < kInfinity ? farClip * invCos - tNear : kInfinity;
    return ray;
}

bool Camera::project(const Vec3& p, Vec2* raster) const {
    const CameraFrame frame = cameraFrame(*this);
    const Vec3 d = p - eye;
    const float depth = glm::dot(d, frame.forward);
    if (!(depth > 0.0f)) return false;
    const float extent = orthographic ? orthoHalfHeight : depth * frame.tanHalfFovY;
    const float x = glm::dot(d, frame.right) / (extent * frame.aspect);
    const float y = glm::dot(d, frame.up) / extent;
    if (raster) {
        *raster = Vec2(0.5f * (x + 1.0f) * static_cast<float>(width), 0.5f * (1.0f - y) * static_cast<float>(height));
    }
    return true;
}

void Scene::finalize() {
    Vec3 lo(std::numeric_limits<float>::max());
    Vec3 hi(-std::numeric_limits<float>::max());
    for (const Shape& shape : shapes) {
        if (const auto* sphere = std::get_if<Sphere>(&shape.geometry)) {
            lo = glm::min(lo, sphere->center - Vec3(sphere->radius));
            hi = glm::max(hi, sphere->center + Vec3(sphere->radius));
        } else if (const auto* instance = std::get_if<MeshInstance>(&shape.geometry)) {
            for (const Vec3& p : instance->mesh->positions) {
                lo = glm::min(lo, instance->point(p));
                hi = glm::max(hi, instance->point(p));
            }
        } else {
            for (const Vec3& p : std::get<TriangleMesh>(shape.geometry).positions) {
                lo = glm::min(lo, p);
                hi = glm::max(hi, p);
            }
        }
    }
    if (lo.x > hi.x) lo = hi = Vec3(0.0f);  // nothing to bound
    boundsMin = lo;
    boundsMax = hi;

    const Vec3 center = 0.5f * (boundsMin + boundsMax);
    const float radius = glm::length(boundsMax - center);
    for (const auto& light : lights) light->setSceneBounds(center, radius);

    if (!lightChoiceWeights.empty()) {
        if (lightChoiceWeights.size() != lights.size()) {
            throw std::invalid_argument("Scene::lightChoiceWeights must hold one weight per light");
        }
        for (const float w : lightChoiceWeights) {
            if (!(std::isfinite(w) && w >= 0.0f)) throw std::invalid_argument("light choice weights must be finite and >= 0");
        }
    }
    // Power depends on the bounds for infinite lights, so it is read afterwards.
    if (lights.empty()) {
        lightPower = Distribution1D();
        lightChoice = Distribution1D();
        return;
    }
    std::vector<float> weights(lights.size());
    for (std::size_t i = 0; i < lights.size(); ++i) {
        const float w = luminance(lights[i]->power());
        weights[i] = std::isfinite(w) && w > 0.0f ? w : 0.0f;
    }
    lightPower = Distribution1D(weights);
    lightChoice = lightChoiceWeights.empty() ? lightPower : Distribution1D(lightChoiceWeights);
}

std::vector<int> Scene::infiniteLights() const {
    std::vector<int> result;
    for (std::size_t i = 0; i < lights.size(); ++i) {
        if (lights[i]->isInfinite()) result.push_back(static_cast<int>(i));
    }
    return result;
}

}  // namespace fg
