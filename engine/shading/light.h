// Light sources. Sampling for next-event estimation returns, for a reference
// point, a direction wi, the distance to the light and a value L such that the
// estimate of reflected radiance is f(wo, wi)|cos| * L / pdf, where pdf is in
// solid angle (for delta lights pdf = 1 and L already holds I / d^2 or E).
// Emission sampling (sampleEmission) serves the photon passes.
#pragma once

#include "engine/shading/distribution.h"
#include "engine/core/math.h"
#include "engine/scene/shape.h"
#include "engine/shading/texture.h"

#include <memory>
#include <algorithm>
#include <optional>
#include <span>
#include <string>

namespace fg {

struct LightSample {
    Vec3 wi{0.0f};          // unit direction from the reference point to the light
    float distance = 0.0f;  // kInfinity for infinite/directional lights
    Rgb value{0.0f};        // emitted radiance (area, env) or intensity / d^2 (point, spot), irradiance (directional)
    float pdf = 0.0f;       // solid angle; 1 for delta lights
    Vec3 p{0.0f};           // position on the light (finite lights)
    Vec3 n{0.0f};           // light normal at p (area lights)
};

// A ray leaving a light, for photon emission: flux = Le * cos / (pdfPos * pdfDir).
struct EmissionSample {
    Vec3 origin{0.0f};
    Vec3 direction{0.0f};
    Vec3 normal{0.0f};       // zero when the source has no surface (point, spot)
    Rgb flux{0.0f};          // power carried by this sample before dividing by the photon count
    float pdfPosition = 0.0f;  // area density (1 for point sources)
    float pdfDirection = 0.0f; // solid-angle density (1 for collimated sources)
    float emitterArea = 0.0f;  // A_e of Frisvad et al. 2014 Eq. 5 (0 for point sources)
    float emitterSolidAngle = 0.0f;  // omega_e of Eq. 6
};

class Light {
public:
    virtual ~Light() = default;
    virtual bool isDelta() const = 0;     // point, spot, directional
    virtual bool isInfinite() const = 0;  // directional, environments
    virtual std::optional<LightSample> sampleLi(const Vec3& ref, const Vec2& u) const = 0;
    // Solid-angle pdf of sampleLi choosing the point p (normal n) from ref; for
    // infinite lights p is ignored and `wi` is used.
    virtual float pdfLi(const Vec3& ref, const Vec3& p, const Vec3& n, const Vec3& wi) const = 0;
    // Radiance leaving an area light at a point with normal n in direction w (towards the viewer).
    virtual Rgb emitted(const Vec3& n, const Vec3& w) const;
    // The same at surface coordinates uv, for emitters whose radiance is a texture.
    virtual Rgb emittedAt(const Vec3& n, const Vec3& w, const Vec2& uv) const;
    // Radiance arriving along a ray that escapes the scene in direction `dir` (infinite lights).
    virtual Rgb environment(const Vec3& dir) const;
    // Total emitted power, for choosing lights in proportion to power.
    virtual Rgb power() const = 0;
    virtual std::optional<EmissionSample> sampleEmission(const Vec2& uPos, const Vec2& uDir) const = 0;
    // Solid-angle density of sampleEmission's directions, for sources at a point
    // (point, spot, projector); 0 for the others.
    virtual float emissionDirectionPdf(const Vec3& direction) const;
    // Infinite and directional lights need the scene's bounding sphere.
    virtual void setSceneBounds(const Vec3& center, float radius);
    // An environment map samples its directions with a density p_L that is
    // piecewise constant over patches of its (u, v) grid (light.cpp). Through
    // these, a product of p_L with a density constant on each patch (guided
    // environment emission's p_W) is sampled exactly: a patch in proportion to
    // both, then p_L within it. Lights whose sampling has no patches have none.
    virtual std::size_t samplingPatchCount() const { return 0; }
    // The probability that the light's direction sampling lands in the patch.
    virtual float samplingPatchMass(std::size_t) const { return 0.0f; }
    // The directions towards the light at the patches' centres, all at once
    // (`centres` holds samplingPatchCount() of them): rows share their trigonometry.
    virtual void samplingPatchCentres(std::span<Vec3> centres) const { std::fill(centres.begin(), centres.end(), Vec3(0.0f)); }
    // The patch whose density pdfLi reads for the direction towards the light.
    virtual std::size_t samplingPatchOf(const Vec3&) const { return 0; }
    // A direction towards the light within the patch, of solid-angle density
    // pdfLi(ω) / samplingPatchMass(patch); none where pdfLi would be 0 (a pole).
    virtual std::optional<Vec3> sampleInSamplingPatch(std::size_t, const Vec2&) const { return std::nullopt; }
    // Where a point or spot light sits, so that loaders can check it lies in a
    // representable scene; none for lights that are shapes or at infinity.
    virtual std::optional<Vec3> position() const { return std::nullopt; }
};

std::shared_ptr<Light> makePointLight(const Vec3& position, const Rgb& intensity);
// Mitsuba's spot: full intensity inside beamWidth, smooth falloff to zero at cutoffAngle (degrees).
std::shared_ptr<Light> makeSpotLight(const Vec3& position, const Vec3& direction, const Rgb& intensity,
                                     float cutoffAngleDeg, float beamWidthDeg);
// Mitsuba's spot whose intensity is also multiplied by `texture` over the cone:
// a direction with local coordinates (x, y, z) (toWorld's columns, +z the axis)
// reads uv = (1/2 + x / (2 z tan cutoff), 1/2 + y / (2 z tan cutoff)).
std::shared_ptr<Light> makeTexturedSpotLight(const Mat4& toWorld, const Rgb& intensity, float cutoffAngleDeg,
                                             float beamWidthDeg, std::shared_ptr<Texture> texture);
// Mitsuba's projector: a pinhole at toWorld's origin (rotation and translation
// only) looking along +z that projects `irradiance` (resolution width x height
// sets the aspect ratio and the sampling grid) through a frustum with
// horizontal half-angle atan(tanHalfFovX); see light.cpp for the convention.
std::shared_ptr<Light> makeProjectorLight(const Mat4& toWorld, std::shared_ptr<Texture> irradiance, int width,
                                          int height, float tanHalfFovX, float scale);
// Collimated light travelling along `direction` with irradiance `irradiance` on a perpendicular plane.
std::shared_ptr<Light> makeDirectionalLight(const Vec3& direction, const Rgb& irradiance);
std::shared_ptr<Light> makeConstantEnvironment(const Rgb& radiance);
// Equirectangular (latitude-longitude) map, Mitsuba's orientation, importance-sampled
// by luminance x sin(theta); toWorld rotates the map.
std::shared_ptr<Light> makeEnvironmentMap(const RgbImage& image, float scale, const Mat3& toWorld = Mat3(1.0f));
// Diffuse emitter on a shape (front side only unless twoSided). The light keeps its own copy of the geometry.
std::shared_ptr<Light> makeAreaLight(const Shape& shape, const Rgb& radiance, bool twoSided = false);
// Diffuse emitter whose radiance is a texture over the shape's uv (meshes: their
// texture coordinates, or barycentrics without them; spheres: Mitsuba's (phi, theta)).
std::shared_ptr<Light> makeTexturedAreaLight(const Shape& shape, std::shared_ptr<Texture> radiance, bool twoSided = false);

}  // namespace fg
