// Image import and export through OpenImageIO (JPEG, PNG, TIFF, EXR, ...; 8/16-bit integer or float;
// grey, grey+alpha, RGB or RGBA).
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

// Reads `path` as luminance in [0, 1] (see above). Throws InputError naming the file and the problem:
// missing, not a regular file, empty, unrecognised format, truncated or corrupt data, non-finite pixels.
Image read_luminance(const std::string& path, ImageFileInfo* info = nullptr);

enum class PixelType { UInt8, UInt16, Float };

// Writes a single-channel image with values in [0, 1] (clamped) as `channels` = 1 (grey), 3 (RGB,
// replicated) or 4 (RGBA, alpha = 1), in the format implied by the file extension. The file is written
// to a temporary name and renamed into place. Throws InputError when the path cannot be written.
void write_image(const std::string& path, const Image& image, PixelType type = PixelType::UInt8,
                 int channels = 1);

}  // namespace drapelab
