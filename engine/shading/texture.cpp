#include "engine/shading/texture.h"

#include "engine/core/error.h"
#include "engine/image/image_diagnostics.h"
#include "engine/image/image_file_input.h"
#include "engine/image/image_guard.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>
#include <string_view>

namespace fg {

namespace {

class ConstantTexture final : public Texture {
public:
    explicit ConstantTexture(const Rgb& v) : value_(v) {}
    Rgb eval(const Vec2&) const override { return value_; }
    Rgb mean() const override { return value_; }
    Vec2 scalarGradient(const Vec2&) const override { return Vec2(0.0f); }

private:
    Rgb value_;
};

class CheckerboardTexture final : public Texture {
public:
    CheckerboardTexture(const Rgb& even, const Rgb& odd, const UvTransform& toCells)
        : even_(even), odd_(odd), toCells_(toCells) {}
    Rgb eval(const Vec2& uvIn) const override {
        const Vec2 uv = toCells_.apply(uvIn);
        const auto cx = static_cast<long>(std::floor(uv.x));
        const auto cy = static_cast<long>(std::floor(uv.y));
        return ((cx + cy) & 1) == 0 ? even_ : odd_;
    }
    Rgb mean() const override { return 0.5f * (even_ + odd_); }
    Vec2 scalarGradient(const Vec2&) const override { return Vec2(0.0f); }

private:
    Rgb even_, odd_;
    UvTransform toCells_;
};

int wrapTexel(long index, int size, TextureWrap mode) {
    switch (mode) {
        case TextureWrap::Clamp: return static_cast<int>(std::clamp<long>(index, 0, size - 1));
        case TextureWrap::Mirror: {
            const long period = 2L * size;
            const long m = ((index % period) + period) % period;
            return static_cast<int>(m < size ? m : period - 1 - m);
        }
        case TextureWrap::Repeat: break;
    }
    return static_cast<int>(((index % size) + size) % size);
}

class BitmapTexture final : public Texture {
public:
    BitmapTexture(RgbImage image, const BitmapLookup& lookup) : image_(std::move(image)), lookup_(lookup) {
        Rgb sum(0.0f);
        for (const Rgb& p : image_.pixels) sum += p;
        mean_ = sum / static_cast<float>(std::max<std::size_t>(1, image_.pixels.size()));
    }

    Rgb eval(const Vec2& uvIn) const override {
        const Corners c = corners(uvIn);
        if (lookup_.filter == TextureFilter::Nearest) return c.texel[0];
        return (1 - c.fx) * (1 - c.fy) * c.texel[0] + c.fx * (1 - c.fy) * c.texel[1] + (1 - c.fx) * c.fy * c.texel[2] +
               c.fx * c.fy * c.texel[3];
    }

    Vec2 scalarGradient(const Vec2& uvIn) const override {
        if (lookup_.filter == TextureFilter::Nearest) return Vec2(0.0f);
        const Corners c = corners(uvIn);
        float value[4];
        for (int i = 0; i < 4; ++i) value[i] = luminance(c.texel[i]);
        // Derivatives of the bilinear interpolant in texel units, then through
        // x = u' W - 1/2, y = (1 - v') H - 1/2 and uv' = linear * uv + offset.
        const float dx = (1 - c.fy) * (value[1] - value[0]) + c.fy * (value[3] - value[2]);
        const float dy = (1 - c.fx) * (value[2] - value[0]) + c.fx * (value[3] - value[1]);
        const Vec2 gradientMapped(dx * static_cast<float>(image_.width), -dy * static_cast<float>(image_.height));
        return glm::transpose(lookup_.toUv.linear) * gradientMapped;
    }

    Rgb mean() const override { return mean_; }

private:
    // The texels a lookup blends (nearest: only texel[0]) and the weights of the second column / row.
    struct Corners {
        Rgb texel[4];
        float fx = 0.0f, fy = 0.0f;
    };

    Corners corners(const Vec2& uvIn) const {
        // v = 0 is the bottom row of the image (OBJ / Mitsuba convention).
        const Vec2 uv = lookup_.toUv.apply(uvIn);
        float x = uv.x * static_cast<float>(image_.width);
        float y = (1.0f - uv.y) * static_cast<float>(image_.height);
        Corners c;
        if (lookup_.filter == TextureFilter::Nearest) {
            c.texel[0] = texel(static_cast<long>(std::floor(x)), static_cast<long>(std::floor(y)));
            return c;
        }
        x -= 0.5f;
        y -= 0.5f;
        const auto x0 = static_cast<long>(std::floor(x)), y0 = static_cast<long>(std::floor(y));
        c.fx = x - static_cast<float>(x0);
        c.fy = y - static_cast<float>(y0);
        c.texel[0] = texel(x0, y0);
        c.texel[1] = texel(x0 + 1, y0);
        c.texel[2] = texel(x0, y0 + 1);
        c.texel[3] = texel(x0 + 1, y0 + 1);
        return c;
    }

    const Rgb& texel(long x, long y) const {
        return image_.at(wrapTexel(x, image_.width, lookup_.wrapU), wrapTexel(y, image_.height, lookup_.wrapV));
    }

    RgbImage image_;
    BitmapLookup lookup_;
    Rgb mean_{0.0f};
};

float srgbToLinear(float v) { return v <= 0.04045f ? v / 12.92f : std::pow((v + 0.055f) / 1.055f, 2.4f); }

}  // namespace

std::shared_ptr<Texture> makeConstantTexture(const Rgb& value) { return std::make_shared<ConstantTexture>(value); }

Vec2 Texture::scalarGradient(const Vec2& uv) const {
    // Central differences over a step well below any texel of the textures in use.
    constexpr float kStep = 1e-3f;
    return Vec2(evalScalar(uv + Vec2(kStep, 0.0f)) - evalScalar(uv - Vec2(kStep, 0.0f)),
                evalScalar(uv + Vec2(0.0f, kStep)) - evalScalar(uv - Vec2(0.0f, kStep))) /
           (2.0f * kStep);
}

std::shared_ptr<Texture> makeCheckerboardTexture(const Rgb& even, const Rgb& odd, const Vec2& scale) {
    return std::make_shared<CheckerboardTexture>(even, odd, UvTransform::scale(scale));
}

std::shared_ptr<Texture> makeCheckerboardTexture(const Rgb& even, const Rgb& odd, const UvTransform& toCells) {
    return std::make_shared<CheckerboardTexture>(even, odd, toCells);
}

std::shared_ptr<Texture> loadBitmapTexture(const std::string& path, const Vec2& uvScale) {
    return makeBitmapTexture(readRgbImage(path), uvScale);
}

std::shared_ptr<Texture> makeBitmapTexture(RgbImage image, const Vec2& uvScale) {
    BitmapLookup lookup;
    lookup.toUv = UvTransform::scale(uvScale);
    return std::make_shared<BitmapTexture>(std::move(image), lookup);
}

std::shared_ptr<Texture> makeBitmapTexture(RgbImage image, const BitmapLookup& lookup) {
    return std::make_shared<BitmapTexture>(std::move(image), lookup);
}

RgbImage readRgbImage(const std::string& path, bool raw) {
    checkImageStructure(path);
    CapturedStderr libraryMessages;
    std::string openError;
    std::unique_ptr<ImageFileInput> input = openImageFile(path, openError);
    if (!input) throw InputError(path, 0, "cannot read image: " + imageReadFailure(openError, libraryMessages));
    const ImageFileSpec& spec = input->spec();
    // The header's size is only a claim: it is checked before the pixels are
    // allocated. The buffer is also left uninitialised, so that a header that
    // lies within the bound costs address space, not memory.
    checkImageHeader(path, spec.formatName, spec.width, spec.height, spec.depth, spec.channels());
    const std::int64_t pixelCount = std::int64_t{spec.width} * spec.height;
    // Only red, green and blue (or grey) are used; alpha and further channels are not read.
    const int channels = spec.channels() >= 3 ? 3 : 1;
    const std::unique_ptr<float[]> data(new float[static_cast<std::size_t>(pixelCount) * channels]);
    if (!input->readPixels(channels, data.get())) {
        throw InputError(path, 0, "cannot decode image: " + imageReadFailure(input->error(), libraryMessages));
    }
    // 8/16-bit images are display-encoded unless they say otherwise; float formats are linear.
    const bool encoded = spec.sampleType == SampleType::UInt8 || spec.sampleType == SampleType::UInt16;
    const bool linearise = !raw && encoded && spec.colorSpace != "Linear" && spec.colorSpace != "linear";
    RgbImage image;
    image.width = spec.width;
    image.height = spec.height;
    image.pixels.resize(static_cast<std::size_t>(spec.width) * spec.height);
    for (std::size_t i = 0; i < image.pixels.size(); ++i) {
        const float* p = &data[i * channels];
        Rgb c = channels >= 3 ? Rgb(p[0], p[1], p[2]) : Rgb(p[0]);
        if (linearise) c = Rgb(srgbToLinear(c.x), srgbToLinear(c.y), srgbToLinear(c.z));
        image.pixels[i] = c;
    }
    return image;
}

}  // namespace fg
