// fluxgraph's native scene format: one TOML file (parsed with toml++) that
// fills an fg::Scene. Lengths are in scene units (no physical unit is
// implied), angles in degrees, colours are linear RGB.
//
// Every problem in the file -- TOML syntax, an unknown key, a value of the
// wrong type, a reference to an undefined material or medium, a value outside
// its range, a missing file -- is reported as fg::InputError "file:LINE:
// message", LINE being the line of the offending key (or of the table header
// when a required key is missing). Unknown keys are always errors. Relative
// file paths are resolved against the directory of the scene file.
//
// Value notation used below:
//   vec3   [x, y, z]
//   rgb    [r, g, b] or one number for grey
//   ior    a number > 0 or a preset name ("vacuum", "air", "water", "bk7", "glass", "diamond", ...)
//
// [camera]                     pinhole or orthographic camera; required
//   type = "perspective"       default; or "orthographic" (parallel rays along target - eye)
//   eye = vec3                 required
//   target = vec3              required
//   up = vec3                  default [0, 1, 0]
//   fov = number               perspective: vertical field of view, degrees in (0, 180); default 40
//   view_height = number       orthographic: height of the view in scene units, > 0; default 2
//                              (the width follows the image's aspect ratio)
//   width, height = integer    image size in pixels; default 256 x 256
//   medium = "name"            medium surrounding the camera; default none
//
// [[medium]]                   homogeneous medium; any number of them
//   name = "name"              required, unique among media
//   sigma_s = rgb              scattering coefficient >= 0, per scene unit; required
//   sigma_a = rgb              absorption coefficient >= 0, per scene unit; required
//   g = number                 Henyey-Greenstein asymmetry in (-1, 1); default 0
//   scale = number             multiplies sigma_s and sigma_a, > 0; default 1
//
// [[material]]                 a BSDF; any number of them
//   name = "name"              required, unique among materials
//   type = "diffuse"           reflectance = texture (default 0.5)
//          "dielectric"        ior (default 1.5), exterior_ior (default 1.0),
//                              specular_reflectance, specular_transmittance = rgb in [0, 1] (default 1)
//          "thindielectric"    ior, exterior_ior
//          "conductor"         material = one of Mitsuba's named conductors ("Au", "Ag", "Al",
//                              "Cu", "Cr", ...; tools/conductor_table.py), or "none" for an
//                              ideal mirror (the default) or eta = rgb and k = rgb;
//                              specular_reflectance = rgb in [0, 1] (default 1)
//          "roughconductor"    as conductor, plus alpha = roughness > 0 (default 0.1) and
//                              distribution = "ggx" (default) or "beckmann"
//          "roughdielectric"   ior, exterior_ior, alpha (default 0.1), distribution
//          "plastic"           reflectance = texture (diffuse base, default 0.5), ior (default 1.5),
//                              exterior_ior, nonlinear = bool (default false)
//          "roughplastic"      as plastic, plus alpha (default 0.1), distribution, and
//                              specular_reflectance = rgb in [0, 1] (coating, default 1)
//          "null"              index-matched boundary (for media); no parameters
//          "twosided"          inner = "name" of a material defined above this one
//   texture: rgb in [0, 1]
//          | { checkerboard = { even = rgb, odd = rgb, scale = [su, sv] (default [2, 2]) } }
//          | { bitmap = "file.png", uv_scale = [su, sv] (default [1, 1]) }
//   ior is interior over exterior: the interior is the side the surface normal points away from.
//
// [[shape]]                    any number of them; geometry id == order in the file
//   type = "obj"               file = "mesh.obj" (required)
//          "rectangle"         [-1, 1]^2 in the z = 0 plane, facing +z
//          "disk"              unit disk in the z = 0 plane, facing +z; segments = integer >= 3 (default 128)
//          "cube"              [-1, 1]^3, facing outwards
//          "cylinder"          open tube (no caps) facing outwards: radius = number > 0 (default 1),
//                              p0 = vec3 (default origin), p1 = vec3 (default [0, 0, 1]);
//                              256 flat facets with smooth normals, uv = (angle / 360, height)
//          "sphere"            center = vec3 (default origin), radius = number > 0 (default 1);
//                              analytic, so it takes no transform
//   name = "name"              optional label
//   material = "name"          required
//   transform = [ op, ... ]    meshes only; ops apply in the order listed (first op first):
//       { translate = vec3 }
//       { scale = number or vec3 }                       (no zero factors)
//       { rotate = { axis = vec3, angle = degrees } }    (right-handed)
//       { matrix = [16 numbers] or [[4], [4], [4], [4]] } (row-major, affine, invertible)
//       { lookat = { origin = vec3, target = vec3, up = vec3 } }  (object +z towards target)
//   interior = "medium"        medium on the side the normal points away from; default none
//   exterior = "medium"        medium on the side the normal points to; default none
//   emission = rgb >= 0        radiance; makes the shape a diffuse area light
//   two_sided_emission = bool  emit from both sides (needs emission); default false
//   flip_normals = bool        reverse the shape's orientation; default false (meshes are flipped
//                              in their data, spheres through Shape::flipNormals)
//
// [[light]]                    any number of them
//   type = "point"             position = vec3, intensity = rgb (power per steradian)
//          "spot"              position = vec3, target = vec3 or direction = vec3, intensity = rgb,
//                              cutoff_angle = degrees in (0, 180) (default 20),
//                              beam_width = degrees in (0, cutoff_angle] (default 3/4 cutoff_angle)
//          "directional"       direction = vec3 (direction of travel), irradiance = rgb
//          "constant"          radiance = rgb (uniform environment)
//          "envmap"            file = "sky.exr" (equirectangular), scale = number > 0 (default 1),
//                              transform = [ op, ... ] (rotations only)
//
// Example:
//   [camera]
//   eye = [0, 1, 4]
//   target = [0, 1, 0]
//   fov = 40
//
//   [[material]]
//   name = "white"
//   type = "diffuse"
//   reflectance = [0.8, 0.8, 0.8]
//
//   [[shape]]
//   type = "rectangle"
//   material = "white"
//   transform = [{ rotate = { axis = [1, 0, 0], angle = -90 } }, { scale = 5 }]
//
//   [[light]]
//   type = "point"
//   position = [0, 3, 0]
//   intensity = 20
#pragma once

#include "engine/scene/scene.h"

#include <string>
#include <string_view>

namespace fg {

// Reads and parses a scene file; the returned scene is finalized.
Scene loadTomlScene(const std::string& path);
// Parses scene text; messages name `pathForMessages`, relative files resolve against `baseDir`.
Scene parseTomlScene(std::string_view text, const std::string& pathForMessages, const std::string& baseDir);

}  // namespace fg
