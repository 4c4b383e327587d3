#include "garment/revolved_body.hpp"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>

#include "contact/barrier.hpp"
#include "contact/disk_edge.hpp"
#include "contact/pair_barrier.hpp"
#include "physics/sparse_pattern.hpp"
#include "util/error.hpp"
#include "util/psd_projection.hpp"

namespace drapelab {

namespace {
constexpr double kCcdGapFraction = 0.1;  // a step may close at most 90 % of a vertex's clearance
constexpr double kCarryFull = 0.01;   // m: cloth this close to the body moves with it (obstacle_carry)
constexpr double kCarryReach = 0.03;  // m: ... falling smoothly to none at this clearance
constexpr double kBlendWidth = 0.005; // m: least width of the softmin that blends the parts' motions ...
constexpr double kBlendSpreadFactor = 2.0;  // ... else this times the spread of their motions
constexpr double kBlendContactFactor = 0.02; // ... times min(1, clearance / kCarryFull), at least this
constexpr double kSpreadReach = 0.05;       // m: parts this much farther than the nearest count in the spread
constexpr double kCarryWidthFactor = 4.0;   // the falloff is at least this times the motion wide
constexpr double kMaxCarry = 0.1;           // m: no part moves more than this in a step (where the carry looks)
constexpr double kEdgeDip = 1e-4;           // m: an edge's barrier fades in as its minimum dips below its ends'

// E_ek of an edge (x: both ends, world frame) against a part at pose `pose`, for a minimum m found at the same
// (double) positions; pa, pb the ends' pieces.
template <class T>
T edge_energy_at(const ProfileView& P, const RigidPose& pose, const T* x, const SegmentPartMinimum& m, int pa, int pb,
                 double kappa, double dhat) {
  T y[6];
  for (int end = 0; end < 2; ++end)
    for (int i = 0; i < 3; ++i) {
      T v = T(0.0);
      for (int j = 0; j < 3; ++j) v += pose.R(j, i) * (x[3 * end + j] - pose.c[j]);
      y[3 * end + i] = v;
    }
  const T d = segment_part_clearance(P, y, y + 3, m);
  const T ga = piece_clearance(P, pa, y), gb = piece_clearance(P, pb, y + 3);
  const T w = dip_weight(ga - d, kEdgeDip) * dip_weight(gb - d, kEdgeDip);
  return kappa * w * barrier(d, dhat);
}
}

RevolvedBodyContact::RevolvedBodyContact(std::vector<RevolvedPart> parts, Eigen::VectorXd kappa, double activation,
                                         std::vector<std::array<int, 2>> edges)
    : parts_(std::move(parts)), kappa_(std::move(kappa)), dhat_(activation), edges_(std::move(edges)) {
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
    views_.push_back(ProfileView{parts_[k].origin.data(), parts_[k].s.data(), parts_[k].r.data(),
                                 static_cast<int>(parts_[k].s.size())});
  }
  for (size_t e = 0; e < edges_.size(); ++e) {
    const auto [a, b] = edges_[e];
    if (a < 0 || b < 0 || a >= kappa_.size() || b >= kappa_.size() || a == b)
      throw InputError("body: edge " + std::to_string(e) + " (" + std::to_string(a) + ", " + std::to_string(b) +
                       ") is not a pair of distinct vertices of the " + std::to_string(kappa_.size()));
    // a vertex has about six edges, each shared by two vertices: the edges around a vertex carry about its weight
    edge_kappa_.push_back((kappa_[a] + kappa_[b]) / 6.0);
  }
  start_.assign(parts_.size(), RigidPose{});
  end_ = start_;
  current_ = start_;
}

void RevolvedBodyContact::set_poses(const std::vector<RigidPose>& start, const std::vector<RigidPose>& end) {
  if (start.size() != parts_.size() || end.size() != parts_.size())
    throw InputError("body: expected " + std::to_string(parts_.size()) + " poses per time");
  start_ = start;
  end_ = end;
  current_ = start;
  progress_ = 0.0;
}

RigidPose RevolvedBodyContact::interpolate(const RigidPose& a, const RigidPose& b, double t) {
  const Eigen::AngleAxisd rel(a.R.transpose() * b.R);
  RigidPose out;
  out.R = a.R * Eigen::AngleAxisd(t * rel.angle(), rel.axis()).toRotationMatrix();
  out.c = a.c + t * (b.c - a.c);
  return out;
}

void RevolvedBodyContact::advance_obstacle(double tau) {
  if (!(tau >= 0)) throw SolverError("body: advance by " + std::to_string(tau) + " of its motion");
  if (tau >= 1) {
    current_ = end_;
    progress_ = 1.0;
    return;
  }
  for (size_t k = 0; k < parts_.size(); ++k) current_[k] = interpolate(current_[k], end_[k], tau);
  progress_ += tau * (1.0 - progress_);
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

double RevolvedBodyContact::part_clearance_at(int k, const RigidPose& P, const Eigen::Vector3d& q,
                                             Eigen::Vector3d* grad, Eigen::Matrix3d* hess) const {
  Eigen::Vector3d gl;
  Eigen::Matrix3d Hl;
  const double v = local_clearance(parts_[k], P.R.transpose() * (q - P.c), grad ? &gl : nullptr, hess ? &Hl : nullptr);
  if (grad) *grad = P.R * gl;
  if (hess) *hess = P.R * Hl * P.R.transpose();
  return v;
}

double RevolvedBodyContact::part_clearance(int k, const Eigen::Vector3d& q, Eigen::Vector3d* grad,
                                           Eigen::Matrix3d* hess) const {
  return part_clearance_at(k, current_[k], q, grad, hess);
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
    if (kind == 3) d2b = barrier_step_curvature(c, dhat_);  // the step matrix's curvature cap (header)
    E += kappa_[i] * b;
    if (g) *g += kappa_[i] * db * dg;
    if (H) {
      Eigen::Matrix3d h = kappa_[i] * d2b * dg * dg.transpose();
      // kinds 1 and 3: Gauss-Newton (the dropped part is NSD on convex parts)
      if (kind != 1 && kind != 3) h += kappa_[i] * db * dH;
      if (kind == 2) project_psd<3>(h.data());
      *H += h;
    }
  }
  return E;
}

std::vector<std::vector<int>> RevolvedBodyContact::stencils() const {
  std::vector<std::vector<int>> s;
  for (int i = 0; i < kappa_.size(); ++i) s.push_back({i});
  for (const auto& e : edges_) s.push_back({e[0], e[1]});
  return s;
}

void RevolvedBodyContact::bind_pattern(const SparsePattern& pattern) {
  diag_.clear();
  for (int i = 0; i < kappa_.size(); ++i)
    for (int a = 0; a < 3; ++a)
      for (int b = a; b < 3; ++b) diag_.push_back(pattern.index(3 * i + a, 3 * i + b));
  edge_scatter_.assign(edges_.size() * 36, -1);
  for (size_t e = 0; e < edges_.size(); ++e)
    for (int i = 0; i < 6; ++i)
      for (int j = 0; j < 6; ++j) {
        const int r = 3 * edges_[e][i / 3] + i % 3, c = 3 * edges_[e][j / 3] + j % 3;
        if (r <= c) edge_scatter_[e * 36 + i * 6 + j] = pattern.index(r, c);
      }
}

double RevolvedBodyContact::energy(const Eigen::VectorXd& x, const Eigen::VectorXd&) const {
  double E = 0;
  for (int i = 0; i < kappa_.size(); ++i) E += vertex_terms(i, x.segment<3>(3 * i), nullptr, nullptr, 0);
  if (!std::isfinite(E)) return E;
  return E + edge_terms(x, nullptr, 0, 0.0, nullptr, nullptr, nullptr);
}

void RevolvedBodyContact::add_gradient(const Eigen::VectorXd& x, const Eigen::VectorXd&, Eigen::VectorXd& g) const {
  Eigen::Vector3d gi;
  for (int i = 0; i < kappa_.size(); ++i) {
    vertex_terms(i, x.segment<3>(3 * i), &gi, nullptr, 0);
    g.segment<3>(3 * i) += gi;
  }
  edge_terms(x, &g, 0, 0.0, nullptr, nullptr, nullptr);
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
    vertex_terms(i, x.segment<3>(3 * i), nullptr, &h, 3);
    scatter(diag_, i, h, scale, values);
  }
  // The edges' step matrix is their exact Hessian projected onto the PSD cone, not Gauss-Newton: an edge's
  // clearance is a minimum over the segment, and b' times its curvature (-g_xt g_tt^-1 g_tx from the moving
  // minimiser) is what resists sliding a chord across a convex part (measured: with Gauss-Newton alone, 2k wool
  // walking, a 3 cm chord of the hip was pushed 1 nm from it over 50 Newton iterations, the residual growing).
  edge_terms(x, nullptr, 3, scale, &values, nullptr, nullptr);
}

void RevolvedBodyContact::add_hessian(const Eigen::VectorXd& x, const Eigen::VectorXd&, double scale,
                                      Eigen::VectorXd& values) const {
  Eigen::Matrix3d h;
  for (int i = 0; i < kappa_.size(); ++i) {
    vertex_terms(i, x.segment<3>(3 * i), nullptr, &h, 0);
    scatter(diag_, i, h, scale, values);
  }
  edge_terms(x, nullptr, 0, scale, &values, nullptr, nullptr);
}

void RevolvedBodyContact::add_projected_hessian(const Eigen::VectorXd& x, const Eigen::VectorXd&, double scale,
                                                Eigen::VectorXd& values) const {
  Eigen::Matrix3d h;
  for (int i = 0; i < kappa_.size(); ++i) {
    vertex_terms(i, x.segment<3>(3 * i), nullptr, &h, 2);
    scatter(diag_, i, h, scale, values);
  }
  edge_terms(x, nullptr, 2, scale, &values, nullptr, nullptr);
}

void RevolvedBodyContact::add_hessian_product(const Eigen::VectorXd& x, const Eigen::VectorXd&,
                                              const Eigen::VectorXd& dir, Eigen::VectorXd& out) const {
  Eigen::Matrix3d h;
  for (int i = 0; i < kappa_.size(); ++i) {
    vertex_terms(i, x.segment<3>(3 * i), nullptr, &h, 0);
    out.segment<3>(3 * i) += h * dir.segment<3>(3 * i);
  }
  edge_terms(x, nullptr, 0, 0.0, nullptr, &dir, &out);
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
  return edges_max_step(x, dx, alpha);
}

void RevolvedBodyContact::obstacle_carry(const Eigen::VectorXd& x, Eigen::VectorXd& u) const {
  if (progress_ >= 1) return;
  const int nparts = static_cast<int>(parts_.size());
  std::vector<double> c(nparts);
  std::vector<Eigen::Vector3d> D(nparts);
  for (int i = 0; i < kappa_.size(); ++i) {
    const Eigen::Vector3d q = x.segment<3>(3 * i);
    double cmin = std::numeric_limits<double>::infinity();
    int nearest = 0;
    for (int k = 0; k < nparts; ++k) {
      c[k] = part_clearance(k, q) / lipschitz_[k];  // gradient norm <= 1
      if (c[k] < cmin) cmin = c[k], nearest = k;
    }
    if (!(cmin < kCarryReach + kCarryWidthFactor * kMaxCarry)) continue;
    for (int k = 0; k < nparts; ++k) {
      const RigidPose &a = current_[k], &b = end_[k];
      D[k] = b.R * (a.R.transpose() * (q - a.c)) + b.c - q;  // part k's rigid motion of q
    }
    // Widths scale with the motion so that the field's gradient stays below 1 (the carried map is injective and
    // layers 0.5 mm apart move nearly together): the blend with the parts' motions' spread, the falloff with the
    // motion itself.
    double spread = 0;
    for (int k = 0; k < nparts; ++k)
      spread = std::max(spread, (D[k] - D[nearest]).norm() * std::max(0.0, 1.0 - (c[k] - cmin) / kSpreadReach));
    // ... and shrinks toward contact: cloth touching one part moves with that part only (no motion relative to
    // it, so the bound on the relative motion does not hold it back).
    const double sigma = std::max(kBlendWidth, kBlendSpreadFactor * spread) *
                         std::clamp(cmin / kCarryFull, kBlendContactFactor, 1.0);
    Eigen::Vector3d d = Eigen::Vector3d::Zero();
    double wsum = 0;
    for (int k = 0; k < nparts; ++k) {
      const double w = std::exp(-(c[k] - cmin) / sigma);
      if (w < 1e-12) continue;
      d += w * D[k];
      wsum += w;
    }
    d /= wsum;
    const double width = std::max(kCarryReach - kCarryFull, kCarryWidthFactor * d.norm());
    if (cmin >= kCarryFull + width) continue;
    double f = 1.0;
    if (cmin > kCarryFull) {
      const double t = (cmin - kCarryFull) / width;
      f = 1.0 - t * t * (3.0 - 2.0 * t);
    }
    u.segment<3>(3 * i) += f * d;
  }
}

double RevolvedBodyContact::obstacle_max_advance(const Eigen::VectorXd& x, const Eigen::VectorXd& u) const {
  if (progress_ >= 1) return 1.0;
  const int nparts = static_cast<int>(parts_.size());
  // Per part: the rotation from the current to the end pose (angle theta about the world axis n) and the translation.
  std::vector<Eigen::Vector3d> axis(nparts), shift(nparts);
  std::vector<double> angle(nparts);
  for (int k = 0; k < nparts; ++k) {
    const RigidPose &a = current_[k], &b = end_[k];
    const Eigen::AngleAxisd rel(a.R.transpose() * b.R);
    angle[k] = std::abs(rel.angle());
    axis[k] = a.R * rel.axis() * (rel.angle() < 0 ? -1.0 : 1.0);
    shift[k] = b.c - a.c;
  }
  double alpha = 1.0;
  for (int i = 0; i < kappa_.size(); ++i) {
    const Eigen::Vector3d q = x.segment<3>(3 * i), d = u.segment<3>(3 * i);
    for (int k = 0; k < nparts; ++k) {
      // The vertex in the part's frame, y(t) = R(t)^T (q + t d - c(t)), moves at
      // |y'| = |(d - dc) - theta n x (q - c0 + t (d - dc))| <= |w0| + theta |d - dc| = V.
      const Eigen::Vector3d rel_move = d - shift[k];
      const Eigen::Vector3d w0 = rel_move - angle[k] * axis[k].cross(q - current_[k].c);
      const double V = w0.norm() + angle[k] * rel_move.norm();
      if (V == 0) continue;
      const double L = lipschitz_[k];
      const double c0 = part_clearance(k, q);
      if (c0 - alpha * L * V > kCcdGapFraction * c0) continue;  // cannot come close within this advance
      double t = 0;
      for (int it = 0; it < 64 && t < alpha; ++it) {
        const double c = part_clearance_at(k, interpolate(current_[k], end_[k], t), q + t * d);
        if (c <= kCcdGapFraction * c0) break;
        t += (c - kCcdGapFraction * c0) / (L * V);
      }
      if (t < alpha && std::getenv("DRAPELAB_DEBUG_CROSSING")) {
        std::fprintf(stderr, "  body advance limited to %.3g by vertex %d (%.4f %.4f %.4f) part %d: clearance %.3g, "
                     "others", t, i, q.x(), q.y(), q.z(), k, c0);
        for (size_t j = 0; j < parts_.size(); ++j) std::fprintf(stderr, " %.3g", part_clearance(static_cast<int>(j), q));
        std::fprintf(stderr, ", move %.3g, bound speed %.3g\n", d.norm(), V);
      }
      alpha = std::min(alpha, t);
    }
  }
  return edges_max_advance(x, u, alpha);
}

// ---- cloth edges against the parts (garment/revolved_edge.hpp) ----

std::vector<Eigen::VectorXd> RevolvedBodyContact::local_positions(const Eigen::VectorXd& x) const {
  const int n = static_cast<int>(x.size() / 3);
  std::vector<Eigen::VectorXd> out(parts_.size());
  for (size_t k = 0; k < parts_.size(); ++k) {
    const RigidPose& P = current_[k];
    out[k].resize(x.size());
    for (int i = 0; i < n; ++i) out[k].segment<3>(3 * i) = P.R.transpose() * (x.segment<3>(3 * i) - P.c);
  }
  return out;
}

Eigen::VectorXd RevolvedBodyContact::edge_clearance(const Eigen::VectorXd& x) const {
  if (x.size() != 3 * kappa_.size())
    throw InputError("body: expected " + std::to_string(3 * kappa_.size()) + " coordinates, got " +
                     std::to_string(x.size()));
  const auto local = local_positions(x);
  Eigen::VectorXd out(edges_.size());
  for (size_t e = 0; e < edges_.size(); ++e) {
    double best = std::numeric_limits<double>::infinity();
    for (size_t k = 0; k < parts_.size(); ++k)
      best = std::min(best, segment_part_minimum(views_[k], local[k].data() + 3 * edges_[e][0],
                                                 local[k].data() + 3 * edges_[e][1]).clearance);
    out[e] = best;
  }
  return out;
}

double RevolvedBodyContact::edge_energy(const Eigen::VectorXd& x) const {
  return edge_terms(x, nullptr, 0, 0.0, nullptr, nullptr, nullptr);
}

bool RevolvedBodyContact::edge_part_terms(int e, int k, const std::vector<Eigen::VectorXd>& local, double* E,
                                          double* g, double* H, int kind) const {
  const ProfileView& P = views_[k];
  const double* ya = local[k].data() + 3 * edges_[e][0];
  const double* yb = local[k].data() + 3 * edges_[e][1];
  double lo[3], hi[3];
  for (int i = 0; i < 3; ++i) lo[i] = std::min(ya[i], yb[i]), hi[i] = std::max(ya[i], yb[i]);
  if (box_clearance_bound(P, lo, hi, nullptr) >= dhat_) return false;  // out of reach: no segment search
  const SegmentPartMinimum m = segment_part_minimum(P, ya, yb);
  if (m.kind == SegmentPartMinimum::kEnd || m.clearance >= dhat_) return false;
  if (!(m.clearance > 0)) {
    *E = std::numeric_limits<double>::infinity();
    return true;
  }
  const int pa = profile_piece(P, P.origin[2] - ya[2]), pb = profile_piece(P, P.origin[2] - yb[2]);
  const double kappa = edge_kappa_[e];
  const RigidPose& pose = current_[k];
  double xd[6];
  for (int i = 0; i < 3; ++i) {
    xd[i] = pose.R.row(i).dot(Eigen::Map<const Eigen::Vector3d>(ya)) + pose.c[i];
    xd[3 + i] = pose.R.row(i).dot(Eigen::Map<const Eigen::Vector3d>(yb)) + pose.c[i];
  }
  // (xd: the ends in the world frame, recomputed from the local ones so that jets and the search see one state)
  if (!g && !H) {
    *E = edge_energy_at<double>(P, pose, xd, m, pa, pb, kappa, dhat_);
    return *E != 0;
  }
  if (!H) {
    using J = Jet<double, 6>;
    J xj[6];
    for (int i = 0; i < 6; ++i) xj[i] = J(xd[i], i);
    const J Ej = edge_energy_at<J>(P, pose, xj, m, pa, pb, kappa, dhat_);
    *E = Ej.a;
    for (int i = 0; i < 6; ++i) g[i] = Ej.v[i];
    return true;
  }
  using J1 = Jet<double, 6>;
  using J2 = Jet<J1, 6>;
  J2 xj[6];
  for (int i = 0; i < 6; ++i) xj[i] = J2(J1(xd[i], i), i);
  const J2 Ej = edge_energy_at<J2>(P, pose, xj, m, pa, pb, kappa, dhat_);
  *E = Ej.a.a;
  if (g)
    for (int i = 0; i < 6; ++i) g[i] = Ej.a.v[i];
  for (int i = 0; i < 6; ++i)
    for (int j = 0; j < 6; ++j) H[6 * i + j] = 0.5 * (Ej.v[i].v[j] + Ej.v[j].v[i]);
  if (kind >= 2) project_psd<6>(H);
  if (kind == 3 && m.clearance < kGaussNewtonDistanceFloor * dhat_) {  // the step matrix's curvature cap (header)
    double b, db, d2b;
    barrier_derivatives(m.clearance, dhat_, b, db, d2b);
    const double factor = barrier_step_curvature(m.clearance, dhat_) / d2b;  // positive, below 1: still PSD
    for (int i = 0; i < 36; ++i) H[i] *= factor;
  }
  return true;
}

double RevolvedBodyContact::edge_terms(const Eigen::VectorXd& x, Eigen::VectorXd* grad, int kind, double scale,
                                       Eigen::VectorXd* values, const Eigen::VectorXd* dir,
                                       Eigen::VectorXd* product) const {
  if (edges_.empty()) return 0.0;
  const auto local = local_positions(x);
  const bool want_h = values || product;
  double total = 0, E, g[6], H[36];
  for (size_t e = 0; e < edges_.size(); ++e)
    for (size_t k = 0; k < parts_.size(); ++k) {
      if (!edge_part_terms(static_cast<int>(e), static_cast<int>(k), local, &E, grad ? g : nullptr,
                           want_h ? H : nullptr, kind))
        continue;
      total += E;
      if (!std::isfinite(E)) {
        if (!grad && !want_h) return E;
        continue;
      }
      const int a = edges_[e][0], b = edges_[e][1];
      if (grad) {
        grad->segment<3>(3 * a) += Eigen::Map<const Eigen::Vector3d>(g);
        grad->segment<3>(3 * b) += Eigen::Map<const Eigen::Vector3d>(g + 3);
      }
      if (values)
        for (int i = 0; i < 36; ++i)
          if (edge_scatter_[e * 36 + i] >= 0) (*values)[edge_scatter_[e * 36 + i]] += scale * H[i];
      if (product) {
        double d[6], out[6] = {0, 0, 0, 0, 0, 0};
        for (int i = 0; i < 3; ++i) d[i] = (*dir)[3 * a + i], d[3 + i] = (*dir)[3 * b + i];
        for (int i = 0; i < 6; ++i)
          for (int j = 0; j < 6; ++j) out[i] += H[6 * i + j] * d[j];
        for (int i = 0; i < 3; ++i) (*product)[3 * a + i] += out[i], (*product)[3 * b + i] += out[3 + i];
      }
    }
  return total;
}

// Conservative advancement on each edge's clearance along the cloth's move x + t dx (the body still): every
// point of the edge moves by a convex combination of its ends' moves, so at most len = max(|dx_a|, |dx_b|) per
// unit t, and its clearance g changes at most L len per unit t (L: g's Lipschitz constant over the box the move
// stays in). Skipped when the box's bound stays above the gap fraction of the ends' clearance (>= the edge's).
double RevolvedBodyContact::edges_max_step(const Eigen::VectorXd& x, const Eigen::VectorXd& dx, double alpha) const {
  if (edges_.empty() || alpha <= 0) return alpha;
  const auto local = local_positions(x);
  for (size_t k = 0; k < parts_.size(); ++k) {
    const ProfileView& P = views_[k];
    const Eigen::Matrix3d Rt = current_[k].R.transpose();
    for (size_t e = 0; e < edges_.size(); ++e) {
      const int a = edges_[e][0], b = edges_[e][1];
      const Eigen::Vector3d da = Rt * dx.segment<3>(3 * a), db = Rt * dx.segment<3>(3 * b);
      const double len = std::max(da.norm(), db.norm());
      if (len == 0) continue;
      const Eigen::Vector3d ya = local[k].segment<3>(3 * a), yb = local[k].segment<3>(3 * b);
      const Eigen::Vector3d ea = ya + alpha * da, eb = yb + alpha * db;
      const Eigen::Vector3d lo = ya.cwiseMin(yb).cwiseMin(ea).cwiseMin(eb), hi = ya.cwiseMax(yb).cwiseMax(ea).cwiseMax(eb);
      double L;
      const double bound = box_clearance_bound(P, lo.data(), hi.data(), &L);
      const double ends = std::min(piece_clearance(P, profile_piece(P, P.origin[2] - ya[2]), ya.data()),
                                   piece_clearance(P, profile_piece(P, P.origin[2] - yb[2]), yb.data()));
      if (bound > kCcdGapFraction * ends) continue;  // the whole move stays clear of the part
      const double d0 = segment_part_minimum(P, ya.data(), yb.data()).clearance;
      double t = 0;
      for (int it = 0; it < 64 && t < alpha; ++it) {
        const Eigen::Vector3d pa = ya + t * da, pb = yb + t * db;
        const double c = segment_part_minimum(P, pa.data(), pb.data()).clearance;
        if (!(c > kCcdGapFraction * d0)) break;
        t += (c - kCcdGapFraction * d0) / (L * len);
      }
      if (t < alpha && std::getenv("DRAPELAB_DEBUG_EDGES"))
        std::fprintf(stderr, "  edge step limited to %.3g by edge %zu part %zu: clearance %.3g, ends %.3g, L %.3g, move %.3g\n",
                     t, e, k, d0, ends, L, len);
      alpha = std::min(alpha, t);
    }
  }
  return alpha;
}

// The same on the relative motion of the body advancing along its rest (the cloth carried by u): in part k's
// frame each end moves at most at V_end (obstacle_max_advance), every point of the edge at most max(V_a, V_b)
// (|y'| is bounded by a convex function of the point's place on the edge).
double RevolvedBodyContact::edges_max_advance(const Eigen::VectorXd& x, const Eigen::VectorXd& u, double alpha) const {
  if (edges_.empty() || alpha <= 0) return alpha;
  const int nparts = static_cast<int>(parts_.size());
  const auto local = local_positions(x);
  const int nv = static_cast<int>(kappa_.size());
  for (int k = 0; k < nparts; ++k) {
    const ProfileView& P = views_[k];
    const RigidPose &a0 = current_[k], &b0 = end_[k];
    const Eigen::AngleAxisd rel(a0.R.transpose() * b0.R);
    const double angle = std::abs(rel.angle());
    const Eigen::Vector3d axis = a0.R * rel.axis() * (rel.angle() < 0 ? -1.0 : 1.0), shift = b0.c - a0.c;
    Eigen::VectorXd speed(nv);
    for (int i = 0; i < nv; ++i) {
      const Eigen::Vector3d rel_move = u.segment<3>(3 * i) - shift;
      const Eigen::Vector3d w0 = rel_move - angle * axis.cross(x.segment<3>(3 * i) - a0.c);
      speed[i] = w0.norm() + angle * rel_move.norm();
    }
    for (size_t e = 0; e < edges_.size(); ++e) {
      const int a = edges_[e][0], b = edges_[e][1];
      const double V = std::max(speed[a], speed[b]);
      if (V == 0) continue;
      const Eigen::Vector3d ya = local[k].segment<3>(3 * a), yb = local[k].segment<3>(3 * b);
      const Eigen::Vector3d pad = Eigen::Vector3d::Constant(alpha * V);
      const Eigen::Vector3d lo = ya.cwiseMin(yb) - pad, hi = ya.cwiseMax(yb) + pad;
      double L;
      const double bound = box_clearance_bound(P, lo.data(), hi.data(), &L);
      const double ends = std::min(piece_clearance(P, profile_piece(P, P.origin[2] - ya[2]), ya.data()),
                                   piece_clearance(P, profile_piece(P, P.origin[2] - yb[2]), yb.data()));
      if (bound > kCcdGapFraction * ends) continue;
      const double d0 = segment_part_minimum(P, ya.data(), yb.data()).clearance;
      const Eigen::Vector3d qa = x.segment<3>(3 * a), qb = x.segment<3>(3 * b);
      const Eigen::Vector3d ua = u.segment<3>(3 * a), ub = u.segment<3>(3 * b);
      double t = 0;
      for (int it = 0; it < 64 && t < alpha; ++it) {
        const RigidPose pose = interpolate(a0, b0, t);
        const Eigen::Vector3d pa = pose.R.transpose() * (qa + t * ua - pose.c);
        const Eigen::Vector3d pb = pose.R.transpose() * (qb + t * ub - pose.c);
        const double c = segment_part_minimum(P, pa.data(), pb.data()).clearance;
        if (!(c > kCcdGapFraction * d0)) break;
        t += (c - kCcdGapFraction * d0) / (L * V);
      }
      alpha = std::min(alpha, t);
    }
  }
  return alpha;
}

}  // namespace drapelab
