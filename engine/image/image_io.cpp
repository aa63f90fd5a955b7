// Image files through OpenImageIO: float or half OpenEXR with extra AOV
// channels and string metadata, and 8-bit sRGB PNG previews (sRGB transfer
// function of IEC 61966-2-1). Images are encoded in memory and written through
// output_files.h: to a checked temporary, renamed onto the final name only
// once every byte is known to be written.
#include "engine/image/image_io.h"

#include "engine/core/error.h"
#include "engine/image/image_diagnostics.h"
#include "engine/image/image_guard.h"

#include <OpenImageIO/filesystem.h>
#include <OpenImageIO/imageio.h>

#include <cmath>
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

// OpenImageIO's PNG writer ignores failed writes (a full disk gives a
// truncated file and a successful close), so the image is encoded into memory
// and its bytes written by writeFileChecked, which checks every write.
// `formatPath` picks the format by its extension and names the file in errors.
std::vector<unsigned char> encodeWithOiio(const std::string& formatPath, const OIIO::ImageSpec& spec,
                                          OIIO::TypeDesc bufferType, const void* pixels) {
    auto fail = [&](const std::string& reason) -> void {
        throw InputError(formatPath, 0, "cannot write image: " + reason);
    };
    std::vector<unsigned char> encoded;
    OIIO::Filesystem::IOVecOutput memory(encoded);
    std::unique_ptr<OIIO::ImageOutput> output = OIIO::ImageOutput::create(formatPath);
    if (!output) fail(OIIO::geterror());
    if (!output->supports("ioproxy")) fail("the " + std::string(output->format_name()) + " writer cannot write to memory");
    if (!output->set_ioproxy(&memory) || !output->open(formatPath, spec)) fail(output->geterror());
    if (!output->write_image(bufferType, pixels)) {
        const std::string reason = output->geterror();
        output->close();
        fail(reason);
    }
    if (!output->close()) fail(output->geterror());
    return encoded;
}

float srgbEncode(float linear) {
    if (!(linear > 0.0f)) return 0.0f;  // also maps NaN to black
    if (linear >= 1.0f) return 1.0f;
    return linear <= 0.0031308f ? 12.92f * linear : 1.055f * std::pow(linear, 1.0f / 2.4f) - 0.055f;
}

}  // namespace

std::vector<unsigned char> encodeExr(const std::string& path, const ImageChannels& image, const Metadata& metadata,
                                     bool halfFloat) {
    validateImage(image);
    const int channels = 3 + static_cast<int>(image.extra.size());
    OIIO::ImageSpec spec(image.width, image.height, channels, halfFloat ? OIIO::TypeDesc::HALF : OIIO::TypeDesc::FLOAT);
    spec.channelnames = {"R", "G", "B"};
    for (const auto& [name, values] : image.extra) spec.channelnames.push_back(name);
    if (halfFloat && !image.extra.empty()) {
        // Only the colour drops to half: AOVs such as time_ns exceed half's range (65504).
        spec.channelformats.assign(static_cast<std::size_t>(channels), OIIO::TypeDesc::FLOAT);
        for (int c = 0; c < 3; ++c) spec.channelformats[static_cast<std::size_t>(c)] = OIIO::TypeDesc::HALF;
    }
    spec.attribute("compression", "zip");
    for (const auto& [key, value] : metadata) spec.attribute(std::string(kMetadataPrefix) + key, value);

    const std::size_t pixels = image.rgb.size();
    std::vector<float> interleaved(pixels * static_cast<std::size_t>(channels));
    for (std::size_t p = 0; p < pixels; ++p) {
        float* out = &interleaved[p * static_cast<std::size_t>(channels)];
        out[0] = image.rgb[p].x;
        out[1] = image.rgb[p].y;
        out[2] = image.rgb[p].z;
        for (std::size_t c = 0; c < image.extra.size(); ++c) out[3 + c] = image.extra[c].second[p];
    }
    return encodeWithOiio(path, spec, OIIO::TypeDesc::FLOAT, interleaved.data());
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
    OIIO::ImageSpec spec(image.width, image.height, 3, OIIO::TypeDesc::UINT8);
    spec.attribute("oiio:ColorSpace", "sRGB");
    return encodeWithOiio(path, spec, OIIO::TypeDesc::UINT8, bytes.data());
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
    std::unique_ptr<OIIO::ImageInput> input = OIIO::ImageInput::open(path);
    if (!input) throw InputError(path, 0, "cannot read image: " + imageReadFailure(OIIO::geterror(), libraryMessages));
    const OIIO::ImageSpec& spec = input->spec();
    checkImageHeader(path, input->format_name(), spec.width, spec.height, spec.depth, spec.nchannels);
    const int channels = spec.nchannels;
    ImageChannels image;
    image.width = spec.width;
    image.height = spec.height;
    const std::size_t pixels = static_cast<std::size_t>(spec.width) * static_cast<std::size_t>(spec.height);

    std::vector<float> interleaved(pixels * static_cast<std::size_t>(channels));
    if (!input->read_image(0, 0, 0, channels, OIIO::TypeDesc::FLOAT, interleaved.data()))
        throw InputError(path, 0, "cannot read image: " + imageReadFailure(input->geterror(), libraryMessages));

    int rgbChannel[3] = {-1, -1, -1};
    const char* rgbNames[3] = {"R", "G", "B"};
    for (int c = 0; c < channels; ++c) {
        const std::string& name = spec.channelnames[static_cast<std::size_t>(c)];
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
        for (const OIIO::ParamValue& attribute : spec.extra_attribs) {
            const std::string name = attribute.name().string();
            if (attribute.type() != OIIO::TypeDesc::STRING || name.rfind(kMetadataPrefix, 0) != 0) continue;
            metadata->emplace_back(name.substr(kMetadataPrefix.size()), attribute.get_string());
        }
    }
    input->close();
    return image;
}

}  // namespace fg
