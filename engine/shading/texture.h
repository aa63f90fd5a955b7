// Textures map surface (u, v) to a linear RGB value. Bitmaps are read with
// OpenImageIO; 8-bit sRGB-encoded files are linearised on load.
#pragma once

#include "engine/core/math.h"

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

namespace fg {

struct TriangleMesh;

// Where on a surface a texture is looked up: (u, v) and, on a mesh, which
// triangle and where in it (for textures that read the mesh's attributes).
// Built implicitly from uv where no mesh is at hand (lights, tests).
struct TexturePoint {
    TexturePoint(const Vec2& uvIn) : uv(uvIn) {}
    TexturePoint(const Vec2& uvIn, const TriangleMesh* meshIn, std::uint32_t triangleIn, const Vec2& barycentricIn)
        : uv(uvIn), mesh(meshIn), triangle(triangleIn), barycentric(barycentricIn) {}
    Vec2 uv;
    const TriangleMesh* mesh = nullptr;
    std::uint32_t triangle = 0;
    Vec2 barycentric{0.0f};  // weights of the triangle's second and third vertex
};

class Texture {
public:
    virtual ~Texture() = default;
    virtual Rgb eval(const Vec2& uv) const = 0;
    // The value at a surface point; materials look textures up through this.
    // It is eval(uv) except for textures that read the mesh (mesh_attribute).
    virtual Rgb evalAt(const TexturePoint& at) const { return eval(at.uv); }
    // Mean value over the texture's domain (used for albedo estimates and power).
    virtual Rgb mean() const = 0;
    // The scalar a texture stands for where a parameter is one number (opacity,
    // bump height): the luminance of eval(uv).
    float evalScalar(const TexturePoint& at) const { return luminance(evalAt(at)); }
    // d evalScalar / d(u, v). The default differentiates numerically; textures
    // with a closed form override it.
    virtual Vec2 scalarGradient(const Vec2& uv) const;
};

// Affine map of (u, v) applied before a lookup: linear * uv + offset (Mitsuba's
// to_uv, of which the 2x2 linear part and the x, y translation act on uv).
struct UvTransform {
    glm::mat2 linear{1.0f};
    Vec2 offset{0.0f};
    Vec2 apply(const Vec2& uv) const { return linear * uv + offset; }
    static UvTransform scale(const Vec2& s) { return {glm::mat2(s.x, 0.0f, 0.0f, s.y), Vec2(0.0f)}; }
    // This map applied after `first`.
    UvTransform after(const UvTransform& first) const { return {linear * first.linear, linear * first.offset + offset}; }
};

// How a bitmap lookup treats texel indices outside the image (Mitsuba's wrap_mode).
enum class TextureWrap : std::uint8_t { Repeat, Mirror, Clamp };
// Bilinear interpolation between texel centres, or the nearest texel.
enum class TextureFilter : std::uint8_t { Bilinear, Nearest };
struct BitmapLookup {
    UvTransform toUv;
    TextureWrap wrapU = TextureWrap::Repeat;
    TextureWrap wrapV = TextureWrap::Repeat;
    TextureFilter filter = TextureFilter::Bilinear;
};

std::shared_ptr<Texture> makeConstantTexture(const Rgb& value);
// Alternates `even` and `odd` on a grid of `scale` cells per unit of (u, v)
// (Mitsuba's checkerboard has scale (2, 2): one checker per half of uv space).
std::shared_ptr<Texture> makeCheckerboardTexture(const Rgb& even, const Rgb& odd, const Vec2& scale = Vec2(2.0f));
// The same with cells of one unit after an arbitrary map of (u, v).
std::shared_ptr<Texture> makeCheckerboardTexture(const Rgb& even, const Rgb& odd, const UvTransform& toCells);
// Bilinear lookup with wrap-around; throws InputError if the file cannot be read.
// `uvScale` multiplies (u, v) before the lookup.
std::shared_ptr<Texture> loadBitmapTexture(const std::string& path, const Vec2& uvScale = Vec2(1.0f));

// A loaded RGB float image (row-major, top row first), shared by bitmap textures
// and environment maps.
struct RgbImage {
    int width = 0;
    int height = 0;
    std::vector<Rgb> pixels;
    const Rgb& at(int x, int y) const { return pixels[static_cast<std::size_t>(y) * width + x]; }
};
// A bitmap texture over an image already in memory (same lookup as loadBitmapTexture).
std::shared_ptr<Texture> makeBitmapTexture(RgbImage image, const Vec2& uvScale = Vec2(1.0f));
// With any uv map, wrap mode and filter. Texel (x, y) covers [x, x+1) / width in
// u and, since v = 0 is the bottom row, [height-1-y, height-y) / height in v.
std::shared_ptr<Texture> makeBitmapTexture(RgbImage image, const BitmapLookup& lookup);
// Reads any OpenImageIO format into linear RGB; throws InputError naming the file.
// `raw`: keep 8/16-bit values as stored (data such as normal maps, Mitsuba's raw = true).
RgbImage readRgbImage(const std::string& path, bool raw = false);

}  // namespace fg
