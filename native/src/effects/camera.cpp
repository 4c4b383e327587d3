// Effect "camera": the measurement model itself, as a transform of positions before the silhouette render
// (Model::observe). The images' calibration maps the support's plane (z = 0, the flat specimen's height) to
// pixels at P = ModelOptions::px_per_m; this effect says how the real camera differs from it:
//   scale_error s [1]: pixels per metre off by 1 + s;
//   cx_px, cy_px [px]: the tester's centre appears cx_px columns right of and cy_px rows below the calibrated
//     centre;
//   inv_distance_per_m k [1/m]: perspective, the camera at height 1/k above the support's plane looking down
//     (0 = orthographic): a point at height z appears scaled by 1 / (1 - k z) about the optical axis, so the
//     support's plane keeps its calibrated scale and the hanging skirt (z < 0) looks smaller.
// For each vertex (metres, the tester's frame):
//   m = (1 + s) / (1 - k z),  y = (m x + cx_px / P,  m y - cy_px / P,  z)
// which the calibrated renderer then maps to pixels. At the off values (all 0) y = x bit for bit. It adds no
// term: the drape is the same, only its measurement changes.
#include <cmath>
#include <sstream>

#include "physics/effect.hpp"
#include "physics/model.hpp"
#include "util/error.hpp"

namespace drapelab {
namespace {

constexpr double kMinDepthFactor = 0.05;  // 1 - k z must stay above this: a vertex near the camera is an error

class CameraObservation : public PositionTransform {
 public:
  explicit CameraObservation(const EffectContext& c)
      : s_(c.layout.block(effect_block_name("camera", "scale_error")).offset),
        cx_(c.layout.block(effect_block_name("camera", "cx_px")).offset),
        cy_(c.layout.block(effect_block_name("camera", "cy_px")).offset),
        k_(c.layout.block(effect_block_name("camera", "inv_distance_per_m")).offset),
        px_per_m_(c.options.px_per_m) {
    if (!(px_per_m_ > 0) || !std::isfinite(px_per_m_))
      throw InputError("camera: px_per_m (the images' calibration) must be > 0");
  }

  void apply(const Eigen::VectorXd& x, const Eigen::VectorXd& p, Eigen::VectorXd& y) const override {
    y = x;
    const double s = p[s_], k = p[k_], ox = p[cx_] / px_per_m_, oy = -p[cy_] / px_per_m_;
    if (s == 0 && k == 0 && ox == 0 && oy == 0) return;  // the identity, bit for bit
    for (Eigen::Index i = 0; i < x.size(); i += 3) {
      const double m = (1.0 + s) / depth(x[i + 2], k);
      y[i] = m * x[i] + ox;
      y[i + 1] = m * x[i + 1] + oy;
    }
  }

  void add_vjp(const Eigen::VectorXd& x, const Eigen::VectorXd& p, const Eigen::VectorXd& gy, Eigen::VectorXd& gx,
               Eigen::VectorXd& gp) const override {
    const double s = p[s_], k = p[k_];
    double gs = 0, gk = 0, gcx = 0, gcy = 0;
    for (Eigen::Index i = 0; i < x.size(); i += 3) {
      const double z = x[i + 2], q = depth(z, k), m = (1.0 + s) / q;
      const double a = gy[i] * x[i] + gy[i + 1] * x[i + 1];  // g_y . d y / d m
      gx[i] += m * gy[i];
      gx[i + 1] += m * gy[i + 1];
      gx[i + 2] += gy[i + 2] + a * (1.0 + s) * k / (q * q);  // dm/dz = (1 + s) k / q^2
      gs += a / q;                                            // dm/ds = 1 / q
      gk += a * (1.0 + s) * z / (q * q);                      // dm/dk = (1 + s) z / q^2
      gcx += gy[i];
      gcy += gy[i + 1];
    }
    gp[s_] += gs;
    gp[k_] += gk;
    gp[cx_] += gcx / px_per_m_;
    gp[cy_] -= gcy / px_per_m_;
  }

 private:
  static double depth(double z, double k) {
    const double q = 1.0 - k * z;
    if (!(q > kMinDepthFactor)) {
      std::ostringstream m;
      m << "camera: a vertex at z = " << z << " m is at or above the camera (inv_distance_per_m = " << k << ")";
      throw InputError(m.str());
    }
    return q;
  }
  int s_, cx_, cy_, k_;
  double px_per_m_;
};

}  // namespace

EffectSpec make_camera_effect() {
  EffectSpec s;
  s.name = "camera";
  s.explanation = "the measurement model: scale error, centre offset (px) and perspective (inverse distance)";
  s.signature =
      "the silhouette scaled about (or shifted from) the tester's centre (scale and perspective move DC); the "
      "drape itself does not change";
  s.parameters = {
      // Moderate strengths measured on circle3 (tools/observation_effects_probe.py, docs/lab/effect-recovery.md):
      // scale_error 0.02 / 0.03: DC +0.048 / +0.072 (2.3x the 0.031 floor), MSE 0.017 / 0.026; cx_px 3 / 5: DC 0,
      // MSE 0.018 / 0.031 (4 px: about scale_error's 0.026); inv_distance_per_m 0.5 / 1: DC -0.050 / -0.096.
      {"scale_error", "1", 0.0, -0.3, 0.3, 0.03, 0.03, "pixels per metre off by 1 + scale_error (fraction)"},
      {"cx_px", "px", 0.0, -40.0, 40.0, 4.0, 4.0, "tester's centre right of the calibrated centre (columns)"},
      {"cy_px", "px", 0.0, -40.0, 40.0, 4.0, 4.0, "tester's centre below the calibrated centre (rows)"},
      // One-sided: 0 is orthographic, 3 /m a camera 33 cm above the support.
      {"inv_distance_per_m", "1/m", 0.0, 0.0, 3.0, 1.0, 0.75, "perspective: 1 / camera height above the support"},
  };
  s.make_terms = [](const EffectContext&) { return std::vector<std::unique_ptr<Term>>{}; };  // no physics
  s.make_observation = [](const EffectContext& c) -> std::unique_ptr<PositionTransform> {
    return std::make_unique<CameraObservation>(c);
  };
  return s;
}

}  // namespace drapelab
