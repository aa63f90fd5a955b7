// EXR files, the format of every render, reference and environment map in
// data/, are read through OpenEXR, which the program links anyway. Any other
// format goes through OpenImageIO, whose module (libfluxgraph_oiio.so) is
// loaded on the first such read: OpenImageIO links about 260 shared libraries
// (OpenVDB, GDAL, FFmpeg, ...) whose start-up alone took 135 MiB of resident
// memory, more than twice what a render of the Cornell box needs.
#include "engine/image/image_file_input.h"

#include <OpenEXR/ImfChannelList.h>
#include <OpenEXR/ImfFrameBuffer.h>
#include <OpenEXR/ImfHeader.h>
#include <OpenEXR/ImfInputFile.h>
#include <OpenEXR/ImfStdIO.h>
#include <OpenEXR/ImfStringAttribute.h>

#include <dlfcn.h>

#include <algorithm>
#include <cstdint>
#include <array>
#include <cstring>
#include <exception>
#include <filesystem>
#include <fstream>
#include <stdexcept>
#include <string>
#include <limits>
#include <utility>
#include <vector>

#ifndef FLUXGRAPH_OIIO_MODULE
#error "FLUXGRAPH_OIIO_MODULE must name the OpenImageIO module's path"
#endif

namespace fg {

namespace {

bool startsWithExrMagic(const std::string& path) {
    std::ifstream in(path, std::ios::binary);
    char magic[4] = {};
    return in.read(magic, sizeof magic) && std::memcmp(magic, "\x76\x2f\x31\x01", 4) == 0;
}

// OpenEXR sizes its decompression buffers from the header alone when it
// opens a file (a scanline block, 1 to 256 lines by compression, or a tile):
// a damaged header, a data window millions of pixels wide or thousands of
// channels, would allocate gigabytes before any pixel is read. So the header
// is read first, and a file whose block would exceed kMaxExrBlockBytes is
// refused. The bound holds legitimate files by far: a 16384-pixel-wide
// four-channel float image needs 256 KiB a line, 64 MiB a 256-line block.
constexpr std::int64_t kMaxExrBlockBytes = std::int64_t{256} << 20;

int exrLinesPerBlock(Imf::Compression compression) {
    switch (compression) {
        case Imf::NO_COMPRESSION:
        case Imf::RLE_COMPRESSION:
        case Imf::ZIPS_COMPRESSION: return 1;
        case Imf::ZIP_COMPRESSION:
        case Imf::PXR24_COMPRESSION: return 16;
        case Imf::PIZ_COMPRESSION:
        case Imf::B44_COMPRESSION:
        case Imf::B44A_COMPRESSION:
        case Imf::DWAA_COMPRESSION: return 32;
        default: return 256;  // DWAB, and any later method: the largest block
    }
}

void refuseOversizedExr(const std::string& path) {
    Imf::StdIFStream stream(path.c_str());
    char magicAndVersion[8] = {};
    stream.read(magicAndVersion, sizeof magicAndVersion);
    int version = 0;
    for (int b = 3; b >= 0; --b) version = (version << 8) | static_cast<unsigned char>(magicAndVersion[4 + b]);
    Imf::Header header;
    header.readFrom(stream, version);
    const Imath::Box2i window = header.dataWindow();
    const std::int64_t width = std::int64_t{window.max.x} - window.min.x + 1;
    std::int64_t bytesPerPixel = 0;
    std::int64_t channels = 0;
    for (auto channel = header.channels().begin(); channel != header.channels().end(); ++channel, ++channels)
        bytesPerPixel += channel.channel().type == Imf::HALF ? 2 : 4;
    const std::int64_t blockBytes =
        header.hasTileDescription()
            ? std::int64_t{header.tileDescription().xSize} * header.tileDescription().ySize * bytesPerPixel
            : std::max<std::int64_t>(width, 0) * bytesPerPixel * exrLinesPerBlock(header.compression());
    if (blockBytes > kMaxExrBlockBytes)
        throw std::runtime_error("an EXR block of " + std::to_string(blockBytes) + " bytes (" + std::to_string(width) +
                                 " pixels wide, " + std::to_string(channels) +
                                 " channels) is more than this reader allows (" +
                                 std::to_string(kMaxExrBlockBytes >> 20) + " MiB): a damaged header?");
}

// OpenEXR lists channels alphabetically; OpenImageIO, which read these files
// before, puts R, G, B and A first. Callers take the first three channels as
// the colour, so that order is kept.
int colourRank(const std::string& name) {
    static constexpr std::array<const char*, 4> kColourFirst = {"R", "G", "B", "A"};
    for (std::size_t i = 0; i < kColourFirst.size(); ++i)
        if (name == kColourFirst[i]) return static_cast<int>(i);
    return static_cast<int>(kColourFirst.size());
}

class ExrFileInput final : public ImageFileInput {
public:
    explicit ExrFileInput(const std::string& path) : file_(path.c_str()) {
        const Imf::Header& header = file_.header();
        const Imath::Box2i window = header.dataWindow();
        spec_.formatName = "openexr";
        // Computed in 64 bits: a damaged window must reach the guard as a bad size, not overflow.
        spec_.width = clampedExtent(std::int64_t{window.max.x} - window.min.x + 1);
        spec_.height = clampedExtent(std::int64_t{window.max.y} - window.min.y + 1);
        bool allUnsigned = true;
        for (auto channel = header.channels().begin(); channel != header.channels().end(); ++channel) {
            channels_.push_back({channel.name(), channel.channel()});
            allUnsigned = allUnsigned && channel.channel().type == Imf::UINT;
        }
        std::stable_sort(channels_.begin(), channels_.end(), [](const Channel& a, const Channel& b) {
            return colourRank(a.name) < colourRank(b.name);
        });
        for (const Channel& channel : channels_) spec_.channelNames.push_back(channel.name);
        spec_.sampleType = allUnsigned && !channels_.empty() ? SampleType::OtherInteger : SampleType::Float;
    }

    const ImageFileSpec& spec() const override { return spec_; }

    bool readPixels(int channelCount, float* pixels) override {
        try {
            const Imath::Box2i window = file_.header().dataWindow();
            const std::size_t xStride = sizeof(float) * static_cast<std::size_t>(channelCount);
            const std::size_t yStride = xStride * static_cast<std::size_t>(spec_.width);
            Imf::FrameBuffer frame;
            std::vector<std::vector<std::uint32_t>> unsignedRows;
            for (int c = 0; c < channelCount; ++c) {
                const Channel& channel = channels_[static_cast<std::size_t>(c)];
                if (channel.format.xSampling != 1 || channel.format.ySampling != 1) {
                    error_ = "channel " + channel.name + " is subsampled, which is not supported";
                    return false;
                }
                // OpenEXR converts half to float itself; unsigned integers are
                // read as such and scaled to [0, 1] below, as OpenImageIO did.
                const Imf::PixelType type = channel.format.type == Imf::UINT ? Imf::UINT : Imf::FLOAT;
                frame.insert(channel.name, Imf::Slice::Make(type, pixels + c, window, xStride, yStride));
            }
            file_.setFrameBuffer(frame);
            file_.readPixels(window.min.y, window.max.y);
            const std::size_t pixelCount = static_cast<std::size_t>(spec_.width) * static_cast<std::size_t>(spec_.height);
            for (int c = 0; c < channelCount; ++c) {
                if (channels_[static_cast<std::size_t>(c)].format.type != Imf::UINT) continue;
                for (std::size_t p = 0; p < pixelCount; ++p) {
                    float& sample = pixels[p * static_cast<std::size_t>(channelCount) + static_cast<std::size_t>(c)];
                    std::uint32_t stored;
                    std::memcpy(&stored, &sample, sizeof stored);
                    sample = static_cast<float>(stored) / static_cast<float>(std::numeric_limits<std::uint32_t>::max());
                }
            }
            return true;
        } catch (const std::exception& failure) {
            error_ = failure.what();
            return false;
        }
    }

    std::string error() override { return std::exchange(error_, {}); }

    std::vector<std::pair<std::string, std::string>> stringAttributes(const std::string& prefix) override {
        std::vector<std::pair<std::string, std::string>> found;
        const Imf::Header& header = file_.header();
        for (auto attribute = header.begin(); attribute != header.end(); ++attribute) {
            const std::string name = attribute.name();
            const auto* text = dynamic_cast<const Imf::StringAttribute*>(&attribute.attribute());
            if (text && name.rfind(prefix, 0) == 0) found.emplace_back(name, text->value());
        }
        return found;
    }

private:
    struct Channel {
        std::string name;
        Imf::Channel format;
    };

    static int clampedExtent(std::int64_t extent) {
        return static_cast<int>(std::clamp<std::int64_t>(extent, 0, std::numeric_limits<int>::max()));
    }

    Imf::InputFile file_;
    ImageFileSpec spec_;
    std::vector<Channel> channels_;
    std::string error_;
};

// Next to the program first (a build tree moved elsewhere), then where the
// build put it.
OpenImageWithOiio loadOiioModule(std::string& error) {
    static const auto loaded = [] {
        std::pair<OpenImageWithOiio, std::string> result{nullptr, {}};
        std::vector<std::string> candidates;
        std::error_code ec;
        const std::filesystem::path program = std::filesystem::read_symlink("/proc/self/exe", ec);
        const std::filesystem::path built(FLUXGRAPH_OIIO_MODULE);
        if (!ec) candidates.push_back((program.parent_path() / built.filename()).string());
        candidates.push_back(built.string());
        for (const std::string& candidate : candidates) {
            if (!std::filesystem::exists(candidate, ec)) continue;
            void* module = dlopen(candidate.c_str(), RTLD_NOW | RTLD_LOCAL);
            if (!module) {
                result.second = "cannot load " + candidate + ": " + dlerror();
                return result;
            }
            result.first = reinterpret_cast<OpenImageWithOiio>(dlsym(module, kOpenImageWithOiioSymbol));
            if (!result.first) result.second = candidate + " lacks " + kOpenImageWithOiioSymbol;
            return result;
        }
        result.second = "the OpenImageIO module " + built.string() + " is missing";
        return result;
    }();
    error = loaded.second;
    return loaded.first;
}

}  // namespace

std::unique_ptr<ImageFileInput> openImageFile(const std::string& path, std::string& error) {
    error.clear();
    if (startsWithExrMagic(path)) {
        try {
            refuseOversizedExr(path);
            return std::make_unique<ExrFileInput>(path);
        } catch (const std::exception& failure) {
            error = failure.what();
            return nullptr;
        }
    }
    const OpenImageWithOiio openWithOiio = loadOiioModule(error);
    if (!openWithOiio) return nullptr;
    return std::unique_ptr<ImageFileInput>(openWithOiio(path.c_str(), &error));
}

}  // namespace fg
