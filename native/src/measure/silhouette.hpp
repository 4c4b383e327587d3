// Silhouette extraction: from a clean silhouette or a raw top-down photo of a Cusick drape to a binary
// mask (1 = cloth) of the specimen's shadow, plus the calibration it is measured with.
//
// Steps (each documented at its option):
//  1. cloth value s in [0, 1] (1 = cloth) from the luminance L: s = 1 - L for dark cloth on a light table
//     (the dataset's s = 1 - mean(R,G,B)/255), s = L for light cloth on a dark table; the polarity is
//     detected from the image border (background) unless given.
//  2. threshold: fixed, or automatic: Otsu's threshold refined by the Ridler-Calvard (ISODATA) iteration
//     t = (mean(s | s <= t) + mean(s | s > t)) / 2. On a clean 0/1 silhouette this lands at the midpoint
//     of the two tones (0.5 for the dataset), the README's threshold.
//  3. the specimen's connected region (8-connected) is kept: the one containing the calibrated centre,
//     else the one with most pixels inside the support disk; specks (all other regions) are removed.
//  4. holes (4-connected background regions not reaching the image border) smaller than
//     max_hole_fraction of the kept region are filled.
#pragma once
#include <string>

#include "geometry/cusick.hpp"
#include "measure/calibration.hpp"
#include "util/image.hpp"

namespace drapelab {

enum class Polarity { Auto, DarkOnLight, LightOnDark };

struct SilhouetteOptions {
  double threshold = -1.0;            // on s, in (0, 1); negative = automatic (Otsu + ISODATA)
  Polarity polarity = Polarity::Auto;
  bool keep_central_region = true;    // false: keep every region (no speck removal)
  double max_hole_fraction = 0.05;    // holes up to this fraction of the region's area are filled; 0 = none
  // Images whose luminance spread (99.9th minus 0.1th percentile) is below this have no silhouette.
  double min_contrast = 0.1;
  CusickGeometry geometry;            // support-disk radius: where the specimen region must be
};

struct Silhouette {
  Image mask;               // binary: 1 = cloth, 0 = background
  Image cloth_value;        // s in [0, 1] before thresholding (1 = cloth)
  double threshold = 0.5;   // on s
  bool dark_on_light = true;
  Calibration calibration;  // resolved (centre filled in)
  long specks_removed_px = 0;
  long holes_filled_px = 0;
  std::string source;       // file name or a caller-given label, used in error messages

  long area_px() const { return static_cast<long>(mask.sum()); }
};

// Extracts the silhouette from a luminance image in [0, 1]. Throws InputError naming `source` for an
// image without contrast (all black, all white), without foreground, or without a region at the centre.
Silhouette extract_silhouette(const Image& luminance, const Calibration& calibration = {},
                              const SilhouetteOptions& options = {}, const std::string& source = "image");

// read_luminance(path) then extract_silhouette (errors name the file).
Silhouette load_silhouette(const std::string& path, const Calibration& calibration = {},
                           const SilhouetteOptions& options = {});

// Automatic threshold of values in [0, 1] (Otsu on a 256-bin histogram, refined by ISODATA).
double automatic_threshold(const Image& values);

}  // namespace drapelab
