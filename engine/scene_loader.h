// Loads a scene file into the in-memory Scene, choosing the importer by the
// file's extension. Errors are InputErrors naming the file and line.
#pragma once

#include "engine/scene.h"

#include <string>

namespace fg {

Scene loadScene(const std::string& path);

}  // namespace fg
