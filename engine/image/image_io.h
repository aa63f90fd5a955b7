// Image output. Every file is written atomically: to a temporary name in the
// destination directory, then renamed, so an interrupted or failed run never
// leaves a truncated image under the final name.
#pragma once

#include "engine/core/math.h"
#include "engine/core/output_files.h"

#include <string>
#include <utility>
#include <vector>

namespace fg {

struct ImageChannels {
    int width = 0;
    int height = 0;
    std::vector<Rgb> rgb;  // row-major, top row first
    std::vector<std::pair<std::string, std::vector<float>>> extra;  // AOVs, one float per pixel
};

using Metadata = std::vector<std::pair<std::string, std::string>>;

// Float EXR (R, G, B + AOV channels), ZIP-compressed, with string metadata attributes
// (keys prefixed "fluxgraph:"). `halfFloat` stores 16-bit channels (references).
void writeExr(const std::string& path, const ImageChannels& image, const Metadata& metadata, bool halfFloat = false);
// 8-bit sRGB PNG preview: pixel * 2^exposure, clamped, sRGB-encoded.
void writePngPreview(const std::string& path, const ImageChannels& image, float exposureStops = 0.0f);
// Reads R, G, B and any other channels back; metadata strings with the "fluxgraph:" prefix stripped.
ImageChannels readExr(const std::string& path, Metadata* metadata = nullptr);

// The bytes writeExr and writePngPreview write, for callers that commit several
// outputs together (OutputCommit). `path` only names the file in errors.
std::vector<unsigned char> encodeExr(const std::string& path, const ImageChannels& image, const Metadata& metadata,
                                     bool halfFloat = false);
std::vector<unsigned char> encodePngPreview(const std::string& path, const ImageChannels& image,
                                            float exposureStops = 0.0f);

}  // namespace fg
