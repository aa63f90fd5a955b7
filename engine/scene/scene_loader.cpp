// Scene-format dispatch: the native TOML format and Mitsuba XML; importers
// only have to build the same Scene.
#include "engine/scene/scene_loader.h"

#include "engine/core/error.h"
#include "engine/scene/scene_toml.h"
#include "engine/scene/scene_xml.h"

#include <filesystem>

namespace fg {

Scene loadScene(const std::string& path, const std::map<std::string, std::string>& defines) {
    if (!std::filesystem::exists(path)) throw InputError(path + ": scene file not found");
    const std::string ext = std::filesystem::path(path).extension().string();
    if (ext == ".xml") return loadXmlScene(path, defines);
    if (ext == ".toml") {
        if (!defines.empty()) {
            throw InputError(path + ": scene parameter '" + defines.begin()->first +
                             "' is given (--define or scene_defines), but TOML scenes have no parameters");
        }
        return loadTomlScene(path);
    }
    throw InputError(path + ": unknown scene format '" + ext + "' (supported: .toml, .xml)");
}

}  // namespace fg
