// Checks made before an image is decoded, shared by every reader of images
// (textures and environment maps, references, `fluxgraph compare`): a damaged
// file of a few bytes must cost one InputError line, never gigabytes. The image
// libraries trust the sizes a file states (OpenEXR's attribute sizes, libpng's
// chunk lengths, a header's width and height) and allocate them before they
// find the data missing.
#pragma once

#include <cstdint>
#include <string>

namespace fg {

// 16384 x 8192, the largest environment maps in common use.
inline constexpr std::int64_t kMaxImagePixels = std::int64_t{1} << 27;
// More than any renderer's AOV set; bounds a header's channel count.
inline constexpr int kMaxImageChannels = 1024;

// Walks an EXR header's attributes and a PNG's chunks (recognised by
// signature, whatever the file's name): each stated size must fit in the file.
void checkImageStructure(const std::string& path);

// The header's claims, checked before the pixels are allocated: a positive 2D
// size of at most kMaxImagePixels, at most kMaxImageChannels channels, and for
// the uncompressed formats (PFM, PNM) at least as many bytes as the samples need.
void checkImageHeader(const std::string& path, const std::string& formatName, int width, int height, int depth,
                      int channels);

}  // namespace fg
