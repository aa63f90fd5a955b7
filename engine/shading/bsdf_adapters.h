// Materials that wrap another material (Mitsuba's mask, bumpmap and normalmap)
// or two (blendbsdf).
// They scatter exactly as the material they wrap; what they change is where
// and around which normal it scatters, which the tracers ask through
// Bsdf::opacity and Bsdf::perturbedNormal (see bsdf.h).
#pragma once

#include "engine/shading/bsdf.h"
#include "engine/shading/texture.h"

#include <memory>

namespace fg {

// Opacity = the texture's luminance, clamped to [0, 1].
std::shared_ptr<Bsdf> makeMask(std::shared_ptr<Bsdf> inner, std::shared_ptr<Texture> opacity);
// Height field h = scale * luminance(texture) over (u, v): the surface is
// displaced by h along the shading normal, to first order in its derivatives.
std::shared_ptr<Bsdf> makeBumpMap(std::shared_ptr<Bsdf> inner, std::shared_ptr<Texture> height, float scale = 1.0f);
// Tangent-space normals: the texture's RGB in [0, 1] encodes 2 * rgb - 1 in the
// frame (dp/du, n x dp/du, n) of the interpolated shading normal n.
std::shared_ptr<Bsdf> makeNormalMap(std::shared_ptr<Bsdf> inner, std::shared_ptr<Texture> normals);
// (1 - w) first + w second with w = the weight texture's luminance clamped to
// [0, 1] (Mitsuba's blendbsdf). Neither material may perturb the normal.
std::shared_ptr<Bsdf> makeBlend(std::shared_ptr<Bsdf> first, std::shared_ptr<Bsdf> second, std::shared_ptr<Texture> weight);

}  // namespace fg
