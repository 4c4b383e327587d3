#include "measure/calibration.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "measure/metrics.hpp"
#include "render/camera.hpp"
#include "render/rasterizer.hpp"
#include "util/error.hpp"

namespace drapelab {

namespace {

constexpr double kPi = 3.14159265358979323846;

std::string fmt(double v, int digits = 1) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.*f", digits, v);
  return buf;
}

struct MaskMoments {
  double area = 0;          // px
  double col = 0, row = 0;  // centroid, continuous coordinates
};

MaskMoments moments(const Image& mask) {
  MaskMoments m;
  for (Eigen::Index r = 0; r < mask.rows(); ++r)
    for (Eigen::Index c = 0; c < mask.cols(); ++c)
      if (mask(r, c) > 0.5) {
        m.area += 1;
        m.col += static_cast<double>(c) + 0.5;
        m.row += static_cast<double>(r) + 0.5;
      }
  if (m.area > 0) m.col /= m.area, m.row /= m.area;
  return m;
}

}  // namespace

void validate_calibration(const Calibration& calibration, int width, int height, const std::string& source) {
  if (!std::isfinite(calibration.px_per_m) || calibration.px_per_m <= 0)
    throw InputError(source + ": wrong calibration: px_per_m must be a positive number, got " +
                     fmt(calibration.px_per_m, 3));
  if (!calibration.has_centre() || calibration.cx < 0 || calibration.cy < 0 || calibration.cx > width ||
      calibration.cy > height)
    throw InputError(source + ": wrong calibration: the centre (" + fmt(calibration.cx) + ", " +
                     fmt(calibration.cy) + ") lies outside the " + std::to_string(width) + "x" +
                     std::to_string(height) + " image");
}

Calibration resolve_calibration(const Calibration& calibration, int width, int height, const std::string& source) {
  Calibration out = calibration;
  if (!std::isfinite(out.cx)) out.cx = 0.5 * width;
  if (!std::isfinite(out.cy)) out.cy = 0.5 * height;
  validate_calibration(out, width, height, source);
  return out;
}

void check_cusick_calibration(const Image& mask, const Calibration& calibration, const std::string& source,
                              const CusickGeometry& geometry, double min_slack, double radius_slack) {
  const Calibration cal = resolve_calibration(calibration, static_cast<int>(mask.cols()),
                                              static_cast<int>(mask.rows()), source);
  const double dc = drape_coefficient(mask, cal.px_per_m, geometry);
  const std::string at = " at " + fmt(cal.px_per_m) + " px/m";
  if (dc < -min_slack)
    throw InputError(source + ": wrong calibration: the shadow (" + fmt(shadow_area(mask, cal.px_per_m) * 1e4, 1) +
                     " cm^2" + at + ") is smaller than the support disk (" +
                     fmt(kPi * geometry.support_radius * geometry.support_radius * 1e4, 1) +
                     " cm^2), drape coefficient " + fmt(dc, 3) + "; check the scale (--px-per-m)");
  if (dc > 1 + min_slack)
    throw InputError(source + ": wrong calibration: the shadow (" + fmt(shadow_area(mask, cal.px_per_m) * 1e4, 1) +
                     " cm^2" + at + ") is larger than the flat specimen (" +
                     fmt(kPi * geometry.specimen_radius * geometry.specimen_radius * 1e4, 1) +
                     " cm^2), drape coefficient " + fmt(dc, 3) + "; check the scale (--px-per-m)");
  const double r_max = radius_angle_curve(mask, cal).maxCoeff();
  if (r_max > (1 + radius_slack) * geometry.specimen_radius)
    throw InputError(source + ": wrong calibration: the silhouette reaches " + fmt(r_max * 100, 1) +
                     " cm from the centre (" + fmt(cal.cx) + ", " + fmt(cal.cy) + ")" + at +
                     ", beyond the specimen radius " + fmt(geometry.specimen_radius * 100, 1) +
                     " cm; check the scale and the centre");
}

Calibration calibrate_from_disk(const Image& mask, double diameter_m, const std::string& source,
                                double max_roundness_error) {
  if (!(diameter_m > 0) || !std::isfinite(diameter_m))
    throw InputError(source + ": calibration: the specimen diameter must be positive, got " + fmt(diameter_m, 4));
  const MaskMoments m = moments(mask);
  if (m.area < 10)
    throw InputError(source + ": calibration: no undraped specimen in the image (" + fmt(m.area, 0) + " pixels)");
  const double radius = std::sqrt(m.area / kPi);
  double farthest = 0;
  for (Eigen::Index r = 0; r < mask.rows(); ++r)
    for (Eigen::Index c = 0; c < mask.cols(); ++c)
      if (mask(r, c) > 0.5)
        farthest = std::max(farthest, std::hypot(static_cast<double>(c) + 0.5 - m.col, static_cast<double>(r) + 0.5 - m.row));
  // Pixel centres reach about half a pixel less than the boundary.
  const double roundness = std::abs(farthest + 0.5 - radius) / radius;
  if (roundness > max_roundness_error)
    throw InputError(source + ": calibration: the specimen is not a flat disk (farthest pixel " + fmt(farthest) +
                     " px from its centroid, equivalent radius " + fmt(radius) +
                     " px); use an image of the undraped specimen");
  Calibration cal;
  cal.px_per_m = 2.0 * radius / diameter_m;
  cal.cx = m.col;
  cal.cy = m.row;
  validate_calibration(cal, static_cast<int>(mask.cols()), static_cast<int>(mask.rows()), source);
  return cal;
}

MeshCalibrationFit calibrate_from_mesh(const Image& mask, const MatrixX3d& positions, const MatrixX3i& faces,
                                       const std::string& source) {
  const int w = static_cast<int>(mask.cols()), h = static_cast<int>(mask.rows());
  const MaskMoments m = moments(mask);
  if (m.area < 10) throw InputError(source + ": calibration: the silhouette is empty");
  if (positions.rows() == 0 || faces.rows() == 0 || !positions.allFinite())
    throw InputError(source + ": calibration: the reference mesh is empty or has non-finite positions");
  // Moment matching on a reference rendering that holds the whole mesh.
  constexpr int kReference = 512;
  const double extent = positions.leftCols<2>().cwiseAbs().maxCoeff();
  if (!(extent > 0)) throw InputError(source + ": calibration: the reference mesh has no extent in x, y");
  const double s0 = 0.45 * kReference / extent;
  const OrthographicCamera reference(s0, 0.5 * kReference, 0.5 * kReference, kReference, kReference);
  const MaskMoments mm = moments(hard_silhouette(reference, positions, faces));
  if (mm.area < 10) throw InputError(source + ": calibration: the reference mesh casts no shadow from above");
  const double area_m2 = mm.area / (s0 * s0);
  const double x_bar = (mm.col - 0.5 * kReference) / s0, y_bar = (0.5 * kReference - mm.row) / s0;

  MeshCalibrationFit fit;
  Calibration& cal = fit.calibration;
  cal.px_per_m = std::sqrt(m.area / area_m2);
  cal.cx = m.col - cal.px_per_m * x_bar;
  cal.cy = m.row + cal.px_per_m * y_bar;
  auto score = [&](const Calibration& c) {
    return iou(hard_silhouette(OrthographicCamera(c.px_per_m, c.cx, c.cy, w, h), positions, faces), mask);
  };
  fit.iou = score(cal);
  // Coordinate search: scale in relative steps, centre in pixels; halve the steps when nothing improves.
  double ds = 0.02, dc = 2.0;
  for (int round = 0; round < 200 && (ds > 1e-4 || dc > 0.05); ++round) {
    bool improved = false;
    for (int axis = 0; axis < 3; ++axis)
      for (int sign : {1, -1}) {
        Calibration t = cal;
        if (axis == 0) t.px_per_m *= 1 + sign * ds;
        if (axis == 1) t.cx += sign * dc;
        if (axis == 2) t.cy += sign * dc;
        const double v = score(t);
        if (v > fit.iou + 1e-12) {
          fit.iou = v;
          cal = t;
          improved = true;
        }
      }
    if (!improved) ds *= 0.5, dc *= 0.5;
  }
  validate_calibration(cal, w, h, source);
  return fit;
}

}  // namespace drapelab
