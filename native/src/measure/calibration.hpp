// Calibration of a top-down Cusick image: how many pixels one metre on the table spans and where the
// support-disk centre lies in the image (an orthographic top view: no perspective, no rotation).
//
//   col = cx + px_per_m * x,   row = cy - px_per_m * y      (continuous image coordinates, x right, y up)
//
// The bundled dataset (../shared/data/cusick) is 720 px/m with the centre at the image centre (128, 128).
// A calibration is given (defaults, or a user's --px-per-m) or estimated: from an undraped specimen of
// known diameter, or by fitting a reference 3D mesh's orthographic shadow to its silhouette.
#pragma once
#include <cmath>
#include <limits>
#include <string>

#include "geometry/cusick.hpp"
#include "geometry/mesh.hpp"
#include "util/image.hpp"

namespace drapelab {

// Pixels per metre of the bundled Cusick dataset's orthographic top view.
inline constexpr double kDatasetPxPerM = 720.0;

struct Calibration {
  double px_per_m = kDatasetPxPerM;
  // Disk centre in continuous image coordinates (pixel (r, c) covers [c, c+1) x [r, r+1)).
  // NaN = the image centre (width / 2, height / 2), resolved by resolve_calibration().
  double cx = std::numeric_limits<double>::quiet_NaN();
  double cy = std::numeric_limits<double>::quiet_NaN();

  bool has_centre() const { return std::isfinite(cx) && std::isfinite(cy); }
};

// Fills a missing centre with the image centre and checks the result (see validate_calibration).
Calibration resolve_calibration(const Calibration& calibration, int width, int height,
                                const std::string& source);

// Throws InputError naming `source` unless px_per_m is finite and positive and the centre lies
// inside the image.
void validate_calibration(const Calibration& calibration, int width, int height, const std::string& source);

// Checks that a measured silhouette is plausible for a Cusick test under `calibration`: its drape
// coefficient must lie in [-min_slack, 1 + min_slack] and its far edge no further from the centre than
// (1 + radius_slack) * specimen_radius (the dataset reaches 1.046). Otherwise the scale (px/m) or the
// centre is wrong for this image. Throws InputError naming `source`.
void check_cusick_calibration(const Image& mask, const Calibration& calibration, const std::string& source,
                              const CusickGeometry& geometry = {}, double min_slack = 0.05,
                              double radius_slack = 0.10);

// Estimates the calibration from a binary mask (1 = cloth) of an undraped (flat) specimen of known
// diameter: px_per_m = 2 sqrt(area_px / pi) / diameter_m, centre = the mask's centroid. Throws
// InputError when the mask is empty or not disk-like (its farthest pixel from the centroid more than
// `max_roundness_error` (relative) away from the equivalent-disk radius).
Calibration calibrate_from_disk(const Image& mask, double diameter_m, const std::string& source,
                                double max_roundness_error = 0.1);

struct MeshCalibrationFit {
  Calibration calibration;
  double iou = 0.0;  // of the mesh's shadow under the fitted calibration with the mask
};

// Estimates the calibration from a binary mask (1 = cloth) and a reference 3D mesh of the same drape
// (metres, z up, support disk centred at the origin): the scale and centre are first taken from the
// shadow's area and centroid (moment matching, hard-rasterised orthographic shadow), then refined by a
// coordinate search maximising the IoU. Throws InputError when the mask is empty.
MeshCalibrationFit calibrate_from_mesh(const Image& mask, const MatrixX3d& positions, const MatrixX3i& faces,
                                       const std::string& source);

}  // namespace drapelab
