// Textures map surface (u, v) to a linear RGB value. Bitmaps are read with
// OpenImageIO; 8-bit sRGB-encoded files are linearised on load.
#pragma once

#include "engine/core/math.h"

#include <memory>
#include <string>
#include <vector>

namespace fg {

class Texture {
public:
    virtual ~Texture() = default;
    virtual Rgb eval(const Vec2& uv) const = 0;
    // Mean value over the texture's domain (used for albedo estimates and power).
    virtual Rgb mean() const = 0;
};

std::shared_ptr<Texture> makeConstantTexture(const Rgb& value);
// Alternates `even` and `odd` on a grid of `scale` cells per unit of (u, v)
// (Mitsuba's checkerboard has scale (2, 2): one checker per half of uv space).
std::shared_ptr<Texture> makeCheckerboardTexture(const Rgb& even, const Rgb& odd, const Vec2& scale = Vec2(2.0f));
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
// Reads any OpenImageIO format into linear RGB; throws InputError naming the file.
RgbImage readRgbImage(const std::string& path);

}  // namespace fg
