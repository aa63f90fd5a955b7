#include "engine/shading/texture.h"

#include "engine/core/error.h"
#include "engine/image/image_diagnostics.h"

#include <OpenImageIO/imageio.h>

#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>

namespace fg {

namespace {

class ConstantTexture final : public Texture {
public:
    explicit ConstantTexture(const Rgb& v) : value_(v) {}
    Rgb eval(const Vec2&) const override { return value_; }
    Rgb mean() const override { return value_; }

private:
    Rgb value_;
};

class CheckerboardTexture final : public Texture {
public:
    CheckerboardTexture(const Rgb& even, const Rgb& odd, const Vec2& scale) : even_(even), odd_(odd), scale_(scale) {}
    Rgb eval(const Vec2& uv) const override {
        const auto cx = static_cast<long>(std::floor(uv.x * scale_.x));
        const auto cy = static_cast<long>(std::floor(uv.y * scale_.y));
        return ((cx + cy) & 1) == 0 ? even_ : odd_;
    }
    Rgb mean() const override { return 0.5f * (even_ + odd_); }

private:
    Rgb even_, odd_;
    Vec2 scale_;
};

class BitmapTexture final : public Texture {
public:
    BitmapTexture(RgbImage image, const Vec2& uvScale) : image_(std::move(image)), uvScale_(uvScale) {
        Rgb sum(0.0f);
        for (const Rgb& p : image_.pixels) sum += p;
        mean_ = sum / static_cast<float>(std::max<std::size_t>(1, image_.pixels.size()));
    }
    Rgb eval(const Vec2& uvIn) const override {
        // v = 0 is the bottom row of the image (OBJ / Mitsuba convention).
        const Vec2 uv = uvIn * uvScale_;
        const float x = (uv.x - std::floor(uv.x)) * static_cast<float>(image_.width) - 0.5f;
        const float y = (1.0f - (uv.y - std::floor(uv.y))) * static_cast<float>(image_.height) - 0.5f;
        const int x0 = static_cast<int>(std::floor(x)), y0 = static_cast<int>(std::floor(y));
        const float fx = x - static_cast<float>(x0), fy = y - static_cast<float>(y0);
        auto texel = [&](int px, int py) {
            px = ((px % image_.width) + image_.width) % image_.width;
            py = ((py % image_.height) + image_.height) % image_.height;
            return image_.at(px, py);
        };
        return (1 - fx) * (1 - fy) * texel(x0, y0) + fx * (1 - fy) * texel(x0 + 1, y0) +
               (1 - fx) * fy * texel(x0, y0 + 1) + fx * fy * texel(x0 + 1, y0 + 1);
    }
    Rgb mean() const override { return mean_; }

private:
    RgbImage image_;
    Vec2 uvScale_;
    Rgb mean_{0.0f};
};

// 16384 x 8192, the largest environment maps in common use.
constexpr std::int64_t kMaxImagePixels = std::int64_t{1} << 27;

float srgbToLinear(float v) { return v <= 0.04045f ? v / 12.92f : std::pow((v + 0.055f) / 1.055f, 2.4f); }

// OpenEXR 3.1 allocates each header attribute at the size the file states
// (up to 2 GB for a string) before it reads the value, so a damaged header of
// a few bytes costs gigabytes. The attribute list is simple enough to walk
// first (OpenEXR file layout: magic, version, then per part the attributes as
// name NUL, type NUL, int32 size, value, ended by an empty name; multi-part
// files end the list of parts with one more empty name): every size must fit
// in what is left of the file. Checked by signature, whatever the file's name,
// because OpenImageIO tries the EXR reader on any file the named reader refuses.
void checkExrAttributeSizes(const std::string& path) {
    std::ifstream in(path, std::ios::binary);
    char start[8] = {};
    if (!in.read(start, sizeof start) || std::memcmp(start, "\x76\x2f\x31\x01", 4) != 0) return;
    const bool multiPart = (static_cast<unsigned char>(start[5]) & 0x10) != 0;
    std::error_code ec;
    const std::uintmax_t fileSize = std::filesystem::file_size(path, ec);
    if (ec) return;  // the reader reports it
    const auto refuse = [&](const std::string& why) { throw InputError(path, 0, "cannot read image: " + why); };
    const auto readName = [&](std::string& name) {
        name.clear();
        for (char c; in.get(c) && c != '\0';) {
            name += c;
            if (name.size() > 255) refuse("EXR header holds a name longer than 255 bytes");
        }
        if (!in) refuse("EXR header ends early");
    };
    std::string name, type;
    bool partEnded = false;
    while (true) {
        readName(name);
        if (name.empty()) {
            if (!multiPart || partEnded) return;  // the end of the header (of the list of parts)
            partEnded = true;
            continue;
        }
        partEnded = false;
        readName(type);
        unsigned char sizeBytes[4];
        if (!in.read(reinterpret_cast<char*>(sizeBytes), 4)) refuse("EXR header ends early");
        const std::int64_t size = static_cast<std::int32_t>(sizeBytes[0] | (sizeBytes[1] << 8) | (sizeBytes[2] << 16) |
                                                            (std::uint32_t{sizeBytes[3]} << 24));
        const auto position = static_cast<std::int64_t>(in.tellg());
        if (size < 0 || position < 0 || static_cast<std::uintmax_t>(position + size) > fileSize)
            refuse("EXR attribute '" + name + "' claims " + std::to_string(size) + " bytes, more than the file holds");
        in.seekg(size, std::ios::cur);
    }
}

// libpng likewise allocates a chunk (tEXt and others) at its stated length,
// up to 2 GB, before reading it. A PNG's chunks (length, type, data, CRC;
// PNG specification section 5.3) are walked first: each must fit in the file.
void checkPngChunkSizes(const std::string& path) {
    std::ifstream in(path, std::ios::binary);
    char signature[8] = {};
    if (!in.read(signature, sizeof signature) || std::memcmp(signature, "\x89PNG\r\n\x1a\n", 8) != 0) return;
    std::error_code ec;
    const std::uintmax_t fileSize = std::filesystem::file_size(path, ec);
    if (ec) return;  // the reader reports it
    std::uintmax_t position = 8;
    unsigned char header[8];
    while (position + 8 <= fileSize && in.read(reinterpret_cast<char*>(header), 8)) {
        const std::uintmax_t length = (std::uintmax_t{header[0]} << 24) | (std::uintmax_t{header[1]} << 16) |
                                      (std::uintmax_t{header[2]} << 8) | header[3];
        const std::string type(reinterpret_cast<const char*>(header + 4), 4);
        if (position + 12 + length > fileSize)
            throw InputError(path, 0, "cannot read image: PNG chunk " + type + " claims " + std::to_string(length) +
                                          " bytes, more than the file holds");
        if (type == "IEND") return;
        position += 12 + length;
        in.seekg(static_cast<std::streamoff>(position));
    }
}

}  // namespace

std::shared_ptr<Texture> makeConstantTexture(const Rgb& value) { return std::make_shared<ConstantTexture>(value); }

std::shared_ptr<Texture> makeCheckerboardTexture(const Rgb& even, const Rgb& odd, const Vec2& scale) {
    return std::make_shared<CheckerboardTexture>(even, odd, scale);
}

std::shared_ptr<Texture> loadBitmapTexture(const std::string& path, const Vec2& uvScale) {
    return std::make_shared<BitmapTexture>(readRgbImage(path), uvScale);
}

std::shared_ptr<Texture> makeBitmapTexture(RgbImage image, const Vec2& uvScale) {
    return std::make_shared<BitmapTexture>(std::move(image), uvScale);
}

RgbImage readRgbImage(const std::string& path) {
    checkExrAttributeSizes(path);
    checkPngChunkSizes(path);
    CapturedStderr libraryMessages;
    auto input = OIIO::ImageInput::open(path);
    if (!input) throw InputError(path, 0, "cannot read image: " + imageReadFailure(OIIO::geterror(), libraryMessages));
    const OIIO::ImageSpec& spec = input->spec();
    // The size is the header's claim: a few bytes can announce 100000 x 100000
    // pixels, which would be allocated here before the read finds the data
    // missing. The buffer is also left uninitialised, so that a header that
    // lies within the bound costs address space, not memory.
    if (spec.width <= 0 || spec.height <= 0 || spec.depth != 1 || spec.nchannels <= 0)
        throw InputError(path, 0, "image has no pixels, no channels or more than two dimensions");
    const std::int64_t pixelCount = std::int64_t{spec.width} * spec.height;
    if (pixelCount > kMaxImagePixels)
        throw InputError(path, 0, "image of " + std::to_string(spec.width) + " x " + std::to_string(spec.height) +
                                      " pixels is over the limit of " + std::to_string(kMaxImagePixels) +
                                      " (16384 x 8192)");
    // Only red, green and blue (or grey) are used; alpha and further channels are not read.
    const int channels = spec.nchannels >= 3 ? 3 : 1;
    const std::unique_ptr<float[]> data(new float[static_cast<std::size_t>(pixelCount) * channels]);
    if (!input->read_image(0, 0, 0, channels, OIIO::TypeDesc::FLOAT, data.get())) {
        throw InputError(path, 0, "cannot decode image: " + imageReadFailure(input->geterror(), libraryMessages));
    }
    // 8/16-bit images are display-encoded unless they say otherwise; float formats are linear.
    const std::string colorSpace = spec.get_string_attribute("oiio:ColorSpace");
    const bool encoded = spec.format.basetype == OIIO::TypeDesc::UINT8 || spec.format.basetype == OIIO::TypeDesc::UINT16;
    const bool linearise = encoded && colorSpace != "Linear" && colorSpace != "linear";
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
