// The in-memory scene: camera, materials, media, shapes and lights. It is
// independent of any file format: the TOML loader (scene_toml) and later
// importers only fill this structure.
#pragma once

#include "engine/shading/bsdf.h"
#include "engine/shading/distribution.h"
#include "engine/image/film.h"
#include "engine/shading/light.h"
#include "engine/core/math.h"
#include "engine/shading/medium.h"
#include "engine/scene/shape.h"

#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace fg {

struct Ray {
    Vec3 origin{0.0f};
    Vec3 direction{0.0f, 0.0f, 1.0f};
    float tMax = kInfinity;
};

struct Camera {
    Vec3 eye{0.0f, 0.0f, 0.0f};
    Vec3 target{0.0f, 0.0f, -1.0f};
    Vec3 up{0.0f, 1.0f, 0.0f};
    float fovYDegrees = 40.0f;
    int width = 256;
    int height = 256;
    int medium = -1;  // medium the camera sits in
    // Clipping distances along the viewing axis (as Mitsuba's near_clip / far_clip):
    // camera rays start on the near plane and end on the far one.
    float nearClip = 0.0f;
    float farClip = kInfinity;
    // Mirror the image left-right: set for a Mitsuba sensor whose to_world has a
    // negative determinant (e.g. a <scale x="-1"/>), which flips its image.
    bool mirrored = false;
    // Orthographic projection (Mitsuba's orthographic sensor): parallel rays along
    // the viewing axis from a window of 2 * orthoHalfHeight * aspect by
    // 2 * orthoHalfHeight scene units centred on the eye; fovYDegrees is unused.
    bool orthographic = false;
    float orthoHalfHeight = 1.0f;

    // Ray through a continuous raster position (x right, y down, pixel (i,j) spans [i,i+1)x[j,j+1)).
    Ray generateRay(const Vec2& raster) const;
    // Inverse: raster position of a world point in front of the camera, false if behind
    // (orthographic: behind the eye's plane).
    bool project(const Vec3& p, Vec2* raster) const;
};

// Rendering settings a scene file suggests (Mitsuba's sampler, integrator and
// film filter). The job file decides; these only record what the scene said.
struct RenderHints {
    int samplesPerPixel = -1;          // -1: not given
    int maxDepth = -1;                 // -1: not given, or unlimited (Mitsuba's max_depth = -1)
    std::optional<FilterKind> filter;  // reconstruction filter, if the scene names one
    float filterRadius = 0.0f;         // pixels: box half-width or Gaussian support radius
    float gaussianSigma = 0.0f;        // pixels, Gaussian only
};

struct Scene {
    std::string sourcePath;  // the file it was loaded from, for messages
    Camera camera;
    std::vector<std::shared_ptr<Bsdf>> bsdfs;
    std::vector<HomogeneousMedium> media;
    std::vector<Shape> shapes;
    std::vector<std::shared_ptr<Light>> lights;  // area lights point back to their shape via Shape::areaLight
    std::vector<int> lightShape;                 // per light: emitting shape index, -1 otherwise
    Distribution1D lightPower;                   // light selection in proportion to power
    // Per light, the weight with which next-event estimation picks it; empty:
    // in proportion to power. Mitsuba scenes give every light weight 1, as
    // Mitsuba's integrators pick emitters (a small light beside a large
    // environment is then not starved of shadow rays).
    std::vector<float> lightChoiceWeights;
    Distribution1D lightChoice;  // next-event estimation's choice of light, built from the above
    Vec3 boundsMin{0.0f}, boundsMax{0.0f};
    RenderHints hints;

    // Computes bounds, tells infinite lights the scene radius, builds lightPower
    // and lightChoice (throws std::invalid_argument if lightChoiceWeights is
    // neither empty nor one finite non-negative weight per light).
    // Loaders call it once after filling the scene.
    void finalize();
    // Indices of infinite lights (environment, directional): rays that escape meet the environment ones.
    std::vector<int> infiniteLights() const;
};

}  // namespace fg
