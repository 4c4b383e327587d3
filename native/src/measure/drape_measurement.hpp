// The rotation-free description of one drape silhouette: drape coefficient, r(theta), nodes, spectrum.
#pragma once
#include <Eigen/Core>

#include "geometry/cusick.hpp"
#include "measure/metrics.hpp"
#include "measure/silhouette.hpp"

namespace drapelab {

struct DrapeMeasurementOptions {
  int r_theta_samples = 360;  // angles of r(theta), 1 degree apart
  int harmonics = 20;         // a_0 .. a_19 of harmonic_spectrum
  NodeOptions nodes;
  CusickGeometry geometry;
};

struct DrapeMeasurement {
  double drape_coefficient = 0.0;  // unitless, see drape_coefficient()
  long area_px = 0;                // shadow area in pixels
  double px_per_m = 0.0;           // calibration used
  Eigen::Vector2d centre_px{0, 0}; // (col, row), continuous image coordinates
  Eigen::VectorXd r_theta_m;       // radius_angle_curve (m)
  Eigen::VectorXd harmonics_m;     // harmonic_spectrum (m)
  NodeAnalysis nodes;              // count, amplitude (m), angles
};

// Measures a binary mask (1 = cloth) under an orthographic calibration (centre resolved).
DrapeMeasurement measure_drape(const Image& mask, const Calibration& calibration,
                               const DrapeMeasurementOptions& options = {});
inline DrapeMeasurement measure_drape(const Silhouette& silhouette, const DrapeMeasurementOptions& options = {}) {
  return measure_drape(silhouette.mask, silhouette.calibration, options);
}

}  // namespace drapelab
