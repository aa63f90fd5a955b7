// The medium each light's subpaths start in, found by probing the scene:
// shared by the passes that trace paths from the lights (photon tracing,
// bidirectional path tracing), which must agree on it with the path tracer's
// camera paths for their estimates to match.
#pragma once

#include "engine/accel/ray_query.h"
#include "engine/core/math.h"
#include "engine/scene/scene.h"

#include <optional>
#include <vector>

namespace fg {

// A light's start medium that depends on the side of its emitting shape a
// path leaves by (the shape declares media).
constexpr int kMediumBySide = -2;

// Where a probe ray from p first meets a boundary that declares media: the
// medium on p's side, or nothing if it escapes.
std::optional<int> probeMedium(const Scene& scene, const RayQuery& rays, const Vec3& p);

// Per light, the medium its paths start in: kMediumBySide for emitting shapes
// that declare media, the probed medium around positioned lights, and for
// lights at infinity (and positioned ones no probe places) the medium outside
// every boundary: the camera's if the camera is out there too, else none.
std::vector<int> lightStartMedia(const Scene& scene, const RayQuery& rays);

}  // namespace fg
