// Scene-format dispatch: the native TOML format and Mitsuba XML; importers
// only have to build the same Scene.
#include "engine/scene/scene_loader.h"

#include "engine/core/error.h"
#include "engine/scene/scene_toml.h"
#include "engine/scene/scene_xml.h"

#include <cmath>
#include <filesystem>
#include <optional>
#include <sstream>
#include <variant>

namespace fg {

namespace {

// Coordinates beyond this are not a scene but a mistake: ray origins there
// lose all precision in float, and Embree rejects (asserts on) rays whose
// origin exceeds about 1.8e18.
constexpr float kMaxCoordinate = 1e10f;

bool representable(float value) { return std::isfinite(value) && std::abs(value) <= kMaxCoordinate; }
bool representable(const Vec3& p) { return representable(p.x) && representable(p.y) && representable(p.z); }

void checkExtent(const Vec3& p, const std::string& path, const std::string& what) {
    if (representable(p)) return;
    std::ostringstream message;
    message << what << " (" << p.x << ", " << p.y << ", " << p.z
            << ") is not finite or lies beyond 1e10 from the origin; scale the scene down";
    throw InputError(path, 0, message.str());
}

void checkSceneExtent(const Scene& scene, const std::string& path) {
    checkExtent(scene.camera.eye, path, "camera position");
    checkExtent(scene.camera.target, path, "camera target");
    for (const Shape& shape : scene.shapes) {
        const std::string name = "shape" + (shape.name.empty() ? std::string() : " '" + shape.name + "'");
        if (const auto* sphere = std::get_if<Sphere>(&shape.geometry)) {
            checkExtent(sphere->center, path, name + " centre");
            checkExtent(Vec3(sphere->radius), path, name + " radius");
        } else {
            for (const Vec3& p : shape.worldMesh().positions) checkExtent(p, path, name + " vertex");
        }
    }
    for (const auto& light : scene.lights) {
        if (const std::optional<Vec3> position = light->position()) checkExtent(*position, path, "light position");
    }
}

Scene loadByFormat(const std::string& path, const std::map<std::string, std::string>& defines) {
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

}  // namespace

Scene loadScene(const std::string& path, const std::map<std::string, std::string>& defines) {
    std::error_code ec;
    if (!std::filesystem::exists(path, ec)) {
        throw InputError(path + (ec ? ": cannot open scene file (" + ec.message() + ")" : ": scene file not found"));
    }
    Scene scene = loadByFormat(path, defines);
    checkSceneExtent(scene, path);
    return scene;
}

}  // namespace fg
