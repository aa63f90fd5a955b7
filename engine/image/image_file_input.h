// One way of reading every image file format, whichever library decodes it:
// EXR through OpenEXR (linked in), every other format through OpenImageIO in
// a module that is loaded only when such a file is read (image_file_input.cpp
// says why). Callers check the header (image_guard.h) before they allocate
// the pixels; the interface is header-only so that the module needs nothing
// from the program.
#pragma once

#include <memory>
#include <string>
#include <utility>
#include <vector>

namespace fg {

enum class SampleType {
    Float,         // half, float or double: linear values
    UInt8,         // 8/16-bit integers, scaled to [0, 1]; display-encoded unless the file says otherwise
    UInt16,
    OtherInteger,  // 32-bit or signed integers, scaled to [0, 1]
};

struct ImageFileSpec {
    std::string formatName;  // OpenImageIO's names: "openexr", "png", "pfm", "pnm", ...
    int width = 0;
    int height = 0;
    int depth = 1;
    std::vector<std::string> channelNames;  // R, G, B, A first, as OpenImageIO orders them
    SampleType sampleType = SampleType::Float;
    std::string colorSpace;  // as the file states it ("sRGB", "Linear", ...), empty if it does not
    int channels() const { return static_cast<int>(channelNames.size()); }
};

class ImageFileInput {
public:
    virtual ~ImageFileInput() = default;
    virtual const ImageFileSpec& spec() const = 0;
    // The first `channels` channels of every pixel, interleaved, top row first.
    // False on failure, with error() saying why.
    virtual bool readPixels(int channels, float* pixels) = 0;
    virtual std::string error() = 0;
    // String attributes whose names start with `prefix`, the prefix kept.
    virtual std::vector<std::pair<std::string, std::string>> stringAttributes(const std::string& prefix) = 0;
};

// Opens `path` (the format recognised by its first bytes, as OpenImageIO
// does); nullptr with `error` set when it cannot be opened. The image guards
// are the caller's: checkImageStructure before, checkImageHeader after.
std::unique_ptr<ImageFileInput> openImageFile(const std::string& path, std::string& error);

// The module's one entry point (extern "C", looked up by name): opens `path`
// with OpenImageIO; nullptr with *error set on failure.
using OpenImageWithOiio = ImageFileInput* (*)(const char* path, std::string* error);
inline constexpr const char* kOpenImageWithOiioSymbol = "fluxgraph_open_image_with_oiio";

}  // namespace fg
