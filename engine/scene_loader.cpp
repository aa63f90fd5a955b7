// Scene-format dispatch: the native TOML format for now; importers for other
// formats only have to build the same Scene.
#include "engine/scene_loader.h"

#include "engine/error.h"
#include "engine/scene_toml.h"

#include <filesystem>

namespace fg {

Scene loadScene(const std::string& path) {
    if (!std::filesystem::exists(path)) throw InputError(path + ": scene file not found");
    const std::string ext = std::filesystem::path(path).extension().string();
    if (ext == ".toml") return loadTomlScene(path);
    throw InputError(path + ": unknown scene format '" + ext + "' (supported: .toml)");
}

}  // namespace fg
