#include "garment/revolved_body.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include "contact/barrier.hpp"
#include "physics/sparse_pattern.hpp"
#include "util/error.hpp"
#include "util/psd_projection.hpp"

namespace drapelab {

namespace {
constexpr double kCcdGapFraction = 0.1;  // a step may close at most 90 % of a vertex's clearance
constexpr double kCarryReach = 0.02;     // m: cloth this close to a moving part starts the step carried by it
}

RevolvedBodyContact::RevolvedBodyContact(std::vector<RevolvedPart> parts, Eigen::VectorXd kappa, double activation)
    : parts_(std::move(parts)), kappa_(std::move(kappa)), dhat_(activation) {
  if (parts_.empty()) throw InputError("body: no parts");
  if (!(dhat_ > 0)) throw InputError("body: contact reach must be > 0 m");
  for (size_t k = 0; k < parts_.size(); ++k) {
    const auto& q = parts_[k];
    if (q.s.size() < 2 || q.s.size() != q.r.size())
      throw InputError("body part " + std::to_string(k) + ": profile needs >= 2 (s, r) samples of equal count");
    double slope = 0;
    for (size_t j = 0; j < q.s.size(); ++j) {
      if (!std::isfinite(q.s[j]) || !std::isfinite(q.r[j]) || q.r[j] < 0)
        throw InputError("body part " + std::to_string(k) + ": profile sample " + std::to_string(j) + " invalid");
      if (j > 0) {
        if (!(q.s[j] > q.s[j - 1]))
          throw InputError("body part " + std::to_string(k) + ": profile s must increase (sample " +
                           std::to_string(j) + ")");
        slope = std::max(slope, std::abs(q.r[j] - q.r[j - 1]) / (q.s[j] - q.s[j - 1]));
      }
    }
    lipschitz_.push_back(std::sqrt(1.0 + slope * slope));
  }
  start_.assign(parts_.size(), RigidPose{});
  end_ = start_;
}

void RevolvedBodyContact::set_poses(const std::vector<RigidPose>& start, const std::vector<RigidPose>& end) {
  if (start.size() != parts_.size() || end.size() != parts_.size())
    throw InputError("body: expected " + std::to_string(parts_.size()) + " poses per time");
  start_ = start;
  end_ = end;
}

// Clearance of a point y in part k's rest frame; gradient and Hessian in that frame.
static double local_clearance(const RevolvedPart& part, const Eigen::Vector3d& y, Eigen::Vector3d* g,
                              Eigen::Matrix3d* H) {
  const Eigen::Vector3d d = y - part.origin;
  const double s = -d.z();
  const double rho = std::hypot(d.x(), d.y());
  const double s0 = part.s.front(), s1 = part.s.back();
  if (s < s0 || s > s1) {  // beyond an apex: the distance to it
    const Eigen::Vector3d apex = part.origin - Eigen::Vector3d(0, 0, s < s0 ? s0 : s1);
    const Eigen::Vector3d w = y - apex;
    const double n = w.norm();
    if (g) *g = w / n;
    if (H) *H = (Eigen::Matrix3d::Identity() - (w / n) * (w / n).transpose()) / n;
    return n;
  }
  const auto it = std::upper_bound(part.s.begin(), part.s.end(), s);
  const size_t j = std::min<size_t>(std::max<size_t>(1, it - part.s.begin()), part.s.size() - 1);
  const double t = (s - part.s[j - 1]) / (part.s[j] - part.s[j - 1]);
  const double r = part.r[j - 1] + t * (part.r[j] - part.r[j - 1]);
  const double slope = (part.r[j] - part.r[j - 1]) / (part.s[j] - part.s[j - 1]);
  const double safe = std::max(rho, 1e-12);
  const Eigen::Vector3d e(d.x() / safe, d.y() / safe, 0.0);
  if (g) *g = e + Eigen::Vector3d(0, 0, slope);  // d s / d y_z = -1, so -r'(s) ds/dy_z = +r'
  if (H) {
    H->setZero();
    H->topLeftCorner<2, 2>() = (Eigen::Matrix2d::Identity() - e.head<2>() * e.head<2>().transpose()) / safe;
  }
  return rho - r;
}

double RevolvedBodyContact::part_clearance(int k, const Eigen::Vector3d& q, Eigen::Vector3d* grad,
                                           Eigen::Matrix3d* hess, bool at_start) const {
  const RigidPose& P = at_start ? start_[k] : end_[k];
  const Eigen::Vector3d y = P.R.transpose() * (q - P.c);
  Eigen::Vector3d gl;
  Eigen::Matrix3d Hl;
  const double v = local_clearance(parts_[k], y, grad ? &gl : nullptr, hess ? &Hl : nullptr);
  if (grad) *grad = P.R * gl;
  if (hess) *hess = P.R * Hl * P.R.transpose();
  return v;
}

Eigen::VectorXd RevolvedBodyContact::clearance(const Eigen::VectorXd& x) const {
  const int n = static_cast<int>(x.size() / 3);
  Eigen::VectorXd out(n);
  for (int i = 0; i < n; ++i) {
    double best = std::numeric_limits<double>::infinity();
    for (int k = 0; k < static_cast<int>(parts_.size()); ++k)
      best = std::min(best, part_clearance(k, x.segment<3>(3 * i)));
    out[i] = best;
  }
  return out;
}

double RevolvedBodyContact::vertex_terms(int i, const Eigen::Vector3d& q, Eigen::Vector3d* g, Eigen::Matrix3d* H,
                                         int kind) const {
  double E = 0;
  if (g) g->setZero();
  if (H) H->setZero();
  for (int k = 0; k < static_cast<int>(parts_.size()); ++k) {
    Eigen::Vector3d dg;
    Eigen::Matrix3d dH;
    const double c = part_clearance(k, q, g || H ? &dg : nullptr, H ? &dH : nullptr);
    if (c >= dhat_) continue;
    if (!(c > 0)) return std::numeric_limits<double>::infinity();
    double b, db, d2b;
    barrier_derivatives(c, dhat_, b, db, d2b);
    E += kappa_[i] * b;
    if (g) *g += kappa_[i] * db * dg;
    if (H) {
      Eigen::Matrix3d h = kappa_[i] * d2b * dg * dg.transpose();
      if (kind != 1) h += kappa_[i] * db * dH;  // kind 1: Gauss-Newton (the dropped part is NSD on convex parts)
      if (kind == 2) project_psd<3>(h.data());
      *H += h;
    }
  }
  return E;
}

std::vector<std::vector<int>> RevolvedBodyContact::stencils() const {
  std::vector<std::vector<int>> s;
  for (int i = 0; i < kappa_.size(); ++i) s.push_back({i});
  return s;
}

void RevolvedBodyContact::bind_pattern(const SparsePattern& pattern) {
  diag_.clear();
  for (int i = 0; i < kappa_.size(); ++i)
    for (int a = 0; a < 3; ++a)
      for (int b = a; b < 3; ++b) diag_.push_back(pattern.index(3 * i + a, 3 * i + b));
}

double RevolvedBodyContact::energy(const Eigen::VectorXd& x, const Eigen::VectorXd&) const {
  double E = 0;
  for (int i = 0; i < kappa_.size(); ++i) E += vertex_terms(i, x.segment<3>(3 * i), nullptr, nullptr, 0);
  return E;
}

void RevolvedBodyContact::add_gradient(const Eigen::VectorXd& x, const Eigen::VectorXd&, Eigen::VectorXd& g) const {
  Eigen::Vector3d gi;
  for (int i = 0; i < kappa_.size(); ++i) {
    vertex_terms(i, x.segment<3>(3 * i), &gi, nullptr, 0);
    g.segment<3>(3 * i) += gi;
  }
}

static void scatter(const std::vector<int>& diag, int i, const Eigen::Matrix3d& h, double scale, Eigen::VectorXd& v) {
  int k = 6 * i;
  for (int a = 0; a < 3; ++a)
    for (int b = a; b < 3; ++b) v[diag[k++]] += scale * h(a, b);
}

void RevolvedBodyContact::add_step_matrix(const Eigen::VectorXd& x, const Eigen::VectorXd&, double scale,
                                          Eigen::VectorXd& values) const {
  Eigen::Matrix3d h;
  for (int i = 0; i < kappa_.size(); ++i) {
    vertex_terms(i, x.segment<3>(3 * i), nullptr, &h, 1);
    scatter(diag_, i, h, scale, values);
  }
}

void RevolvedBodyContact::add_hessian(const Eigen::VectorXd& x, const Eigen::VectorXd&, double scale,
                                      Eigen::VectorXd& values) const {
  Eigen::Matrix3d h;
  for (int i = 0; i < kappa_.size(); ++i) {
    vertex_terms(i, x.segment<3>(3 * i), nullptr, &h, 0);
    scatter(diag_, i, h, scale, values);
  }
}

void RevolvedBodyContact::add_projected_hessian(const Eigen::VectorXd& x, const Eigen::VectorXd&, double scale,
                                                Eigen::VectorXd& values) const {
  Eigen::Matrix3d h;
  for (int i = 0; i < kappa_.size(); ++i) {
    vertex_terms(i, x.segment<3>(3 * i), nullptr, &h, 2);
    scatter(diag_, i, h, scale, values);
  }
}

void RevolvedBodyContact::add_hessian_product(const Eigen::VectorXd& x, const Eigen::VectorXd&,
                                              const Eigen::VectorXd& dir, Eigen::VectorXd& out) const {
  Eigen::Matrix3d h;
  for (int i = 0; i < kappa_.size(); ++i) {
    vertex_terms(i, x.segment<3>(3 * i), nullptr, &h, 0);
    out.segment<3>(3 * i) += h * dir.segment<3>(3 * i);
  }
}

void RevolvedBodyContact::add_step_matrix_derivatives(const Eigen::VectorXd&, const Eigen::VectorXd&,
                                                      const Eigen::VectorXd&, const Eigen::VectorXd&, double,
                                                      Eigen::VectorXd&, Eigen::VectorXd&) const {
  // Contact terms run only in IPC steps, whose adjoint is the implicit-function one (no step-matrix derivatives).
}

double RevolvedBodyContact::max_step(const Eigen::VectorXd& x, const Eigen::VectorXd& dx, const Eigen::VectorXd&) const {
  double alpha = 1.0;
  for (int i = 0; i < kappa_.size(); ++i) {
    const Eigen::Vector3d d = dx.segment<3>(3 * i);
    const double len = d.norm();
    if (len == 0) continue;
    const Eigen::Vector3d q = x.segment<3>(3 * i);
    for (int k = 0; k < static_cast<int>(parts_.size()); ++k) {
      const double L = lipschitz_[k];
      const double c0 = part_clearance(k, q);
      if (c0 - alpha * L * len > kCcdGapFraction * c0) continue;  // cannot come close within this step
      double t = 0;
      for (int it = 0; it < 64 && t < alpha; ++it) {
        const double c = part_clearance(k, q + t * d);
        if (c <= kCcdGapFraction * c0) break;
        t += (c - kCcdGapFraction * c0) / (L * len);
      }
      alpha = std::min(alpha, t);
    }
  }
  return alpha;
}

void RevolvedBodyContact::carry_start(Eigen::VectorXd& x) const {
  const int nparts = static_cast<int>(parts_.size());
  for (int i = 0; i < kappa_.size(); ++i) {
    const Eigen::Vector3d q = x.segment<3>(3 * i);
    bool clear_already = true;  // only cloth the moving body would reach (or pass) needs carrying
    for (int k = 0; k < nparts && clear_already; ++k) clear_already = part_clearance(k, q) > 0.5 * dhat_;
    if (clear_already) continue;
    int nearest = -1;
    double best = kCarryReach;
    for (int k = 0; k < nparts; ++k) {
      const double c = part_clearance(k, q, nullptr, nullptr, true);
      if (c < best) {
        best = c;
        nearest = k;
      }
    }
    if (nearest < 0) continue;
    const RigidPose &a = start_[nearest], &b = end_[nearest];
    const Eigen::Vector3d moved = b.R * (a.R.transpose() * (q - a.c)) + b.c;
    bool clear = true;
    for (int k = 0; k < nparts && clear; ++k) clear = part_clearance(k, moved) > 0;
    if (clear) x.segment<3>(3 * i) = moved;
  }
}

}  // namespace drapelab
