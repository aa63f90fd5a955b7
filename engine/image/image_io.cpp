// Image files: float or half OpenEXR with extra AOV channels and string
// metadata through OpenEXR, and 8-bit sRGB PNG previews (sRGB transfer
// function of IEC 61966-2-1) through libpng; reading goes through
// image_file_input.h. Images are encoded in memory and written through
// output_files.h: to a checked temporary, renamed onto the final name only
// once every byte is known to be written.
#include "engine/image/image_io.h"

#include "engine/core/error.h"
#include "engine/image/image_diagnostics.h"
#include "engine/image/image_file_input.h"
#include "engine/image/image_guard.h"

#include <OpenEXR/ImfChannelList.h>
#include <OpenEXR/ImfCompressionAttribute.h>
#include <OpenEXR/ImfFrameBuffer.h>
#include <OpenEXR/ImfHeader.h>
#include <OpenEXR/ImfIO.h>
#include <OpenEXR/ImfOutputFile.h>
#include <OpenEXR/ImfStringAttribute.h>
#include <Imath/half.h>
#include <png.h>

#include <cmath>
#include <cstring>
#include <exception>
#include <filesystem>
#include <memory>
#include <stdexcept>
#include <string_view>
#include <system_error>

namespace fg {

namespace {

constexpr std::string_view kMetadataPrefix = "fluxgraph:";

void validateImage(const ImageChannels& image) {
    if (image.width <= 0 || image.height <= 0) throw std::invalid_argument("image: width and height must be positive");
    const std::size_t pixels = static_cast<std::size_t>(image.width) * static_cast<std::size_t>(image.height);
    if (image.rgb.size() != pixels) throw std::invalid_argument("image: expected one RGB value per pixel");
    for (std::size_t i = 0; i < image.extra.size(); ++i) {
        const std::string& name = image.extra[i].first;
        if (image.extra[i].second.size() != pixels)
            throw std::invalid_argument("image: channel '" + name + "' needs one value per pixel");
        if (name.empty() || name == "R" || name == "G" || name == "B")
            throw std::invalid_argument("image: invalid extra channel name '" + name + "'");
        for (std::size_t j = 0; j < i; ++j)
            if (image.extra[j].first == name) throw std::invalid_argument("image: duplicate channel '" + name + "'");
    }
}

// OpenEXR writes through a stream; this one keeps the bytes in memory, so
// that writeFileChecked can write them and check every write.
class MemoryExrStream final : public Imf::OStream {
public:
    explicit MemoryExrStream(std::vector<unsigned char>& bytes) : Imf::OStream("memory"), bytes_(bytes) {}

    void write(const char data[], int count) override {
        const std::size_t end = position_ + static_cast<std::size_t>(count);
        if (end > bytes_.size()) bytes_.resize(end);
        std::memcpy(bytes_.data() + position_, data, static_cast<std::size_t>(count));
        position_ = end;
    }
    uint64_t tellp() override { return position_; }
    void seekp(uint64_t position) override { position_ = static_cast<std::size_t>(position); }

private:
    std::vector<unsigned char>& bytes_;
    std::size_t position_ = 0;
};

float srgbEncode(float linear) {
    if (!(linear > 0.0f)) return 0.0f;  // also maps NaN to black
    if (linear >= 1.0f) return 1.0f;
    return linear <= 0.0031308f ? 12.92f * linear : 1.055f * std::pow(linear, 1.0f / 2.4f) - 0.055f;
}

}  // namespace

std::vector<unsigned char> encodeExr(const std::string& path, const ImageChannels& image, const Metadata& metadata,
                                     bool halfFloat) {
    validateImage(image);
    Imf::Header header(image.width, image.height);
    header.compression() = Imf::ZIP_COMPRESSION;
    // Only the colour drops to half: AOVs such as time_ns exceed half's range (65504).
    const Imf::PixelType colourType = halfFloat ? Imf::HALF : Imf::FLOAT;
    for (const char* name : {"R", "G", "B"}) header.channels().insert(name, Imf::Channel(colourType));
    for (const auto& [name, values] : image.extra) header.channels().insert(name, Imf::Channel(Imf::FLOAT));
    for (const auto& [key, value] : metadata)
        header.insert(std::string(kMetadataPrefix) + key, Imf::StringAttribute(value));

    // OpenEXR converts pixel types when it reads, not when it writes: half
    // colour is rounded here (to nearest even, as Imath does).
    const std::size_t width = static_cast<std::size_t>(image.width);
    Imf::FrameBuffer frame;
    std::vector<half> halfRgb;
    if (halfFloat) {
        halfRgb.reserve(image.rgb.size() * 3);
        for (const Rgb& pixel : image.rgb)
            for (int c = 0; c < 3; ++c) halfRgb.emplace_back(pixel[c]);
    }
    static_assert(sizeof(Rgb) == 3 * sizeof(float));
    for (int c = 0; c < 3; ++c) {
        const char* name = c == 0 ? "R" : c == 1 ? "G" : "B";
        if (halfFloat)
            frame.insert(name, Imf::Slice(Imf::HALF, reinterpret_cast<char*>(halfRgb.data() + c), 3 * sizeof(half),
                                          3 * sizeof(half) * width));
        else
            frame.insert(name, Imf::Slice(Imf::FLOAT, reinterpret_cast<char*>(const_cast<float*>(&image.rgb[0][c])),
                                          sizeof(Rgb), sizeof(Rgb) * width));
    }
    for (const auto& [name, values] : image.extra)
        frame.insert(name, Imf::Slice(Imf::FLOAT, reinterpret_cast<char*>(const_cast<float*>(values.data())),
                                      sizeof(float), sizeof(float) * width));
    std::vector<unsigned char> encoded;
    try {
        MemoryExrStream stream(encoded);
        Imf::OutputFile output(stream, header);
        output.setFrameBuffer(frame);
        output.writePixels(image.height);
    } catch (const std::exception& failure) {
        throw InputError(path, 0, std::string("cannot write image: ") + failure.what());
    }
    return encoded;
}

void writeExr(const std::string& path, const ImageChannels& image, const Metadata& metadata, bool halfFloat) {
    const std::vector<unsigned char> encoded = encodeExr(path, image, metadata, halfFloat);
    writeAtomically(path, [&](const std::string& temporary) {
        writeFileChecked(path, temporary, std::string_view(reinterpret_cast<const char*>(encoded.data()), encoded.size()));
    });
}

std::vector<unsigned char> encodePngPreview(const std::string& path, const ImageChannels& image, float exposureStops) {
    validateImage(image);
    const float scale = std::exp2(exposureStops);
    std::vector<unsigned char> bytes(image.rgb.size() * 3);
    for (std::size_t p = 0; p < image.rgb.size(); ++p) {
        for (int c = 0; c < 3; ++c) {
            const float encoded = srgbEncode(image.rgb[p][c] * scale);
            bytes[p * 3 + static_cast<std::size_t>(c)] = static_cast<unsigned char>(std::lround(encoded * 255.0f));
        }
    }
    png_image png{};
    png.version = PNG_IMAGE_VERSION;
    png.width = static_cast<png_uint_32>(image.width);
    png.height = static_cast<png_uint_32>(image.height);
    // 8-bit values without PNG_FORMAT_FLAG_LINEAR: libpng marks the file sRGB.
    png.format = PNG_FORMAT_RGB;
    std::vector<unsigned char> encoded(PNG_IMAGE_PNG_SIZE_MAX(png));
    png_alloc_size_t size = encoded.size();
    if (png_image_write_to_memory(&png, encoded.data(), &size, 0, bytes.data(), 0, nullptr)) {
        encoded.resize(size);
        return encoded;
    }
    const std::string reason = png.message;
    png_image_free(&png);
    throw InputError(path, 0, "cannot write image: " + reason);
}

void writePngPreview(const std::string& path, const ImageChannels& image, float exposureStops) {
    const std::vector<unsigned char> encoded = encodePngPreview(path, image, exposureStops);
    writeAtomically(path, [&](const std::string& temporary) {
        writeFileChecked(path, temporary, std::string_view(reinterpret_cast<const char*>(encoded.data()), encoded.size()));
    });
}

ImageChannels readExr(const std::string& path, Metadata* metadata) {
    checkImageStructure(path);
    CapturedStderr libraryMessages;
    std::string openError;
    std::unique_ptr<ImageFileInput> input = openImageFile(path, openError);
    if (!input) throw InputError(path, 0, "cannot read image: " + imageReadFailure(openError, libraryMessages));
    const ImageFileSpec& spec = input->spec();
    checkImageHeader(path, spec.formatName, spec.width, spec.height, spec.depth, spec.channels());
    const int channels = spec.channels();
    ImageChannels image;
    image.width = spec.width;
    image.height = spec.height;
    const std::size_t pixels = static_cast<std::size_t>(spec.width) * static_cast<std::size_t>(spec.height);

    std::vector<float> interleaved(pixels * static_cast<std::size_t>(channels));
    if (!input->readPixels(channels, interleaved.data()))
        throw InputError(path, 0, "cannot read image: " + imageReadFailure(input->error(), libraryMessages));

    int rgbChannel[3] = {-1, -1, -1};
    const char* rgbNames[3] = {"R", "G", "B"};
    for (int c = 0; c < channels; ++c) {
        const std::string& name = spec.channelNames[static_cast<std::size_t>(c)];
        bool isRgb = false;
        for (int k = 0; k < 3; ++k) {
            if (name == rgbNames[k]) {
                rgbChannel[k] = c;
                isRgb = true;
            }
        }
        if (!isRgb) image.extra.emplace_back(name, std::vector<float>(pixels));
    }
    for (int k = 0; k < 3; ++k)
        if (rgbChannel[k] < 0) throw InputError(path, 0, std::string("image has no channel ") + rgbNames[k]);

    image.rgb.resize(pixels);
    for (std::size_t p = 0; p < pixels; ++p) {
        const float* in = &interleaved[p * static_cast<std::size_t>(channels)];
        image.rgb[p] = Rgb(in[rgbChannel[0]], in[rgbChannel[1]], in[rgbChannel[2]]);
        std::size_t extraIndex = 0;
        for (int c = 0; c < channels; ++c) {
            if (c == rgbChannel[0] || c == rgbChannel[1] || c == rgbChannel[2]) continue;
            image.extra[extraIndex++].second[p] = in[c];
        }
    }

    if (metadata) {
        metadata->clear();
        for (auto& [name, value] : input->stringAttributes(std::string(kMetadataPrefix)))
            metadata->emplace_back(name.substr(kMetadataPrefix.size()), std::move(value));
    }
    return image;
}

}  // namespace fg
