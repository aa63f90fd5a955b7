// Mitsuba scene import: XML scenes of Mitsuba 3 (version="2.x" / "3.x") and
// Mitsuba 0.5 / 0.6 (version="0.5.x" / "0.6.x"), parsed with pugixml, become
// the same fg::Scene the native TOML format builds. Older files' camelCase
// parameter names (intIOR, toWorld, sampleCount, ...) and <lookAt> are read as
// their Mitsuba 3 spellings (int_ior, to_world, sample_count, <lookat>), as
// Mitsuba 3 itself upgrades them; defaults follow the file's version where
// the two differ (conductor material: "none" in 3.x, "Cu" in 0.x).
//
// Anything fluxgraph cannot represent faithfully -- an unknown element, plugin
// type or parameter, a malformed or out-of-range value, a missing file or id,
// a parameter value it does not implement -- is an fg::InputError
// "file:LINE: <plugin> '<type>': message" naming the element's file and line.
// Every top-level element is read, so one load reports all such problems (up
// to 50), one line each (InputError::problems).
// Nothing is silently dropped; the exceptions, which do not change what a
// pinhole path tracer computes, are listed as "accepted, no effect" below.
//
// Structure
//   <default name value>   declares $name unless a define (command line
//                          --define name=value, job key scene_defines) gives it
//   $name                  substituted in every attribute value after its declaration;
//                          an undeclared $name is an error, and so is a define the
//                          scene never declares or uses
//   <include filename>     splices the children of another <scene> file; relative
//                          to the including file; include cycles are errors
//   <path value>           another directory to search for relative file names
//   id / <ref id [name]>   any object may be defined once (any depth) and referenced
//                          by id (bsdfs, textures, media, phase functions, area emitters);
//                          name="interior"/"exterior" binds media, name="reflectance" etc. textures
//   Relative file names are looked up in the <path> directories, then the directory
//   of the file that names them, then the directory of the main scene file.
//
// Transforms (<transform name="to_world">; steps apply in the order written)
//   <translate x y z | value="x, y, z">   <scale value="s" | value="x, y, z" | x y z>
//   <rotate x y z | value="x, y, z" angle="degrees">   <matrix value="16 numbers, row-major">
//   <lookat origin target up>  (object +z towards target, +x = up x dir, as Mitsuba)
//
// Values: <float> <integer> <boolean> <string> <point> <vector> <rgb> <srgb>
//   <spectrum value="0.5"> (grey) or value="400:0.1, 500:0.7, ..." (converted to
//   linear sRGB by engine/scene/spectrum.h: white-balanced so that a flat spectrum is grey;
//   reflectances are clamped to [0, 1] and other quantities to >= 0 afterwards, as
//   Mitsuba clamps out-of-gamut conversions). On an emitter both convert as Mitsuba 3's
//   RGB mode does: no white balance, and value="v" is v * sRGB(XYZ = 1, 1, 1), not grey.
//   An <integer> is accepted where a float is.
//
// Sensor (exactly one)
//   perspective   fov (default: focal_length) + fov_axis x|y|diagonal|smaller|larger
//                 (default x), or focal_length ("50mm", 35 mm film diagonal);
//                 near_clip (0.01), far_clip (10000); to_world (rotation, translation,
//                 uniform scale, mirroring; a mirroring to_world mirrors the image as
//                 in Mitsuba); a nested or referenced <medium> the camera sits in.
//                 Accepted, no effect on a pinhole: focus_distance, shutter_open, shutter_close.
//                 Mitsuba's camera looks along +z of to_world with +x to the LEFT of the
//                 image; fg::Camera uses the same convention, so images are not mirrored.
//   orthographic  near_clip (0.01), far_clip (10000), to_world (rotation, translation,
//                 mirroring, scale equal in x and y: the view spans local x in [-1, 1]
//                 across the width and y in [-1/aspect, 1/aspect], as in Mitsuba);
//                 accepted, no effect: shutter_open, shutter_close. pt only (light
//                 tracing cannot reach a camera whose rays are parallel).
//   film          hdrfilm or ldrfilm: width (768), height (576) -> camera resolution;
//                 rfilter box (radius 0.5) | gaussian (stddev 0.5, support 4 stddev; the
//                 default) | tent (radius 1) -> Scene::hints.
//                 Accepted, no effect (the job file decides the output): file_format,
//                 pixel_format, component_format, sample_border, compensate, banner,
//                 high_quality_edges, attach_log; ldrfilm's tonemap_method, gamma,
//                 exposure, key, burn. crop_* only when it is the full frame.
//   sampler       any of Mitsuba's samplers: sample_count -> Scene::hints.samplesPerPixel;
//                 accepted, no effect: seed, jitter, scramble, dimension.
//   <integrator>  only the depth is read (-> hints.maxDepth; found also inside nested
//                 integrators such as moment); the job file chooses the rendering pipeline.
//                 Mitsuba's max_depth counts path vertices with the camera's (2 = direct
//                 light), fluxgraph's counts scattering events: hints.maxDepth = max_depth - 1,
//                 -1 stays unlimited, 0 and 1 are errors; type direct gives 1.
//
// Shapes
//   obj, ply      filename; face_normals (false: vertex normals from the file, else
//                 angle-weighted smooth normals as Mitsuba computes them; true: flat);
//                 obj: flip_tex_coords (true); ply: vertex and face properties become mesh
//                 attributes as Mitsuba groups them (engine/scene/ply_loader.cpp)
//   rectangle, disk, cube   Mitsuba's unit shapes
//   cylinder      radius (1), p0 (0, 0, 0), p1 (0, 0, 1): an open tube, tessellated
//                 into 256 facets with smooth normals; uv = (phi / 2 pi, height)
//   serialized    filename, shape_index (0); Mitsuba's zlib-compressed mesh format
//                 (versions 3 and 4), face_normals as obj/ply
//   sphere        center, radius; to_world may rotate, mirror, translate and scale
//                 uniformly (folded in; the rotation turns the uv parametrisation);
//                 non-uniform scale is an error (spheres stay analytic, no ellipsoids)
//   shapegroup    (with an id) shapes that only instances place; an unused group is
//                 still checked
//   instance      <ref> to a shapegroup, to_world: every shape of the group, placed
//                 after its own to_world; meshes are shared between instances (one
//                 Embree scene, instanced), spheres copied with the transform folded in
//   all           to_world, flip_normals, one bsdf (default: diffuse 0.5), one area
//                 emitter, media named interior / exterior
//   Texture coordinates keep Mitsuba's meaning: OBJ's v is flipped as Mitsuba flips it
//   (flip_tex_coords), and bitmaps are loaded upside down, because Mitsuba's v = 0 is the
//   top image row where fluxgraph's bitmap lookup puts the bottom row.
//
// BSDFs
//   diffuse          reflectance (texture, 0.5)
//   dielectric       int_ior ("bk7"), ext_ior ("air"), numbers or Mitsuba's names;
//                    specular_reflectance, specular_transmittance (texture, 1)
//   thindielectric   int_ior, ext_ior; its straight-through transmission is a null event, as
//                    in Mitsuba 3 (no depth; shadow rays pass with its transmittance)
//   roughdielectric  int_ior, ext_ior, alpha (0.1) or alpha_u = alpha_v, distribution
//   conductor        material (any of Mitsuba's named conductors, "Au", "Cu", ..., or
//                    none; tools/conductor_table.py) or eta + k; ext_eta;
//                    specular_reflectance (texture, 1)
//   roughconductor   conductor's parameters plus alpha / alpha_u = alpha_v, distribution
//   plastic          diffuse_reflectance (texture, 0.5), int_ior (1.49), ext_ior ("air"),
//                    nonlinear (false); specular_reflectance only 1
//   roughplastic     plastic's parameters plus alpha / alpha_u = alpha_v, distribution;
//                    specular_reflectance (1)
//   null, twosided (one nested bsdf)
//   mask             opacity (texture, 0.5; its luminance), one nested bsdf
//   bumpmap          one nested texture (the height; its luminance), scale or strength (1),
//                    epsilon accepted (the gradient is exact), one nested bsdf
//   normalmap        normalmap (texture; tangent-space normals, usually raw), one nested bsdf
//   blendbsdf        weight (texture or float in [0, 1]; its luminance), two nested bsdfs:
//                    (1 - weight) first + weight second; neither may be a bump or normal map
//   principled       base_color (texture, 0.5), roughness (texture, 0.5), metallic,
//                    spec_tint, anisotropic, sheen, sheen_tint, clearcoat, clearcoat_gloss,
//                    spec_trans, flatness (textures, 0; their luminance); specular (0.5)
//                    or eta; main_specular_sampling_rate, clearcoat_sampling_rate,
//                    diffuse_reflectance_sampling_rate (1)
//   principledthin   principled's textures but metallic and clearcoat, plus eta (texture,
//                    1.5) and diff_trans (texture, 0, range 0 to 2); specular_reflectance_,
//                    specular_transmittance_, diffuse_reflectance_ and
//                    diffuse_transmittance_sampling_rate (1)
//   distribution: beckmann (Mitsuba's default) or ggx. Beckmann's Smith masking is the
//   exact one, where Mitsuba uses Walter's rational fit (within 0.35 %).
//   sample_visible is accepted, no effect (sampling strategy only).
// Textures
//   bitmap        filename, filter_type bilinear or nearest (0.x: ewa and trilinear are
//                 read as bilinear), wrap_mode / wrap_mode_u / wrap_mode_v repeat, mirror
//                 or clamp, raw (false); to_uv (its 2x2 linear part and x, y translation;
//                 0.x: uscale, vscale, uoffset, voffset)
//   checkerboard  color0 (0.4), color1 (0.2), to_uv as bitmap
//   mesh_attribute name ("vertex_*": interpolated over the triangle, "face_*": constant
//                 on it), scale (1). Only as a material's parameter (not an emitter's, a
//                 bump or normal map's); every shape whose material reads it must be a
//                 mesh with that attribute, or the shape is an error naming it
//
// Emitters
//   area          radiance (colour or texture over the shape's uv); inside a shape, or
//                 defined with an id and referenced from shapes
//   point         position or to_world; intensity (1)
//   spot          to_world (+z is the axis), intensity (1), cutoff_angle (20),
//                 beam_width (3/4 cutoff_angle), texture (optional, over the cone:
//                 uv = 1/2 + (x, y) / (2 z tan cutoff_angle) in the light's frame)
//   projector     irradiance (colour, 1, or texture; its resolution sets the aspect and
//                 the sampling grid), scale (1), fov + fov_axis or focal_length (50mm) as
//                 the perspective sensor, to_world (rotation and translation)
//   directional   direction or to_world (+z); irradiance (1)
//   constant      radiance (1)
//   envmap        filename, scale (1), to_world (rotation only); looked up as Mitsuba 3 does
//                 (rows on the corners, v (height - 1); engine/shading/light.cpp)
//   Next-event estimation picks every emitter (one per shape for area emitters) with
//   the same probability, as Mitsuba's integrators do (Scene::lightChoiceWeights).
//
// Media
//   homogeneous   sigma_t (1) + albedo (0.75), or sigma_s + sigma_a (0.x scenes must give
//                 one of the two: their default is a material preset); scale (1);
//                 phase isotropic or hg (g, default 0.8); accepted, no effect:
//                 sample_emitters, has_spectral_extinction
//   heterogeneous (and any <volume>): refused with "heterogeneous medium not supported"
#pragma once

#include "engine/scene/scene.h"

#include <map>
#include <string>

namespace fg {

// Reads a Mitsuba XML scene; `defines` override the scene's <default> values.
// The returned scene is finalized, with Scene::hints filled from the file.
Scene loadXmlScene(const std::string& path, const std::map<std::string, std::string>& defines = {});

}  // namespace fg
