#include "engine/image/image_guard.h"

#include "engine/core/error.h"

#include <cstring>
#include <filesystem>
#include <fstream>
#include <string_view>

namespace fg {

namespace {

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

void checkImageStructure(const std::string& path) {
    checkExrAttributeSizes(path);
    checkPngChunkSizes(path);
}

void checkImageHeader(const std::string& path, const std::string& formatName, int width, int height, int depth,
                      int channels) {
    if (width <= 0 || height <= 0 || depth != 1 || channels <= 0)
        throw InputError(path, 0, "image has no pixels, no channels or more than two dimensions");
    const std::int64_t pixelCount = std::int64_t{width} * height;
    if (pixelCount > kMaxImagePixels)
        throw InputError(path, 0, "image of " + std::to_string(width) + " x " + std::to_string(height) +
                                      " pixels is over the limit of " + std::to_string(kMaxImagePixels) +
                                      " (16384 x 8192)");
    if (channels > kMaxImageChannels)
        throw InputError(path, 0, "image claims " + std::to_string(channels) + " channels, more than the limit of " +
                                      std::to_string(kMaxImageChannels));
    // Uncompressed formats store every sample: a header that claims more
    // pixels than the file holds made OpenImageIO's PFM reader grow past 2 GB
    // before failing. PFM stores 4 bytes a sample; PNM at least one.
    const std::uint64_t bytesPerSample = formatName == "pfm" ? 4 : formatName == "pnm" ? 1 : 0;
    if (bytesPerSample == 0) return;
    std::error_code error;
    const std::uintmax_t fileBytes = std::filesystem::file_size(path, error);
    const std::uint64_t dataBytes =
        static_cast<std::uint64_t>(pixelCount) * static_cast<std::uint64_t>(channels) * bytesPerSample;
    if (!error && fileBytes < dataBytes)
        throw InputError(path, 0, "image of " + std::to_string(width) + " x " + std::to_string(height) +
                                      " pixels needs " + std::to_string(dataBytes) + " bytes of data, the file has " +
                                      std::to_string(fileBytes));
}

}  // namespace fg
