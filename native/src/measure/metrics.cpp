#include "measure/metrics.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>

#include "util/error.hpp"

namespace drapelab {

namespace {

constexpr double kPi = 3.14159265358979323846;

void check_same_shape(const Image& a, const Image& b, const char* what) {
  if (a.size() == 0 || b.size() == 0) throw InputError(std::string(what) + ": empty image");
  if (a.rows() != b.rows() || a.cols() != b.cols())
    throw InputError(std::string(what) + ": image shapes differ (" + std::to_string(a.rows()) + "x" +
                     std::to_string(a.cols()) + " vs " + std::to_string(b.rows()) + "x" +
                     std::to_string(b.cols()) + ")");
}

void check_curve(const Eigen::VectorXd& r, const char* what) {
  if (r.size() < 3) throw InputError(std::string(what) + ": r(theta) needs at least 3 samples");
  if (!r.allFinite()) throw InputError(std::string(what) + ": r(theta) has non-finite values");
}

Eigen::VectorXd circular_gaussian(const Eigen::VectorXd& r, double sigma_samples) {
  const int n = static_cast<int>(r.size());
  if (sigma_samples <= 1e-9) return r;
  const int half = std::min(n / 2, static_cast<int>(std::ceil(3.0 * sigma_samples)));
  Eigen::VectorXd w(2 * half + 1);
  for (int j = -half; j <= half; ++j) w[j + half] = std::exp(-0.5 * (j / sigma_samples) * (j / sigma_samples));
  w /= w.sum();
  Eigen::VectorXd out = Eigen::VectorXd::Zero(n);
  for (int i = 0; i < n; ++i)
    for (int j = -half; j <= half; ++j) out[i] += w[j + half] * r[((i + j) % n + n) % n];
  return out;
}

// ---- Hausdorff: uniform grid over primitives (triangles or points), exact nearest-distance queries.
struct Primitives {
  const MatrixX3d* positions;
  const MatrixX3i* faces;  // nullptr: the primitives are the vertices
  int count() const { return faces ? static_cast<int>(faces->rows()) : static_cast<int>(positions->rows()); }
  Eigen::Vector3d vertex(int i) const { return positions->row(i).transpose(); }
  void bounds(int i, Eigen::Vector3d& lo, Eigen::Vector3d& hi) const {
    if (!faces) {
      lo = hi = vertex(i);
      return;
    }
    lo = hi = vertex((*faces)(i, 0));
    for (int k = 1; k < 3; ++k) {
      lo = lo.cwiseMin(vertex((*faces)(i, k)));
      hi = hi.cwiseMax(vertex((*faces)(i, k)));
    }
  }
  double distance(int i, const Eigen::Vector3d& p) const {
    if (!faces) return (vertex(i) - p).norm();
    return point_triangle_distance(p, vertex((*faces)(i, 0)), vertex((*faces)(i, 1)), vertex((*faces)(i, 2)));
  }
};

class NearestGrid {
 public:
  explicit NearestGrid(const Primitives& prims) : prims_(prims) {
    const int n = prims.count();
    lo_ = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
    Eigen::Vector3d hi = -lo_;
    double size_sum = 0;
    for (int i = 0; i < n; ++i) {
      Eigen::Vector3d a, b;
      prims.bounds(i, a, b);
      lo_ = lo_.cwiseMin(a);
      hi = hi.cwiseMax(b);
      size_sum += (b - a).maxCoeff();
    }
    const Eigen::Vector3d extent = hi - lo_;
    // Cells about twice a primitive's size (surfaces), never more than 128 per axis.
    const double typical = prims.faces ? 2.0 * size_sum / n : extent.norm() / std::sqrt(static_cast<double>(n));
    cell_ = std::max({typical, extent.maxCoeff() / 128.0, 1e-12});
    for (int k = 0; k < 3; ++k) dims_[k] = std::max(1, static_cast<int>(std::floor(extent[k] / cell_)) + 1);
    cells_.assign(static_cast<size_t>(dims_[0]) * dims_[1] * dims_[2], {});
    for (int i = 0; i < n; ++i) {
      Eigen::Vector3d a, b;
      prims.bounds(i, a, b);
      const Eigen::Vector3i ca = cell_of(a), cb = cell_of(b);
      for (int x = ca[0]; x <= cb[0]; ++x)
        for (int y = ca[1]; y <= cb[1]; ++y)
          for (int z = ca[2]; z <= cb[2]; ++z) cells_[index(x, y, z)].push_back(i);
    }
    stamp_.assign(static_cast<size_t>(n), -1);
  }

  // Distance from p to the nearest primitive; stops early (returning a value <= cutoff) as soon as one
  // closer than `cutoff` is found: such a point cannot raise a maximum already at cutoff.
  double nearest(const Eigen::Vector3d& p, double cutoff) {
    ++query_;
    const Eigen::Vector3i c = cell_of(p);
    double best = std::numeric_limits<double>::infinity();
    auto visit = [&](int x, int y, int z) {
      for (int i : cells_[index(x, y, z)]) {
        if (stamp_[i] == query_) continue;
        stamp_[i] = query_;
        best = std::min(best, prims_.distance(i, p));
      }
    };
    for (int k = 0;; ++k) {
      // The cells at Chebyshev distance k from c, clipped to the grid: whole columns on the x/y rim of
      // the ring, only the two z caps inside it.
      for (int x = std::max(0, c[0] - k); x <= std::min(dims_[0] - 1, c[0] + k); ++x)
        for (int y = std::max(0, c[1] - k); y <= std::min(dims_[1] - 1, c[1] + k); ++y) {
          if (std::abs(x - c[0]) == k || std::abs(y - c[1]) == k) {
            for (int z = std::max(0, c[2] - k); z <= std::min(dims_[2] - 1, c[2] + k); ++z) visit(x, y, z);
          } else {
            if (c[2] - k >= 0) visit(x, y, c[2] - k);
            if (k > 0 && c[2] + k < dims_[2]) visit(x, y, c[2] + k);
          }
        }
      if (best <= cutoff) return best;
      // Anything in a cell beyond ring k lies beyond one of the faces of the ring's box that has cells
      // behind it; p is on the inner side of each such face.
      double bound = std::numeric_limits<double>::infinity();
      for (int a = 0; a < 3; ++a) {
        if (c[a] - k > 0) bound = std::min(bound, p[a] - (lo_[a] + (c[a] - k) * cell_));
        if (c[a] + k < dims_[a] - 1) bound = std::min(bound, lo_[a] + (c[a] + k + 1) * cell_ - p[a]);
      }
      if (best <= bound || !std::isfinite(bound)) return best;
    }
  }

 private:
  Eigen::Vector3i cell_of(const Eigen::Vector3d& p) const {
    Eigen::Vector3i c;
    for (int k = 0; k < 3; ++k)
      c[k] = std::clamp(static_cast<int>(std::floor((p[k] - lo_[k]) / cell_)), 0, dims_[k] - 1);
    return c;
  }
  size_t index(int x, int y, int z) const {
    return (static_cast<size_t>(x) * dims_[1] + y) * dims_[2] + z;
  }

  Primitives prims_;
  Eigen::Vector3d lo_;
  double cell_ = 1;
  int dims_[3] = {1, 1, 1};
  std::vector<std::vector<int>> cells_;
  std::vector<int> stamp_;
  int query_ = 0;
};

void check_mesh(const MatrixX3d& positions, const MatrixX3i& faces, bool need_faces, const char* which) {
  const std::string name = std::string("hausdorff_distance: mesh ") + which;
  if (positions.rows() == 0) throw InputError(name + " has no vertices");
  if (!positions.allFinite()) throw InputError(name + " has non-finite vertex positions");
  if (need_faces && faces.rows() == 0) throw InputError(name + " has no faces");
  if (faces.rows() > 0 && (faces.minCoeff() < 0 || faces.maxCoeff() >= positions.rows()))
    throw InputError(name + " has a face index outside 0.." + std::to_string(positions.rows() - 1));
}

double directed_hausdorff(const MatrixX3d& from, const Primitives& to) {
  NearestGrid grid(to);
  double h = 0;
  for (Eigen::Index i = 0; i < from.rows(); ++i) h = std::max(h, grid.nearest(from.row(i).transpose(), h));
  return h;
}

}  // namespace

double pixel_mse(const Image& a, const Image& b) {
  check_same_shape(a, b, "pixel_mse");
  return (a - b).square().mean();
}

double iou(const Image& a, const Image& b) {
  check_same_shape(a, b, "iou");
  const auto ma = a > 0.5, mb = b > 0.5;
  const double uni = (ma || mb).count();
  if (uni == 0) throw InputError("iou: both masks are empty");
  return static_cast<double>((ma && mb).count()) / uni;
}

double shadow_area(const Image& mask, double px_per_m) {
  if (!(px_per_m > 0) || !std::isfinite(px_per_m))
    throw InputError("shadow_area: px_per_m must be positive, got " + std::to_string(px_per_m));
  return static_cast<double>((mask > 0.5).count()) / (px_per_m * px_per_m);
}

double drape_coefficient(double shadow_area_m2, const CusickGeometry& geometry) {
  const double disk = kPi * geometry.support_radius * geometry.support_radius;
  const double specimen = kPi * geometry.specimen_radius * geometry.specimen_radius;
  if (!(specimen > disk) || !(disk >= 0))
    throw InputError("drape_coefficient: the specimen radius must exceed the support-disk radius");
  return (shadow_area_m2 - disk) / (specimen - disk);
}

double drape_coefficient(const Image& mask, double px_per_m, const CusickGeometry& geometry) {
  return drape_coefficient(shadow_area(mask, px_per_m), geometry);
}

Eigen::VectorXd radius_angle_curve(const Image& mask, const Calibration& calibration, int samples,
                                   double step_px) {
  if (samples < 3) throw InputError("radius_angle_curve: need at least 3 angles, got " + std::to_string(samples));
  if (!(step_px > 0 && step_px <= 1)) throw InputError("radius_angle_curve: step_px must lie in (0, 1]");
  const int h = static_cast<int>(mask.rows()), w = static_cast<int>(mask.cols());
  const Calibration cal = resolve_calibration(calibration, w, h, "radius_angle_curve");
  Eigen::VectorXd r(samples);
  for (int k = 0; k < samples; ++k) {
    const double theta = 2.0 * kPi * k / samples;
    const double dc = std::cos(theta), dr = -std::sin(theta);
    // Distance (px) at which the ray leaves the image rectangle [0, w) x [0, h).
    double t_max = std::numeric_limits<double>::infinity();
    if (dc > 1e-12) t_max = std::min(t_max, (w - cal.cx) / dc);
    if (dc < -1e-12) t_max = std::min(t_max, -cal.cx / dc);
    if (dr > 1e-12) t_max = std::min(t_max, (h - cal.cy) / dr);
    if (dr < -1e-12) t_max = std::min(t_max, -cal.cy / dr);
    double last = -1;
    const int steps = static_cast<int>(t_max / step_px);
    for (int s = 0; s <= steps; ++s) {
      const double t = s * step_px;
      const int col = static_cast<int>(std::floor(cal.cx + t * dc)), row = static_cast<int>(std::floor(cal.cy + t * dr));
      if (col < 0 || row < 0 || col >= w || row >= h) continue;
      if (mask(row, col) > 0.5) last = t;
    }
    r[k] = last < 0 ? 0.0 : (last + 0.5 * step_px) / cal.px_per_m;
  }
  return r;
}

NodeAnalysis analyse_nodes(const Eigen::VectorXd& r_theta, const NodeOptions& options) {
  check_curve(r_theta, "analyse_nodes");
  const int n = static_cast<int>(r_theta.size());
  NodeAnalysis out;
  out.smoothed = circular_gaussian(r_theta, options.smoothing_deg * n / 360.0);
  const Eigen::VectorXd& s = out.smoothed;
  const double lo = s.minCoeff(), hi = s.maxCoeff();
  const double floor_m = std::max(options.min_prominence_m, options.min_relative_prominence * (hi - lo));
  auto at = [&](int i) { return s[((i % n) + n) % n]; };
  std::vector<int> peaks;
  for (int i = 0; i < n; ++i) {
    if (!(s[i] > at(i - 1))) continue;
    int j = 1;  // a plateau counts once, at its first sample
    while (j < n && at(i + j) == s[i]) ++j;
    if (j == n || !(at(i + j) < s[i])) continue;
    double prominence_base = -std::numeric_limits<double>::infinity();
    for (int dir : {1, -1}) {
      double m = s[i];
      for (int step = 1; step < n; ++step) {
        const double v = at(i + dir * step);
        if (v > s[i]) break;
        m = std::min(m, v);
      }
      prominence_base = std::max(prominence_base, m);
    }
    const double prominence = s[i] - prominence_base;
    if (prominence >= floor_m && prominence > 0) {
      peaks.push_back(i);
      out.prominences_m.push_back(prominence);
      out.angles_rad.push_back(2.0 * kPi * i / n);
    }
  }
  out.count = static_cast<int>(peaks.size());
  if (out.count > 0) {
    double peak_sum = 0, trough_sum = 0;
    for (int p = 0; p < out.count; ++p) {
      const int a = peaks[p], b = p + 1 < out.count ? peaks[p + 1] : peaks[0] + n;
      double m = std::numeric_limits<double>::infinity();
      for (int i = a + 1; i < b; ++i) m = std::min(m, at(i));
      if (!std::isfinite(m)) m = s[a];
      peak_sum += s[a];
      trough_sum += m;
    }
    out.amplitude_m = (peak_sum - trough_sum) / (2.0 * out.count);
  }
  return out;
}

int node_count(const Eigen::VectorXd& r_theta, const NodeOptions& options) {
  return analyse_nodes(r_theta, options).count;
}

double node_amplitude(const Eigen::VectorXd& r_theta, const NodeOptions& options) {
  return analyse_nodes(r_theta, options).amplitude_m;
}

Eigen::VectorXd harmonic_spectrum(const Eigen::VectorXd& r_theta, int count) {
  check_curve(r_theta, "harmonic_spectrum");
  if (count < 1) throw InputError("harmonic_spectrum: count must be positive");
  const int n = static_cast<int>(r_theta.size());
  Eigen::VectorXd a = Eigen::VectorXd::Zero(count);
  for (int k = 0; k < count && k <= n / 2; ++k) {
    double re = 0, im = 0;
    for (int i = 0; i < n; ++i) {
      const double phase = 2.0 * kPi * static_cast<double>((static_cast<long>(k) * i) % n) / n;
      re += r_theta[i] * std::cos(phase);
      im -= r_theta[i] * std::sin(phase);
    }
    a[k] = std::hypot(re, im) / n * (k == 0 || 2 * k == n ? 1.0 : 2.0);
  }
  return a;
}

RThetaAlignment r_theta_rmse(const Eigen::VectorXd& measured, const Eigen::VectorXd& model) {
  check_curve(measured, "r_theta_rmse");
  check_curve(model, "r_theta_rmse");
  if (measured.size() != model.size())
    throw InputError("r_theta_rmse: curves differ in length (" + std::to_string(measured.size()) + " vs " +
                     std::to_string(model.size()) + ")");
  const int n = static_cast<int>(measured.size());
  RThetaAlignment best;
  best.rmse_m = std::numeric_limits<double>::infinity();
  for (int s = 0; s < n; ++s) {
    double sum = 0;
    for (int i = 0; i < n; ++i) {
      const double d = measured[i] - model[(i + s) % n];
      sum += d * d;
    }
    const double rmse = std::sqrt(sum / n);
    if (rmse < best.rmse_m) best = {rmse, 2.0 * kPi * s / n, s};
  }
  return best;
}

double point_triangle_distance(const Eigen::Vector3d& p, const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                               const Eigen::Vector3d& c) {
  const Eigen::Vector3d ab = b - a, ac = c - a, ap = p - a;
  const double d1 = ab.dot(ap), d2 = ac.dot(ap);
  if (d1 <= 0 && d2 <= 0) return ap.norm();
  const Eigen::Vector3d bp = p - b;
  const double d3 = ab.dot(bp), d4 = ac.dot(bp);
  if (d3 >= 0 && d4 <= d3) return bp.norm();
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0) return (p - (a + d1 / (d1 - d3) * ab)).norm();
  const Eigen::Vector3d cp = p - c;
  const double d5 = ab.dot(cp), d6 = ac.dot(cp);
  if (d6 >= 0 && d5 <= d6) return cp.norm();
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0) return (p - (a + d2 / (d2 - d6) * ac)).norm();
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0)
    return (p - (b + (d4 - d3) / ((d4 - d3) + (d5 - d6)) * (c - b))).norm();
  const double sum = va + vb + vc;
  if (!(std::abs(sum) > 0)) {  // degenerate (zero-area) triangle: nearest of its three edges
    auto seg = [&](const Eigen::Vector3d& u, const Eigen::Vector3d& v) {
      const Eigen::Vector3d uv = v - u;
      const double len2 = uv.squaredNorm();
      const double t = len2 > 0 ? std::clamp((p - u).dot(uv) / len2, 0.0, 1.0) : 0.0;
      return (p - (u + t * uv)).norm();
    };
    return std::min({seg(a, b), seg(b, c), seg(c, a)});
  }
  const double v = vb / sum, w = vc / sum;
  return (p - (a + v * ab + w * ac)).norm();
}

double hausdorff_distance(const MatrixX3d& positions_a, const MatrixX3i& faces_a, const MatrixX3d& positions_b,
                          const MatrixX3i& faces_b, HausdorffMode mode) {
  const bool surface = mode == HausdorffMode::PointToSurface;
  check_mesh(positions_a, faces_a, surface, "A");
  check_mesh(positions_b, faces_b, surface, "B");
  const Primitives to_b{&positions_b, surface ? &faces_b : nullptr};
  const Primitives to_a{&positions_a, surface ? &faces_a : nullptr};
  return std::max(directed_hausdorff(positions_a, to_b), directed_hausdorff(positions_b, to_a));
}

}  // namespace drapelab
