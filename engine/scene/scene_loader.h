// Loads a scene file into the in-memory Scene, choosing the importer by the
// file's extension: .toml (fluxgraph's format, scene_toml.h) or .xml (Mitsuba,
// scene_xml.h). Errors are InputErrors naming the file and line.
#pragma once

#include "engine/scene/scene.h"

#include <map>
#include <string>

namespace fg {

// `defines` set scene parameters (Mitsuba's $name); formats without parameters reject them.
Scene loadScene(const std::string& path, const std::map<std::string, std::string>& defines = {});

}  // namespace fg
