// Image import and export through OpenImageIO (JPEG, PNG, TIFF, EXR, BMP; 8/16-bit integer or float;
// grey, grey+alpha, RGB or RGBA).
//
// Import recognises the format by the file's leading bytes (never by its name) and only hands the five
// formats above to OpenImageIO: a user's file never reaches the decoders of other formats. Before anything
// is decoded, the size the header declares is checked against the caps below, so a small file declaring
// a huge image is refused without allocating it.
//
// Import reduces every image to one luminance channel L in [0, 1], the quantity the Cusick dataset's
// silhouette value is defined on (s = 1 - L for dark cloth on a light table):
//   L = mean(R, G, B)                       (grey: L = the grey value)
//   L = alpha L + (1 - alpha) * 1           (alpha, when present: composited over white, so a
//                                             transparent-background silhouette reads as dark-on-light)
// Integer pixels are scaled to [0, 1] by OpenImageIO (v / 255, v / 65535). Float pixels (EXR, float
// TIFF) are used as stored when they lie in [0, 1]; an HDR image with values above 1 is divided by its
// maximum; negative values are clamped to 0.
#pragma once
#include <cstddef>
#include <cstdint>
#include <string>

#include "util/image.hpp"

namespace drapelab {

// What the file held before reduction to luminance (for reports and error messages).
struct ImageFileInfo {
  int width = 0;
  int height = 0;
  int channels = 0;
  std::string pixel_type;  // OpenImageIO's name: "uint8", "uint16", "half", "float", ...
  std::string format;      // reader name: "jpeg", "png", "tiff", "openexr", ...
};

// Caps on an imported image, checked on the file's header before decoding. A Cusick photograph needs a
// few megapixels; the caps leave room for any camera while bounding the decoder's memory (about 1.5 GiB at
// the pixel cap: 4 float channels read plus the double luminance).
inline constexpr int64_t kMaxImageSide = 32768;                  // px, width or height
inline constexpr int64_t kMaxImagePixels = int64_t(1) << 26;     // width x height (64 Mpx, 8192 x 8192)
inline constexpr int64_t kMaxImageChannels = 16;                 // channels declared by the file
inline constexpr int64_t kMaxImageFileBytes = int64_t(1) << 30;  // 1 GiB

// Reads `path` as luminance in [0, 1] (see above). Throws InputError naming the file and the problem:
// missing, not a regular file, empty, unrecognised format, declared size beyond the caps, truncated or
// corrupt data, non-finite pixels.
Image read_luminance(const std::string& path, ImageFileInfo* info = nullptr);

// The same for an image file's bytes already in memory; `source` names them in error messages.
Image decode_luminance(const unsigned char* data, size_t size, const std::string& source,
                       ImageFileInfo* info = nullptr);

enum class PixelType { UInt8, UInt16, Float };

// Writes a single-channel image with values in [0, 1] (clamped) as `channels` = 1 (grey), 3 (RGB,
// replicated) or 4 (RGBA, alpha = 1), in the format implied by the file extension. The file is written
// to a temporary name and renamed into place. Throws InputError when the path cannot be written.
void write_image(const std::string& path, const Image& image, PixelType type = PixelType::UInt8,
                 int channels = 1);

}  // namespace drapelab
