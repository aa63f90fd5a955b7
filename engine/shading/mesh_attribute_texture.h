// Mitsuba's mesh_attribute texture: the value of a named attribute of the mesh
// it is looked up on (engine/scene/shape.h, MeshAttribute), times a scale.
// A "vertex_*" attribute is interpolated with the hit's barycentrics, a
// "face_*" one is constant over each triangle; a one-channel attribute is grey.
// The scene importer makes sure every mesh the texture can be looked up on has
// the attribute; where none is at hand (a lookup by uv alone) it is black.
#pragma once

#include "engine/shading/texture.h"

#include <memory>
#include <string>

namespace fg {

std::shared_ptr<Texture> makeMeshAttributeTexture(std::string attributeName, float scale = 1.0f);

}  // namespace fg
