#include "render/soft_rasterizer.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <sstream>
#include <vector>

#include "render/rasterizer.hpp"
#include "util/error.hpp"

namespace drapelab {

namespace {

// Above this x_f the factor 1 - D_f = 1 / (1 + e^x) < 4.3e-18 is taken as 0 (invisible next to 1 in I).
constexpr double kSaturatedLogit = 40.0;
// Transmittance below this is flushed to 0 so long products never reach subnormal numbers.
constexpr double kTinyTransmittance = 1e-200;

// Branch-free clamp to [0, 1] (minsd/maxsd): the clamp is taken both ways at random in the inner loops.
inline double clamp01(double t) { return std::min(std::max(t, 0.0), 1.0); }

// 1 - exp(-y) for y >= 0, accurate also for tiny y (where 1 - exp(-y) would cancel); exp_neg = exp(-y).
inline double one_minus_exp_neg(double y, double exp_neg) { return y < 1e-2 ? -std::expm1(-y) : 1.0 - exp_neg; }

// Nearest point of a face's boundary to a pixel centre p: v[edge] + t e[edge]; h = +-d^2 (+ inside).
struct BoundaryPoint {
  double h = 0.0;
  bool inside = false;
  int edge = 0;
  double t = 0.0;
};

// The boundary point of face f nearest to (px, py), unless p lies outside beyond the cutoff radius
// (returns false: D_f(p) < epsilon). kWithEdge = false skips edge and t (the forward needs only h).
// Inside a triangle the distance to its boundary is the smallest distance to its three edge lines (and
// that line's foot lies on the edge); outside, the nearest point lies on an edge whose line has p on its
// outer side; a centre farther than r_c behind any edge line is farther than r_c from the triangle,
// which rejects the corners of the dilated bounding box with three multiply-adds.
template <bool kWithEdge>
__attribute__((always_inline)) inline bool nearest_boundary_point(const SoftRasterizer::FaceEdges& f, double px,
                                                                  double py, double cutoff_d2, double cutoff_radius,
                                                                  BoundaryPoint& out) {
  if (f.orientation == 0.0) {  // zero-area projection: no inside, distance to its segments
    double d2 = INFINITY;
    for (int k = 0; k < 3; ++k) {
      const double wx = px - f.vx[k], wy = py - f.vy[k];
      const double tk = clamp01((wx * f.ex[k] + wy * f.ey[k]) * f.inv_len2[k]);
      const double rx = wx - tk * f.ex[k], ry = wy - tk * f.ey[k];
      const double dk = rx * rx + ry * ry;
      if (dk < d2) {
        d2 = dk;
        out.edge = k;
        out.t = tk;
      }
    }
    out.h = -d2;
    out.inside = false;
    return d2 <= cutoff_d2;
  }
  const double l[3] = {f.la[0] * px + f.lb[0] * py + f.lc[0], f.la[1] * px + f.lb[1] * py + f.lc[1],
                       f.la[2] * px + f.lb[2] * py + f.lc[2]};
  const double m = std::min({l[0], l[1], l[2]});
  if (m >= 0.0) {
    out.h = m * m;
    out.inside = true;
    if (kWithEdge) {
      const int k = l[0] == m ? 0 : (l[1] == m ? 1 : 2);
      out.edge = k;
      out.t = clamp01(((px - f.vx[k]) * f.ex[k] + (py - f.vy[k]) * f.ey[k]) * f.inv_len2[k]);
    }
    return true;
  }
  if (m < -cutoff_radius) return false;
  double d2 = INFINITY;
  for (int k = 0; k < 3; ++k) {
    if (l[k] >= 0.0) continue;
    const double wx = px - f.vx[k], wy = py - f.vy[k];
    double tk = (wx * f.ex[k] + wy * f.ey[k]) * f.inv_len2[k];
    double dk;
    if (tk <= 0.0) {
      tk = 0.0;
      dk = wx * wx + wy * wy;
    } else if (tk >= 1.0) {
      tk = 1.0;
      const double ux = px - f.vx[(k + 1) % 3], uy = py - f.vy[(k + 1) % 3];
      dk = ux * ux + uy * uy;
    } else {
      dk = l[k] * l[k];
    }
    if (dk < d2) {
      d2 = dk;
      if (kWithEdge) {
        out.edge = k;
        out.t = tk;
      }
    }
  }
  out.h = -d2;
  out.inside = false;
  return d2 <= cutoff_d2;
}

void check_options(const SoftRasterOptions& options) {
  if (options.profile != SoftProfile::Gaussian && options.profile != SoftProfile::Logistic)
    throw InputError("SoftRasterizer: unknown profile");
  if (!std::isfinite(options.sigma) || options.sigma <= 0.0)
    throw InputError("SoftRasterizer: sigma must be positive and finite (pixels), got " +
                     std::to_string(options.sigma));
  if (!(options.epsilon > 0.0 && options.epsilon < 0.5))
    throw InputError("SoftRasterizer: epsilon must lie in (0, 0.5), got " + std::to_string(options.epsilon));
}

}  // namespace

SoftProfile soft_profile_from_string(const std::string& name) {
  if (name == "gaussian") return SoftProfile::Gaussian;
  if (name == "logistic") return SoftProfile::Logistic;
  throw InputError("soft rasterizer profile must be 'gaussian' or 'logistic', got '" + name + "'");
}

std::string to_string(SoftProfile profile) { return profile == SoftProfile::Gaussian ? "gaussian" : "logistic"; }

SoftRasterizer::SoftRasterizer(const Camera& camera, SoftRasterOptions options)
    : camera_(camera.clone()), options_(options) {
  check_options(options_);
  inv_sigma2_ = 1.0 / (options_.sigma * options_.sigma);
  // Gaussian: D_f < epsilon <=> d^2 > sigma^2 ln(1/epsilon).
  // Logistic: D_f < epsilon <=> x_f < -ln(1/epsilon - 1) <=> outside with d^2 > sigma^2 ln(1/epsilon - 1).
  const double log_ratio = options_.profile == SoftProfile::Gaussian ? std::log(1.0 / options_.epsilon)
                                                                     : std::log(1.0 / options_.epsilon - 1.0);
  cutoff_d2_ = options_.sigma * options_.sigma * log_ratio;
  cutoff_radius_ = std::sqrt(cutoff_d2_);
}

Image SoftRasterizer::forward(const MatrixX3d& positions, const MatrixX3i& faces) {
  has_forward_ = false;
  check_render_input(*camera_, positions, faces);
  const int width = camera_->width(), height = camera_->height();
  positions_ = positions;
  faces_ = faces;
  image_points_.resize(positions.rows(), 2);
  for (Eigen::Index v = 0; v < positions.rows(); ++v)
    image_points_.row(v) = camera_->project(positions.row(v).transpose()).transpose();

  const Eigen::Index num_faces = faces.rows();
  face_edges_.resize(static_cast<size_t>(num_faces));
  for (Eigen::Index fi = 0; fi < num_faces; ++fi) {
    FaceEdges& f = face_edges_[static_cast<size_t>(fi)];
    for (int k = 0; k < 3; ++k) {
      f.vx[k] = image_points_(faces(fi, k), 0);
      f.vy[k] = image_points_(faces(fi, k), 1);
    }
    for (int k = 0; k < 3; ++k) {
      f.ex[k] = f.vx[(k + 1) % 3] - f.vx[k];
      f.ey[k] = f.vy[(k + 1) % 3] - f.vy[k];
      const double len2 = f.ex[k] * f.ex[k] + f.ey[k] * f.ey[k];
      f.inv_len2[k] = len2 > 0.0 ? 1.0 / len2 : 0.0;
    }
    const double area2 = f.ex[0] * (-f.ey[2]) - f.ey[0] * (-f.ex[2]);  // cross(v1 - v0, v2 - v0)
    f.orientation = area2 > 0.0 ? 1.0 : (area2 < 0.0 ? -1.0 : 0.0);
    for (int k = 0; k < 3; ++k) {
      // orientation * cross(e_k, p - v_k) / |e_k|; all edges have nonzero length when the area is nonzero.
      const double scale = f.orientation * std::sqrt(f.inv_len2[k]);
      f.la[k] = -scale * f.ey[k];
      f.lb[k] = scale * f.ex[k];
      f.lc[k] = scale * (f.ey[k] * f.vx[k] - f.ex[k] * f.vy[k]);
    }
    // Pixel centres c + 0.5 within the bounding box dilated by the cutoff radius.
    const double xmin = std::min({f.vx[0], f.vx[1], f.vx[2]}) - cutoff_radius_;
    const double xmax = std::max({f.vx[0], f.vx[1], f.vx[2]}) + cutoff_radius_;
    const double ymin = std::min({f.vy[0], f.vy[1], f.vy[2]}) - cutoff_radius_;
    const double ymax = std::max({f.vy[0], f.vy[1], f.vy[2]}) + cutoff_radius_;
    f.col0 = first_pixel(xmin, width);
    f.col1 = last_pixel(xmax, width);
    f.row0 = first_pixel(ymin, height);
    f.row1 = last_pixel(ymax, height);
  }

  if (transmittance_.rows() != height || transmittance_.cols() != width) transmittance_.resize(height, width);
  transmittance_.setOnes();
  if (options_.profile == SoftProfile::Gaussian)
    forward_gaussian();
  else
    forward_logistic();
  has_forward_ = true;
  return 1.0 - transmittance_;
}

MatrixX3d SoftRasterizer::backward(const Image& grad_image) const {
  if (!has_forward_) throw InputError("SoftRasterizer::backward: call forward first (no forward state)");
  const int width = camera_->width(), height = camera_->height();
  if (grad_image.rows() != height || grad_image.cols() != width) {
    std::ostringstream os;
    os << "SoftRasterizer::backward: grad_image is " << grad_image.rows() << "x" << grad_image.cols()
       << " (rows x cols) but the rendered image is " << height << "x" << width;
    throw InputError(os.str());
  }
  if (!grad_image.allFinite()) throw InputError("SoftRasterizer::backward: grad_image has non-finite values");

  // dL/dq for every vertex's image coordinates, then through the camera.
  MatrixX2d grad_points = MatrixX2d::Zero(image_points_.rows(), 2);
  if (options_.profile == SoftProfile::Gaussian)
    backward_gaussian(grad_image, grad_points);
  else
    backward_logistic(grad_image, grad_points);

  MatrixX3d grad_positions(positions_.rows(), 3);
  Eigen::Matrix<double, 2, 3> jacobian;
  for (Eigen::Index v = 0; v < positions_.rows(); ++v) {
    camera_->project(positions_.row(v).transpose(), &jacobian);
    grad_positions.row(v) = (jacobian.transpose() * grad_points.row(v).transpose()).transpose();
  }
  return grad_positions;
}

// Gaussian profile: covered pixels are exactly 1 (T = 0); uncovered ones multiply 1 - exp(-d^2 / sigma^2).
void SoftRasterizer::forward_gaussian() {
  fill_covered_pixels(image_points_, faces_, transmittance_, 0.0);
  const int width = camera_->width(), height = camera_->height();
  // Most faces lie inside the silhouette with every pixel of their dilated box covered: count the
  // uncovered pixels in each box with a summed-area table and skip the faces that have none.
  const size_t stride = static_cast<size_t>(width) + 1;
  uncovered_sum_.assign(stride * (static_cast<size_t>(height) + 1), 0);
  // next_uncovered_[r * stride + c]: the first uncovered column >= c in row r (width if none), so the
  // loops below jump over covered runs instead of testing (and mispredicting) pixel by pixel.
  next_uncovered_.resize(stride * static_cast<size_t>(height));
  for (int r = 0; r < height; ++r) {
    const double* row = transmittance_.data() + static_cast<Eigen::Index>(r) * width;
    int running = 0;
    for (int c = 0; c < width; ++c) {
      running += row[c] != 0.0;
      uncovered_sum_[(r + 1) * stride + c + 1] = uncovered_sum_[r * stride + c + 1] + running;
    }
    int* next = next_uncovered_.data() + r * stride;
    next[width] = width;
    for (int c = width - 1; c >= 0; --c) next[c] = row[c] != 0.0 ? c : next[c + 1];
  }
  const double cutoff_d2 = cutoff_d2_, cutoff_radius = cutoff_radius_, inv_sigma2 = inv_sigma2_;
  for (FaceEdges& f : face_edges_) {
    if (f.col0 > f.col1 || f.row0 > f.row1) continue;
    const size_t r0 = static_cast<size_t>(f.row0), r1 = static_cast<size_t>(f.row1) + 1;
    const size_t c0 = static_cast<size_t>(f.col0), c1 = static_cast<size_t>(f.col1) + 1;
    const int uncovered = uncovered_sum_[r1 * stride + c1] - uncovered_sum_[r0 * stride + c1] -
                          uncovered_sum_[r1 * stride + c0] + uncovered_sum_[r0 * stride + c0];
    if (uncovered == 0) {
      f.row1 = f.row0 - 1;  // nothing to do here, in the backward either
      continue;
    }
    for (int r = f.row0; r <= f.row1; ++r) {
      const double py = r + 0.5;
      double* row = transmittance_.data() + static_cast<Eigen::Index>(r) * width;
      const int* next = next_uncovered_.data() + r * stride;
      for (int c = next[f.col0]; c <= f.col1; c = next[c + 1]) {
        BoundaryPoint b;
        if (!nearest_boundary_point<false>(f, c + 0.5, py, cutoff_d2, cutoff_radius, b)) continue;
        // An uncovered pixel is outside every face, so h <= 0 up to rounding at an edge (then D_f = 1).
        const double y = std::max(-b.h, 0.0) * inv_sigma2;
        row[c] *= one_minus_exp_neg(y, std::exp(-y));  // 1 - D_f
      }
    }
  }
}

void SoftRasterizer::backward_gaussian(const Image& grad_image, MatrixX2d& grad_points) const {
  const int width = camera_->width();
  const double cutoff_d2 = cutoff_d2_, cutoff_radius = cutoff_radius_, inv_sigma2 = inv_sigma2_;
  for (size_t fi = 0; fi < face_edges_.size(); ++fi) {
    const FaceEdges& f = face_edges_[fi];
    double gx[3] = {0, 0, 0}, gy[3] = {0, 0, 0};
    for (int r = f.row0; r <= f.row1; ++r) {
      const double py = r + 0.5;
      const Eigen::Index offset = static_cast<Eigen::Index>(r) * width;
      const double* trans_row = transmittance_.data() + offset;
      const double* grad_row = grad_image.data() + offset;
      const int* next = next_uncovered_.data() + static_cast<size_t>(r) * (static_cast<size_t>(width) + 1);
      for (int c = next[f.col0]; c <= f.col1; c = next[c + 1]) {
        const double weight = grad_row[c] * trans_row[c];  // dL/dI * T
        if (weight == 0.0) continue;
        const double px = c + 0.5;
        BoundaryPoint b;
        if (!nearest_boundary_point<true>(f, px, py, cutoff_d2, cutoff_radius, b)) continue;
        const int k = b.edge;
        const double t = b.t;
        const double y = std::max(-b.h, 0.0) * inv_sigma2, exp_neg = std::exp(-y);  // D_f = exp_neg
        const double factor = one_minus_exp_neg(y, exp_neg);    // 1 - D_f, as in the forward
        if (factor == 0.0) continue;
        // dL/d(d^2) = dL/dI * (T / (1 - D_f)) * dD_f/d(d^2),  dD_f/d(d^2) = -D_f / sigma^2;
        // d(d^2)/dv[k] = -2 (1 - t) r, d(d^2)/dv[k+1] = -2 t r, r = p - v[k] - t e[k].
        const double g = weight / factor * -exp_neg * inv_sigma2 * -2.0;
        const double rx = px - f.vx[k] - t * f.ex[k], ry = py - f.vy[k] - t * f.ey[k];
        const int k1 = (k + 1) % 3;
        gx[k] += g * (1.0 - t) * rx;
        gy[k] += g * (1.0 - t) * ry;
        gx[k1] += g * t * rx;
        gy[k1] += g * t * ry;
      }
    }
    accumulate_corner_gradients(fi, gx, gy, grad_points);
  }
}

// Logistic profile (SoftRas): every pixel near a face multiplies 1 - D_f = 1 / (1 + e^{x_f}).
void SoftRasterizer::forward_logistic() {
  const int width = camera_->width();
  const double cutoff_d2 = cutoff_d2_, cutoff_radius = cutoff_radius_, inv_sigma2 = inv_sigma2_;
  for (const FaceEdges& f : face_edges_) {
    for (int r = f.row0; r <= f.row1; ++r) {
      const double py = r + 0.5;
      double* row = transmittance_.data() + static_cast<Eigen::Index>(r) * width;
      for (int c = f.col0; c <= f.col1; ++c) {
        BoundaryPoint b;
        if (!nearest_boundary_point<false>(f, c + 0.5, py, cutoff_d2, cutoff_radius, b)) continue;
        const double x = b.h * inv_sigma2;
        const double factor = x > kSaturatedLogit ? 0.0 : 1.0 / (1.0 + std::exp(x));  // 1 - D_f
        const double t = row[c] * factor;
        row[c] = t < kTinyTransmittance ? 0.0 : t;
      }
    }
  }
}

void SoftRasterizer::backward_logistic(const Image& grad_image, MatrixX2d& grad_points) const {
  const int width = camera_->width();
  const double cutoff_d2 = cutoff_d2_, cutoff_radius = cutoff_radius_, inv_sigma2 = inv_sigma2_;
  for (size_t fi = 0; fi < face_edges_.size(); ++fi) {
    const FaceEdges& f = face_edges_[fi];
    double gx[3] = {0, 0, 0}, gy[3] = {0, 0, 0};
    for (int r = f.row0; r <= f.row1; ++r) {
      const double py = r + 0.5;
      const Eigen::Index offset = static_cast<Eigen::Index>(r) * width;
      const double* trans_row = transmittance_.data() + offset;
      const double* grad_row = grad_image.data() + offset;
      for (int c = f.col0; c <= f.col1; ++c) {
        const double weight = grad_row[c] * trans_row[c];  // dL/dI * T
        if (weight == 0.0) continue;
        const double px = c + 0.5;
        BoundaryPoint b;
        if (!nearest_boundary_point<true>(f, px, py, cutoff_d2, cutoff_radius, b)) continue;
        const bool inside = b.inside;
        const int k = b.edge;
        const double t = b.t;
        const double x = b.h * inv_sigma2;
        if (x > kSaturatedLogit) continue;  // its factor was taken as 0 in the forward
        const double d = 1.0 / (1.0 + std::exp(-x));
        // dL/dx_f = dL/dI T D_f; x_f = +-d2 / sigma^2; d2 = |r|^2, r = p - (1-t) v[k] - t v[k+1].
        const double g = weight * d * (inside ? inv_sigma2 : -inv_sigma2) * -2.0;
        const double rx = px - f.vx[k] - t * f.ex[k], ry = py - f.vy[k] - t * f.ey[k];
        const int k1 = (k + 1) % 3;
        gx[k] += g * (1.0 - t) * rx;
        gy[k] += g * (1.0 - t) * ry;
        gx[k1] += g * t * rx;
        gy[k1] += g * t * ry;
      }
    }
    accumulate_corner_gradients(fi, gx, gy, grad_points);
  }
}

void SoftRasterizer::accumulate_corner_gradients(size_t face, const double gx[3], const double gy[3],
                                                 MatrixX2d& grad_points) const {
  for (int k = 0; k < 3; ++k) {
    const int v = faces_(static_cast<Eigen::Index>(face), k);
    grad_points(v, 0) += gx[k];
    grad_points(v, 1) += gy[k];
  }
}

RenderTiming time_soft_render(const TriangleMesh& mesh, int repeats, const Camera& camera, SoftRasterOptions options) {
  if (repeats < 1) throw InputError("time_soft_render: repeats must be at least 1, got " + std::to_string(repeats));
  SoftRasterizer rasterizer(camera, options);
  // A gradient that is nonzero everywhere so the backward visits every pair, as in a pixel-MSE loss.
  Image grad = Image::Constant(camera.height(), camera.width(), 1.0 / (camera.height() * camera.width()));
  std::vector<double> forward_ms, backward_ms;
  using clock = std::chrono::steady_clock;
  rasterizer.forward(mesh.positions, mesh.faces);  // warm-up: sizes the buffers
  for (int i = 0; i < repeats; ++i) {
    const auto t0 = clock::now();
    const Image image = rasterizer.forward(mesh.positions, mesh.faces);
    const auto t1 = clock::now();
    const MatrixX3d g = rasterizer.backward(grad);
    const auto t2 = clock::now();
    forward_ms.push_back(std::chrono::duration<double, std::milli>(t1 - t0).count());
    backward_ms.push_back(std::chrono::duration<double, std::milli>(t2 - t1).count());
  }
  auto median = [](std::vector<double> v) {
    std::nth_element(v.begin(), v.begin() + static_cast<long>(v.size() / 2), v.end());
    return v[v.size() / 2];
  };
  RenderTiming timing;
  timing.forward_ms = median(forward_ms);
  timing.backward_ms = median(backward_ms);
  timing.repeats = repeats;
  timing.width = camera.width();
  timing.height = camera.height();
  timing.faces = mesh.num_faces();
  return timing;
}

}  // namespace drapelab
