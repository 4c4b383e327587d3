#include "measure/drape_measurement.hpp"

namespace drapelab {

DrapeMeasurement measure_drape(const Image& mask, const Calibration& calibration,
                               const DrapeMeasurementOptions& options) {
  const Calibration cal = resolve_calibration(calibration, static_cast<int>(mask.cols()),
                                              static_cast<int>(mask.rows()), "measure_drape");
  DrapeMeasurement m;
  m.px_per_m = cal.px_per_m;
  m.centre_px = {cal.cx, cal.cy};
  m.area_px = static_cast<long>((mask > 0.5).count());
  m.drape_coefficient = drape_coefficient(mask, cal.px_per_m, options.geometry);
  m.r_theta_m = radius_angle_curve(mask, cal, options.r_theta_samples);
  m.harmonics_m = harmonic_spectrum(m.r_theta_m, options.harmonics);
  m.nodes = analyse_nodes(m.r_theta_m, options.nodes);
  return m;
}

}  // namespace drapelab
