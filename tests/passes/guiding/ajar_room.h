// The occluded room of the guiding tests (a small "door ajar"): a closed box
// split by a partition at x = 0.32 with a gap beside it, the light behind the
// partition and the camera on the near side, so that nearly all light reaches
// what the camera sees by indirect paths through the gap, where guiding
// changes the sampled directions most.
#pragma once

#include "engine/scene/scene.h"
#include "engine/scene/scene_loader.h"
#include "tests/support/cli_helpers.h"

#include <filesystem>
#include <string>

namespace fg::test {

inline constexpr float kAjarPartitionX = 0.32f;

inline constexpr const char* kAjarRoom = R"(
[camera]
eye = [-0.9, -0.3, 0.6]
target = [0.32, -0.3, 0.2]
fov = 70
[[material]]
name = "wall"
type = "diffuse"
reflectance = 0.7
[[shape]]
type = "cube"
flip_normals = true
material = "wall"
[[shape]]
type = "cube"
transform = [{ scale = [0.02, 1.0, 0.85] }, { translate = [0.32, 0.0, -0.15] }]
material = "wall"
[[shape]]
type = "rectangle"
transform = [{ scale = 0.15 }, { rotate = { axis = [1, 0, 0], angle = 90 } }, { translate = [0.75, 0.99, -0.6] }]
material = "wall"
emission = 60
)";

// The room loaded as a scene, through a file in the test group's scratch directory.
inline Scene loadAjarRoom(const std::string& scratchGroup) {
    const std::filesystem::path dir = scratchDirectory(scratchGroup);
    writeText(dir / "ajar-room.toml", kAjarRoom);
    return loadScene((dir / "ajar-room.toml").string());
}

}  // namespace fg::test
