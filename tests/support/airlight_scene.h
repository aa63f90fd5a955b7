// The airlight scene of the volumetric photon pipelines' tests: a point light
// in an infinite grey isotropic medium, seen from the origin against a black
// wall, whose single scattering has the closed form of airlight.h.
#pragma once

#include "engine/scene/scene.h"

namespace fg::test {

struct AirlightScene {
    float sigmaS = 0.4f, sigmaA = 0.1f, intensity = 10.0f;
    // The wall at z = -wallDistance; the light at (h, 0, -delta).
    float wallDistance = 3.0f, h = 0.5f, delta = 1.2f;
    Scene scene;

    AirlightScene();
    Vec3 light() const { return Vec3(h, 0.0f, -delta); }
    // Single-scattered radiance of pixel (x, y) of a size x size film: the
    // closed form averaged over 4 x 4 sub-pixel rays.
    double expected(int x, int y, int size) const;
};

}  // namespace fg::test
