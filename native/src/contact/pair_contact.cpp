#include "contact/pair_contact.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

#include "contact/barrier.hpp"
#include "contact/ccd.hpp"
#include "contact/distance.hpp"
#include "contact/diagnostics.hpp"
#include "physics/sparse_pattern.hpp"
#include "util/error.hpp"
#include "util/jet.hpp"

namespace drapelab {

namespace {
constexpr double kSlipSpeed = 1e-3;  // eps_v [m/s]: friction is smoothed below this slip speed (as disk_contact)
// Candidate pairs are found with boxes inflated by dhat (1 + 2 margin) and reused while no vertex moves more
// than margin * dhat (line-search trials and Newton iterations near convergence move far less).
constexpr double kCandidateMargin = 1.0;
// max_step's swept broad phase also gives the candidates of every state along its segment (the next iterate and
// the next step's start lie on it), found with the boxes inflated by dhat (1 + 2 this margin).
constexpr double kSweepCandidateMargin = 0.25;
constexpr double kMollifierScale = 1e-3;
// An obstacle move that brings a pair within this fraction of its start distance counts as passing through.
constexpr double kSweepSeparation = 1e-3;  // edge-edge mollifier eps = this |e0_rest|^2 |e1_rest|^2 (IPC's choice)

template <class T>
T segment_parameter(const T* p, const T* a, const T* b) {
  T pe(0.0), ee(0.0);
  for (int k = 0; k < 3; ++k) {
    pe = pe + (p[k] - a[k]) * (b[k] - a[k]);
    ee = ee + (b[k] - a[k]) * (b[k] - a[k]);
  }
  if (!(value_of(ee) > 0)) return T(0.0);
  const T t = pe / ee;
  if (value_of(t) <= 0) return T(0.0);
  if (value_of(t) >= 1) return T(1.0);
  return t;
}

template <class T>
T dot3(const T* a, const T* b) {
  return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

// Weights of the pair's 4 vertices whose combination is (closest point of the first primitive) - (closest point
// of the second), by closest-feature type; templated for the lagged friction's x_t-derivatives.
template <class T>
std::array<T, 4> closest_weights(PairKind kind, int type, const T* x) {
  const T *q0 = x, *q1 = x + 3, *q2 = x + 6, *q3 = x + 9;
  const T one(1.0), zero(0.0);
  if (kind == PairKind::kPointTriangle) {
    switch (static_cast<PointTriangleType>(type)) {
      case PointTriangleType::kA: return {one, -one, zero, zero};
      case PointTriangleType::kB: return {one, zero, -one, zero};
      case PointTriangleType::kC: return {one, zero, zero, -one};
      case PointTriangleType::kAB: { const T t = segment_parameter(q0, q1, q2); return {one, -(1.0 - t), -t, zero}; }
      case PointTriangleType::kBC: { const T t = segment_parameter(q0, q2, q3); return {one, zero, -(1.0 - t), -t}; }
      case PointTriangleType::kCA: { const T t = segment_parameter(q0, q3, q1); return {one, -t, zero, -(1.0 - t)}; }
      case PointTriangleType::kFace: break;
    }
    T e0[3], e1[3], w[3];
    for (int k = 0; k < 3; ++k) {
      e0[k] = q2[k] - q1[k];
      e1[k] = q3[k] - q1[k];
      w[k] = q0[k] - q1[k];
    }
    const T d00 = dot3(e0, e0), d01 = dot3(e0, e1), d11 = dot3(e1, e1), d20 = dot3(w, e0), d21 = dot3(w, e1);
    const T den = d00 * d11 - d01 * d01;
    const T v = (d11 * d20 - d01 * d21) / den, t = (d00 * d21 - d01 * d20) / den;
    return {one, -(1.0 - v - t), -v, -t};
  }
  switch (static_cast<EdgeEdgeType>(type)) {
    case EdgeEdgeType::kA0_E1: { const T t = segment_parameter(q0, q2, q3); return {one, zero, -(1.0 - t), -t}; }
    case EdgeEdgeType::kB0_E1: { const T t = segment_parameter(q1, q2, q3); return {zero, one, -(1.0 - t), -t}; }
    case EdgeEdgeType::kA1_E0: { const T s = segment_parameter(q2, q0, q1); return {1.0 - s, s, -one, zero}; }
    case EdgeEdgeType::kB1_E0: { const T s = segment_parameter(q3, q0, q1); return {1.0 - s, s, zero, -one}; }
    case EdgeEdgeType::kA0_A1: return {one, zero, -one, zero};
    case EdgeEdgeType::kA0_B1: return {one, zero, zero, -one};
    case EdgeEdgeType::kB0_A1: return {zero, one, -one, zero};
    case EdgeEdgeType::kB0_B1: return {zero, one, zero, -one};
    case EdgeEdgeType::kLineLine: break;
  }
  T e0[3], e1[3], w[3];
  for (int k = 0; k < 3; ++k) {
    e0[k] = q1[k] - q0[k];
    e1[k] = q3[k] - q2[k];
    w[k] = q0[k] - q2[k];
  }
  const T a = dot3(e0, e0), b = dot3(e0, e1), c = dot3(e1, e1), d = dot3(e0, w), e = dot3(e1, w);
  const T den = a * c - b * b;
  const T sp = (b * e - c * d) / den, tp = (a * e - b * d) / den;
  return {1.0 - sp, sp, -(1.0 - tp), -tp};
}

// IPC's edge-edge mollifier (contact/pair_barrier.cpp), templated.
template <class T>
T edge_mollifier(const T* x, double eps) {
  T e0[3], e1[3];
  for (int k = 0; k < 3; ++k) {
    e0[k] = x[3 + k] - x[k];
    e1[k] = x[9 + k] - x[6 + k];
  }
  const T n[3] = {e0[1] * e1[2] - e0[2] * e1[1], e0[2] * e1[0] - e0[0] * e1[2], e0[0] * e1[1] - e0[1] * e1[0]};
  const T c = dot3(n, n);
  if (value_of(c) >= eps) return T(1.0);
  const T s = c / eps;
  return (2.0 - s) * s;
}
}  // namespace

PairContactTerm::PairContactTerm(ContactSurfaces surfaces, int num_cloth, std::vector<double> unit_stiffness,
                                 PairFilter filter, const ContactPositions& rest)
    : surfaces_(std::move(surfaces)),
      num_cloth_(num_cloth),
      obstacle_(surfaces_.num_vertices() - num_cloth, 3),
      unit_stiffness_(std::move(unit_stiffness)),
      filter_(filter) {
  obstacle_.setZero();
  obstacle_start_ = obstacle_;
  for (const auto& e : surfaces_.edges) edge_rest_length2_.push_back((rest.row(e[0]) - rest.row(e[1])).squaredNorm());
}

void PairContactTerm::bind_pattern(const SparsePattern& pattern) {
  diagonal_index_.resize(num_cloth_);
  for (int i = 0; i < num_cloth_; ++i) {
    int k = 0;
    for (int a = 0; a < 3; ++a)
      for (int b = a; b < 3; ++b) diagonal_index_[i][k++] = pattern.index(3 * i + a, 3 * i + b);
  }
}

ContactPositions PairContactTerm::positions(const Eigen::VectorXd& x) const {
  ContactPositions P(surfaces_.num_vertices(), 3);
  for (int i = 0; i < num_cloth_; ++i) P.row(i) = x.segment<3>(3 * i).transpose();
  if (obstacle_.rows() > 0) P.bottomRows(obstacle_.rows()) = obstacle_;
  return P;
}

void PairContactTerm::gather(const ActivePair& q, const ContactPositions& P, double* x12) const {
  for (int k = 0; k < 4; ++k)
    for (int a = 0; a < 3; ++a) x12[3 * k + a] = P(q.v[k], a);
}

bool PairContactTerm::candidates_valid(const Cache& c, const Eigen::VectorXd& x, double dh) const {
  if (!c.candidates || c.candidate_dhat != dh || c.candidate_x.size() != x.size() ||
      c.candidate_obstacle.rows() != obstacle_.rows() || !(c.candidate_obstacle == obstacle_))
    return false;
  const int n = 3 * num_cloth_;
  // The segment's point nearest to x (any point of it would do: this one is exactly x's for the iterates and
  // step ends max_step swept to).
  double s = 0;
  if (c.candidate_dx.size() == x.size()) {
    const double dd = c.candidate_dx.head(n).squaredNorm();
    if (dd > 0) s = std::clamp((x.head(n) - c.candidate_x.head(n)).dot(c.candidate_dx.head(n)) / dd, 0.0, 1.0);
  }
  const double margin = c.candidate_margin * dh;
  for (int i = 0; i < num_cloth_; ++i) {
    Eigen::Vector3d d = x.segment<3>(3 * i) - c.candidate_x.segment<3>(3 * i);
    if (s != 0) d -= s * c.candidate_dx.segment<3>(3 * i);
    if (d.squaredNorm() > margin * margin) return false;
  }
  return true;
}

std::vector<ActivePair> PairContactTerm::active_pairs(const Eigen::VectorXd& x, double dh) const {
  if (!(dh > 0)) return {};
  {
    std::lock_guard<std::mutex> lock(cache_mutex_);
    if (cache_.dhat == dh && cache_.x.size() == x.size() && cache_.x == x && cache_.obstacle.rows() == obstacle_.rows() &&
        cache_.obstacle == obstacle_)
      return cache_.pairs;
  }
  const ContactPositions P = positions(x);
  // Candidates: reused while every cloth vertex is within the candidates' margin of where they were found (a
  // point, or a segment swept by max_step); else found again here, with the boxes inflated by
  // dhat (1 + 2 kCandidateMargin): a box moves by at most the margin, so every pair closer than dhat now was a
  // candidate then.
  std::shared_ptr<const CandidatePairs> candidates;
  {
    std::lock_guard<std::mutex> lock(cache_mutex_);
    if (candidates_valid(cache_, x, dh)) candidates = cache_.candidates;
  }
  if (!candidates) {
    candidates = std::make_shared<const CandidatePairs>(
        broad_phase(surfaces_, P, nullptr, dh * (1 + 2 * kCandidateMargin), filter_));
    std::lock_guard<std::mutex> lock(cache_mutex_);
    cache_.candidates = candidates;
    cache_.candidate_x = x;
    cache_.candidate_dx.resize(0);
    cache_.candidate_obstacle = obstacle_;
    cache_.candidate_dhat = dh;
    cache_.candidate_margin = kCandidateMargin;
  }
  const CandidatePairs& c = *candidates;
  std::vector<ActivePair> pairs;
  auto stiffness = [&](const std::array<int, 4>& v) {
    double sum = 0;
    int n = 0;
    for (int i : v)
      if (i < num_cloth_) {
        sum += unit_stiffness_[i];
        ++n;
      }
    return n > 0 ? sum / n : 0.0;
  };
  auto consider = [&](PairKind kind, const std::array<int, 4>& v, double eps) {
    ActivePair q{kind, 0, v, stiffness(v), eps};
    double x12[12];
    gather(q, P, x12);
    q.type = pair_type(kind, x12);
    if (pair_distance2(kind, q.type, x12) < dh * dh) pairs.push_back(q);
  };
  for (const auto& pt : c.point_triangle) {
    const auto& f = surfaces_.faces[pt[1]];
    consider(PairKind::kPointTriangle, {pt[0], f[0], f[1], f[2]}, 0.0);
  }
  for (const auto& ee : c.edge_edge) {
    const auto &e = surfaces_.edges[ee[0]], &o = surfaces_.edges[ee[1]];
    consider(PairKind::kEdgeEdge, {e[0], e[1], o[0], o[1]},
             kMollifierScale * edge_rest_length2_[ee[0]] * edge_rest_length2_[ee[1]]);
  }
  std::lock_guard<std::mutex> lock(cache_mutex_);
  cache_.x = x;
  cache_.obstacle = obstacle_;
  cache_.dhat = dh;
  cache_.pairs = pairs;
  return pairs;
}

double PairContactTerm::energy(const Eigen::VectorXd& x, const Eigen::VectorXd& p) const {
  const double dh = dhat(p);
  const ContactPositions P = positions(x);
  double E = 0;
  for (const auto& q : active_pairs(x, dh)) {
    double x12[12];
    gather(q, P, x12);
    E += pair_barrier_energy(q.kind, q.type, x12, dh, q.c * dh, q.mollifier_eps);
  }
  const double mu = friction(p);
  for (const auto& f : friction_pairs_) {
    double value;
    friction_kernel(f, x, &value, nullptr, nullptr);
    E += mu * f.normal_force * value;
  }
  return E;
}

void PairContactTerm::add_gradient(const Eigen::VectorXd& x, const Eigen::VectorXd& p, Eigen::VectorXd& g) const {
  const double dh = dhat(p);
  const ContactPositions P = positions(x);
  for (const auto& q : active_pairs(x, dh)) {
    double x12[12], g12[12];
    gather(q, P, x12);
    pair_barrier_gradient(q.kind, q.type, x12, dh, q.c * dh, g12, q.mollifier_eps);
    for (int k = 0; k < 4; ++k)
      if (q.v[k] < num_cloth_)
        for (int a = 0; a < 3; ++a) g[3 * q.v[k] + a] += g12[3 * k + a];
  }
  const double mu = friction(p);
  for (const auto& f : friction_pairs_) {
    double g12[12];
    friction_kernel(f, x, nullptr, g12, nullptr);
    for (int k = 0; k < 4; ++k)
      if (f.v[k] < num_cloth_)
        for (int a = 0; a < 3; ++a) g[3 * f.v[k] + a] += mu * f.normal_force * g12[3 * k + a];
  }
}

template <class F>
void PairContactTerm::for_each_pair_hessian(const Eigen::VectorXd& x, const Eigen::VectorXd& p, bool project,
                                            const F& f) const {
  const double dh = dhat(p);
  const std::vector<ActivePair> pairs = active_pairs(x, dh);
  const std::shared_ptr<const std::vector<double>> H = pair_hessians(x, dh, project, pairs);
  for (size_t i = 0; i < pairs.size(); ++i) f(pairs[i], H->data() + 144 * i);
}

// The active pairs' Hessians (144 doubles each, in active_pairs order), cached per exact x, dhat, obstacle and
// projection: a Newton iteration assembles them once and then applies them in every conjugate-gradient product
// (solver/contact_linear_solve.hpp), which otherwise recomputed them (jets and 12 x 12 eigen-decompositions) in
// each product: on a folding garment most of a step's time.
namespace {
bool same_pairs(const std::vector<ActivePair>& a, const std::vector<ActivePair>& b) {
  if (a.size() != b.size()) return false;
  for (size_t i = 0; i < a.size(); ++i)
    if (a[i].v != b[i].v || a[i].kind != b[i].kind || a[i].type != b[i].type || a[i].c != b[i].c ||
        a[i].mollifier_eps != b[i].mollifier_eps)
      return false;
  return true;
}
}  // namespace

std::shared_ptr<const std::vector<double>> PairContactTerm::pair_hessians(const Eigen::VectorXd& x, double dh,
                                                                          bool project,
                                                                          const std::vector<ActivePair>& pairs) const {
  HessianCache& c = hessian_cache_[project ? 1 : 0];
  {
    std::lock_guard<std::mutex> lock(hessian_mutex_);
    if (c.hessians && c.dhat == dh && c.x.size() == x.size() && c.x == x && c.obstacle.rows() == obstacle_.rows() &&
        c.obstacle == obstacle_ && same_pairs(c.pairs, pairs))
      return c.hessians;
  }
  const ContactPositions P = positions(x);
  auto H = std::make_shared<std::vector<double>>(144 * pairs.size());
  for (size_t i = 0; i < pairs.size(); ++i) {
    const ActivePair& q = pairs[i];
    double x12[12];
    gather(q, P, x12);
    pair_barrier_hessian(q.kind, q.type, x12, dh, q.c * dh, project, H->data() + 144 * i, q.mollifier_eps);
  }
  std::lock_guard<std::mutex> lock(hessian_mutex_);
  c.x = x;
  c.dhat = dh;
  c.obstacle = obstacle_;
  c.pairs = pairs;
  c.hessians = H;
  return H;
}

void PairContactTerm::add_diagonal_blocks(const Eigen::VectorXd& x, const Eigen::VectorXd& p, bool project,
                                          double scale, Eigen::VectorXd& values) const {
  for_each_pair_hessian(x, p, project, [&](const ActivePair& q, const double* H) {
    for (int k = 0; k < 4; ++k) {
      if (q.v[k] >= num_cloth_) continue;
      const auto& idx = diagonal_index_[q.v[k]];
      int m = 0;
      for (int a = 0; a < 3; ++a)
        for (int b = a; b < 3; ++b) values[idx[m++]] += scale * H[12 * (3 * k + a) + 3 * k + b];
    }
  });
  add_friction_blocks(x, p, scale, values);
}

void PairContactTerm::add_hessian(const Eigen::VectorXd& x, const Eigen::VectorXd& p, double scale,
                                  Eigen::VectorXd& values) const {
  add_diagonal_blocks(x, p, false, scale, values);
}
void PairContactTerm::add_projected_hessian(const Eigen::VectorXd& x, const Eigen::VectorXd& p, double scale,
                                            Eigen::VectorXd& values) const {
  add_diagonal_blocks(x, p, true, scale, values);
}

void PairContactTerm::add_hessian_product(const Eigen::VectorXd& x, const Eigen::VectorXd& p,
                                          const Eigen::VectorXd& dir, Eigen::VectorXd& out) const {
  for_each_pair_hessian(x, p, false, [&](const ActivePair& q, const double* H) {
    for (int k = 0; k < 4; ++k) {
      if (q.v[k] >= num_cloth_) continue;
      for (int l = 0; l < 4; ++l) {
        if (q.v[l] >= num_cloth_) continue;
        for (int a = 0; a < 3; ++a)
          for (int b = 0; b < 3; ++b) out[3 * q.v[k] + a] += H[12 * (3 * k + a) + 3 * l + b] * dir[3 * q.v[l] + b];
      }
    }
  });
  add_friction_product(x, p, dir, false, out);
}

void PairContactTerm::add_offpattern_hessian_product(const Eigen::VectorXd& x, const Eigen::VectorXd& p,
                                                     const Eigen::VectorXd& dir, bool projected,
                                                     Eigen::VectorXd& out) const {
  for_each_pair_hessian(x, p, projected, [&](const ActivePair& q, const double* H) {
    for (int k = 0; k < 4; ++k) {
      if (q.v[k] >= num_cloth_) continue;
      for (int l = 0; l < 4; ++l) {
        if (l == k || q.v[l] >= num_cloth_) continue;
        for (int a = 0; a < 3; ++a)
          for (int b = 0; b < 3; ++b) out[3 * q.v[k] + a] += H[12 * (3 * k + a) + 3 * l + b] * dir[3 * q.v[l] + b];
      }
    }
  });
  add_friction_product(x, p, dir, true, out);  // the friction Hessian is PSD: exact = projected
}

void PairContactTerm::add_energy_parameter_gradient(const Eigen::VectorXd& x, const Eigen::VectorXd& p,
                                                    Eigen::VectorXd& gp) const {
  if (friction_index() >= 0)
    for (const auto& f : friction_pairs_) {
      double value;
      friction_kernel(f, x, &value, nullptr, nullptr);
      gp[friction_index()] += f.normal_force * value;
    }
  const int k = dhat_index();
  if (k < 0) return;
  const double dh = dhat(p);
  const ContactPositions P = positions(x);
  for (const auto& q : active_pairs(x, dh)) {
    double x12[12], dg[12], dE;
    gather(q, P, x12);
    pair_barrier_dhat_derivatives(q.kind, q.type, x12, dh, q.c, dE, dg, q.mollifier_eps);
    gp[k] += dE;
  }
}

void PairContactTerm::add_gradient_parameter_product(const Eigen::VectorXd& x, const Eigen::VectorXd& p,
                                                     const Eigen::VectorXd& lambda, double scale,
                                                     Eigen::VectorXd& gp) const {
  if (friction_index() >= 0)
    for (const auto& f : friction_pairs_) {
      double g12[12], sum = 0;
      friction_kernel(f, x, nullptr, g12, nullptr);
      for (int m = 0; m < 4; ++m)
        if (f.v[m] < num_cloth_)
          for (int a = 0; a < 3; ++a) sum += lambda[3 * f.v[m] + a] * g12[3 * m + a];
      gp[friction_index()] += scale * f.normal_force * sum;
    }
  const int k = dhat_index();
  if (k < 0) return;
  const double dh = dhat(p);
  const ContactPositions P = positions(x);
  double sum = 0;
  for (const auto& q : active_pairs(x, dh)) {
    double x12[12], dg[12], dE;
    gather(q, P, x12);
    pair_barrier_dhat_derivatives(q.kind, q.type, x12, dh, q.c, dE, dg, q.mollifier_eps);
    for (int m = 0; m < 4; ++m)
      if (q.v[m] < num_cloth_)
        for (int a = 0; a < 3; ++a) sum += lambda[3 * q.v[m] + a] * dg[3 * m + a];
  }
  gp[k] += scale * sum;
}

double PairContactTerm::max_step(const Eigen::VectorXd& x, const Eigen::VectorXd& dx, const Eigen::VectorXd& p) const {
  const double dh = dhat(p);
  if (!(dh > 0)) return 1.0;
  const ContactPositions P0 = positions(x), P1 = positions(x + dx);
  // One swept broad phase, inflated: its pairs whose uninflated swept boxes overlap go to CCD, and all of them
  // are the candidates of the active pairs anywhere along the segment (the next iterate, the next step's start).
  auto candidates = std::make_shared<const CandidatePairs>(
      broad_phase(surfaces_, P0, &P1, dh * (1 + 2 * kSweepCandidateMargin), filter_));
  const ContactPositions D = P1 - P0;
  auto swept_boxes_overlap = [&](const int* a, int na, const int* b, int nb) {
    for (int k = 0; k < 3; ++k) {
      double alo = INFINITY, ahi = -INFINITY, blo = INFINITY, bhi = -INFINITY;
      for (int i = 0; i < na; ++i) {
        alo = std::min({alo, P0(a[i], k), P1(a[i], k)});
        ahi = std::max({ahi, P0(a[i], k), P1(a[i], k)});
      }
      for (int i = 0; i < nb; ++i) {
        blo = std::min({blo, P0(b[i], k), P1(b[i], k)});
        bhi = std::max({bhi, P0(b[i], k), P1(b[i], k)});
      }
      if (ahi < blo || bhi < alo) return false;
    }
    return true;
  };
  double alpha = 1.0;
  for (const auto& pt : candidates->point_triangle) {
    const auto& f = surfaces_.faces[pt[1]];
    if (!swept_boxes_overlap(&pt[0], 1, f.data(), 3)) continue;
    alpha = std::min(alpha, point_triangle_ccd(P0.row(pt[0]), P0.row(f[0]), P0.row(f[1]), P0.row(f[2]), D.row(pt[0]),
                                               D.row(f[0]), D.row(f[1]), D.row(f[2])));
  }
  for (const auto& ee : candidates->edge_edge) {
    const auto &e = surfaces_.edges[ee[0]], &o = surfaces_.edges[ee[1]];
    if (!swept_boxes_overlap(e.data(), 2, o.data(), 2)) continue;
    alpha = std::min(alpha, edge_edge_ccd(P0.row(e[0]), P0.row(e[1]), P0.row(o[0]), P0.row(o[1]), D.row(e[0]),
                                          D.row(e[1]), D.row(o[0]), D.row(o[1])));
  }
  std::lock_guard<std::mutex> lock(cache_mutex_);
  cache_.candidates = std::move(candidates);
  cache_.candidate_x = x;
  cache_.candidate_dx = dx;
  cache_.candidate_obstacle = obstacle_;
  cache_.candidate_dhat = dh;
  cache_.candidate_margin = kSweepCandidateMargin;
  return alpha;
}

struct PairContactTerm::SavedStep {
  std::vector<FrictionPair> friction;
  double eps_u;
  Cache cache;
};

std::shared_ptr<const void> PairContactTerm::step_state() const {
  auto s = std::make_shared<SavedStep>();
  s->friction = friction_pairs_;
  s->eps_u = eps_u_;
  std::lock_guard<std::mutex> lock(cache_mutex_);
  s->cache = cache_;
  return s;
}

void PairContactTerm::restore_step(const std::shared_ptr<const void>& state) {
  const auto& s = *static_cast<const SavedStep*>(state.get());
  friction_pairs_ = s.friction;
  eps_u_ = s.eps_u;
  std::lock_guard<std::mutex> lock(cache_mutex_);
  cache_ = s.cache;
}

struct PairContactTerm::SavedIterate {
  ContactPositions obstacle;
  double dhat;
  std::vector<ActivePair> pairs;
};

std::shared_ptr<const void> PairContactTerm::iterate_state(const Eigen::VectorXd& x) const {
  std::lock_guard<std::mutex> lock(cache_mutex_);
  if (!(cache_.dhat > 0) || cache_.x.size() != x.size() || !(cache_.x == x)) return nullptr;
  auto s = std::make_shared<SavedIterate>();
  s->obstacle = cache_.obstacle;
  s->dhat = cache_.dhat;
  s->pairs = cache_.pairs;
  return s;
}

void PairContactTerm::restore_iterate(const std::shared_ptr<const void>& state, const Eigen::VectorXd& x) {
  const auto& s = *static_cast<const SavedIterate*>(state.get());
  std::lock_guard<std::mutex> lock(cache_mutex_);
  cache_.x = x;
  cache_.obstacle = s.obstacle;
  cache_.dhat = s.dhat;
  cache_.pairs = s.pairs;
}

void PairContactTerm::start_step(const Eigen::VectorXd& x, const Eigen::VectorXd& p, double h,
                                 bool check_intersections, bool check_sweep) {
  friction_pairs_.clear();
  eps_u_ = kSlipSpeed * h;
  if (!(dhat(p) > 0)) return;
  const ContactPositions P = positions(x);
  std::vector<std::array<int, 2>> first;
  if (check_intersections) {  // the state must be free of intersections (see begin_step, continue_step)
    for (const auto& q : triangle_pairs(surfaces_, P, 0.0, filter_)) {
      Eigen::Vector3d t0[3], t1[3];
      for (int k = 0; k < 3; ++k) {
        t0[k] = P.row(surfaces_.faces[q[0]][k]);
        t1[k] = P.row(surfaces_.faces[q[1]][k]);
      }
      if (triangles_intersect(t0, t1)) {
        first.push_back(q);
        break;
      }
    }
  }
  if (!first.empty()) throw_intersection(first[0]);
  if (check_sweep) check_obstacle_sweep(x);
  if (!(h > 0)) return;  // a static drape: no friction
  // Lagged friction: each active pair's normal force, closest-point weights and normal at the step's start.
  const double dh = dhat(p);
  for (const auto& q : active_pairs(x, dh)) {
    double x12[12];
    gather(q, P, x12);
    const double d = std::sqrt(pair_distance2(q.kind, q.type, x12));
    if (!(d > 0 && d < dh)) continue;
    double b, db, d2b;
    barrier_derivatives(d, dh, b, db, d2b);
    FrictionPair f;
    f.v = q.v;
    f.kind = q.kind;
    f.type = q.type;
    f.c = q.c;
    f.dhat = dh;
    f.mollifier_eps = q.mollifier_eps;
    f.normal_force = q.c * dh * std::abs(db) * pair_mollifier(q.kind, x12, q.mollifier_eps);
    if (!(f.normal_force > 0)) continue;
    const std::array<double, 4> w = closest_weights(q.kind, q.type, x12);
    Eigen::Vector3d r = Eigen::Vector3d::Zero();
    for (int k = 0; k < 4; ++k) r += w[k] * Eigen::Map<const Eigen::Vector3d>(x12 + 3 * k);
    if (!(r.norm() > 0)) continue;
    const Eigen::Vector3d n = r.normalized();
    const Eigen::Matrix3d proj = Eigen::Matrix3d::Identity() - n * n.transpose();
    for (int k = 0; k < 4; ++k) {
      f.T.block<3, 3>(0, 3 * k) = w[k] * proj;
      f.start.segment<3>(3 * k) =
          q.v[k] < num_cloth_ ? Eigen::Vector3d(x.segment<3>(3 * q.v[k])) : Eigen::Vector3d(obstacle_start_.row(q.v[k] - num_cloth_).transpose());
    }
    friction_pairs_.push_back(f);
  }
}

void PairContactTerm::check_obstacle_sweep(const Eigen::VectorXd& x) const {
  if (obstacle_.rows() == 0 || obstacle_start_ == obstacle_) return;
  // The obstacle's move over the step against the cloth held at x: a pair that comes within kSweepSeparation of
  // its start distance means the body reaches (or passes) through the cloth within one step.
  ContactPositions P0 = positions(x);
  P0.bottomRows(obstacle_.rows()) = obstacle_start_;
  const ContactPositions P1 = positions(x), D = P1 - P0;
  const CandidatePairs c = broad_phase(surfaces_, P0, &P1, 0.0, PairFilter::kCross);
  auto fail = [&](const char* kind, int a, int b) {
    std::ostringstream s;
    s << name() << ": the obstacle moves through the cloth within one step (" << kind << " " << a << ", " << b
      << "); substep the obstacle's motion";
    throw SolverError(s.str());
  };
  for (const auto& pt : c.point_triangle) {
    const auto& f = surfaces_.faces[pt[1]];
    if (point_triangle_ccd(P0.row(pt[0]), P0.row(f[0]), P0.row(f[1]), P0.row(f[2]), D.row(pt[0]), D.row(f[0]),
                           D.row(f[1]), D.row(f[2]), kSweepSeparation) < 1.0)
      fail("vertex, triangle", pt[0], pt[1]);
  }
  for (const auto& ee : c.edge_edge) {
    const auto &e = surfaces_.edges[ee[0]], &o = surfaces_.edges[ee[1]];
    if (edge_edge_ccd(P0.row(e[0]), P0.row(e[1]), P0.row(o[0]), P0.row(o[1]), D.row(e[0]), D.row(e[1]), D.row(o[0]),
                      D.row(o[1]), kSweepSeparation) < 1.0)
      fail("edges", ee[0], ee[1]);
  }
}

void PairContactTerm::throw_intersection(const std::array<int, 2>& pair) const {
  int cloth_faces = 0;
  for (size_t f = 0; f < surfaces_.faces.size(); ++f) cloth_faces += surfaces_.face_group(static_cast<int>(f)) == 0;
  auto triangle = [&](int f) {
    std::ostringstream s;
    if (f < cloth_faces) s << "cloth triangle " << f;
    else s << "obstacle triangle " << f - cloth_faces;
    return s.str();
  };
  std::ostringstream s;
  s << name() << ": " << triangle(pair[0]) << " and " << triangle(pair[1])
    << " intersect at the start of a step (contact needs an intersection-free state)";
  throw SolverError(s.str());
}

Eigen::Vector3d PairContactTerm::slip(const FrictionPair& f, const Eigen::VectorXd& x) const {
  Eigen::Matrix<double, 12, 1> X;
  for (int k = 0; k < 4; ++k)
    X.segment<3>(3 * k) = f.v[k] < num_cloth_ ? Eigen::Vector3d(x.segment<3>(3 * f.v[k]))
                                              : Eigen::Vector3d(obstacle_.row(f.v[k] - num_cloth_).transpose());
  return f.T * (X - f.start);
}

void PairContactTerm::friction_kernel(const FrictionPair& f, const Eigen::VectorXd& x, double* value, double* g,
                                      double* H) const {
  const Eigen::Vector3d r = slip(f, x);
  const double u2 = r.squaredNorm(), eps = eps_u_;
  // D / (mu lambda) = f0(|r|): smooth in u^2 near zero slip (as disk_contact's friction)
  const bool tiny = u2 < 1e-20 * eps * eps;
  const double u = std::sqrt(u2);
  if (value) value[0] = tiny ? eps / 3.0 + u2 / eps : friction_f0(u, eps);
  double f1_over_u, df1;
  if (tiny) {
    f1_over_u = 2.0 / eps;
    df1 = 2.0 / eps;
  } else if (u >= eps) {
    f1_over_u = 1.0 / u;
    df1 = 0.0;
  } else {
    f1_over_u = -u / (eps * eps) + 2.0 / eps;
    df1 = -2.0 * u / (eps * eps) + 2.0 / eps;
  }
  if (g) {
    Eigen::Map<Eigen::Matrix<double, 12, 1>> gm(g);
    gm = f.T.transpose() * (f1_over_u * r);
  }
  if (H) {
    // S = f1/u (I - r r^T/u^2) + f1' r r^T/u^2 (PSD); H = T^T S T
    Eigen::Matrix3d S = f1_over_u * Eigen::Matrix3d::Identity();
    if (!tiny) S += (df1 - f1_over_u) * r * r.transpose() / u2;
    Eigen::Map<Eigen::Matrix<double, 12, 12, Eigen::RowMajor>> Hm(H);
    Hm = f.T.transpose() * S * f.T;
  }
}

void PairContactTerm::add_friction_blocks(const Eigen::VectorXd& x, const Eigen::VectorXd& p, double scale,
                                          Eigen::VectorXd& values) const {
  const double mu = friction(p);
  if (mu == 0) return;
  for (const auto& f : friction_pairs_) {
    double H[144];
    friction_kernel(f, x, nullptr, nullptr, H);
    for (int k = 0; k < 4; ++k) {
      if (f.v[k] >= num_cloth_) continue;
      const auto& idx = diagonal_index_[f.v[k]];
      int m = 0;
      for (int a = 0; a < 3; ++a)
        for (int b = a; b < 3; ++b) values[idx[m++]] += scale * mu * f.normal_force * H[12 * (3 * k + a) + 3 * k + b];
    }
  }
}

void PairContactTerm::add_friction_product(const Eigen::VectorXd& x, const Eigen::VectorXd& p, const Eigen::VectorXd& dir,
                                           bool offpattern_only, Eigen::VectorXd& out) const {
  const double mu = friction(p);
  if (mu == 0) return;
  for (const auto& f : friction_pairs_) {
    double H[144];
    friction_kernel(f, x, nullptr, nullptr, H);
    const double s = mu * f.normal_force;
    for (int k = 0; k < 4; ++k) {
      if (f.v[k] >= num_cloth_) continue;
      for (int l = 0; l < 4; ++l) {
        if ((offpattern_only && l == k) || f.v[l] >= num_cloth_) continue;
        for (int a = 0; a < 3; ++a)
          for (int b = 0; b < 3; ++b) out[3 * f.v[k] + a] += s * H[12 * (3 * k + a) + 3 * l + b] * dir[3 * f.v[l] + b];
      }
    }
  }
}

// The step matrix (Gauss-Newton barrier + exact friction Hessian, both PSD per pair): K = sum s r r^T + friction.
template <class F>
void PairContactTerm::for_each_pair_gauss_newton(const Eigen::VectorXd& x, const Eigen::VectorXd& p,
                                                 const F& f) const {
  const double dh = dhat(p);
  const ContactPositions P = positions(x);
  for (const auto& q : active_pairs(x, dh)) {
    double x12[12], r[12], s;
    gather(q, P, x12);
    pair_barrier_gauss_newton(q.kind, q.type, x12, dh, q.c * dh, r, s, q.mollifier_eps);
    if (s != 0) f(q, r, s);
  }
}

void PairContactTerm::add_step_matrix(const Eigen::VectorXd& x, const Eigen::VectorXd& p, double scale,
                                      Eigen::VectorXd& values) const {
  for_each_pair_gauss_newton(x, p, [&](const ActivePair& q, const double* r, double s) {
    for (int k = 0; k < 4; ++k) {
      if (q.v[k] >= num_cloth_) continue;
      const auto& idx = diagonal_index_[q.v[k]];
      int m = 0;
      for (int a = 0; a < 3; ++a)
        for (int b = a; b < 3; ++b) values[idx[m++]] += scale * s * r[3 * k + a] * r[3 * k + b];
    }
  });
  add_friction_blocks(x, p, scale, values);
}

void PairContactTerm::add_offpattern_step_matrix_product(const Eigen::VectorXd& x, const Eigen::VectorXd& p,
                                                         const Eigen::VectorXd& dir, Eigen::VectorXd& out) const {
  for_each_pair_gauss_newton(x, p, [&](const ActivePair& q, const double* r, double s) {
    double rd[4] = {0, 0, 0, 0};  // r_k . dir_k per vertex
    for (int k = 0; k < 4; ++k)
      if (q.v[k] < num_cloth_)
        for (int a = 0; a < 3; ++a) rd[k] += r[3 * k + a] * dir[3 * q.v[k] + a];
    const double total = rd[0] + rd[1] + rd[2] + rd[3];
    for (int k = 0; k < 4; ++k)
      if (q.v[k] < num_cloth_)
        for (int a = 0; a < 3; ++a) out[3 * q.v[k] + a] += s * r[3 * k + a] * (total - rd[k]);
  });
  add_friction_product(x, p, dir, true, out);  // the friction part of K is its exact (PSD) Hessian
}

void PairContactTerm::add_step_matrix_derivatives(const Eigen::VectorXd& x, const Eigen::VectorXd& p,
                                                  const Eigen::VectorXd& lambda, const Eigen::VectorXd& w,
                                                  double scale, Eigen::VectorXd& gx, Eigen::VectorXd& gp) const {
  const double dh = dhat(p);
  const int k_dhat = dhat_index();
  auto pair_vector = [&](const std::array<int, 4>& v, const Eigen::VectorXd& src, double* out12) {
    for (int k = 0; k < 4; ++k)
      for (int a = 0; a < 3; ++a) out12[3 * k + a] = v[k] < num_cloth_ ? src[3 * v[k] + a] : 0.0;
  };
  if (dh > 0) {
    const ContactPositions P = positions(x);
    double gdhat = 0;
    for (const auto& q : active_pairs(x, dh)) {
      double x12[12], l12[12], w12[12], dphi[12], dphi_ddhat;
      gather(q, P, x12);
      pair_vector(q.v, lambda, l12);
      pair_vector(q.v, w, w12);
      pair_barrier_gauss_newton_derivatives(q.kind, q.type, x12, dh, q.c, l12, w12, dphi, dphi_ddhat,
                                            q.mollifier_eps);
      for (int k = 0; k < 4; ++k)
        if (q.v[k] < num_cloth_)
          for (int a = 0; a < 3; ++a) gx[3 * q.v[k] + a] += scale * dphi[3 * k + a];
      gdhat += dphi_ddhat;
    }
    if (k_dhat >= 0) gp[k_dhat] += scale * gdhat;
  }
  add_friction_step_matrix_derivatives(x, p, lambda, w, scale, gx, &gp);
}

void PairContactTerm::add_step_start_adjoint(const Eigen::VectorXd& x, const Eigen::VectorXd& p,
                                             const Eigen::VectorXd& lambda, const Eigen::VectorXd& w, double c,
                                             Eigen::VectorXd& gxt) const {
  if (friction_pairs_.empty() || friction(p) == 0) return;
  // the friction energy is a function of x - x_t: minus its x-derivatives
  Eigen::VectorXd d = Eigen::VectorXd::Zero(gxt.size());
  add_friction_product(x, p, lambda, false, d);
  if (c != 0) add_friction_step_matrix_derivatives(x, p, lambda, w, c, d, nullptr);
  gxt -= d;
  // The lagged quantities' x_t-dependence: lambda = c dhat |b'(d(X_t))| m(X_t), n and Gamma from X_t (12-variable
  // jets over the pair's start positions; the slip's own start, X - X_t, is held: it is the part above).
  const double mu = friction(p);
  using J = Jet<double, 12>;
  for (const auto& f : friction_pairs_) {
    J xs[12];
    for (int k = 0; k < 12; ++k) xs[k] = J(f.start[k], k);
    const J d2 = f.kind == PairKind::kPointTriangle
                     ? point_triangle_distance2(static_cast<PointTriangleType>(f.type), xs)
                     : edge_edge_distance2(static_cast<EdgeEdgeType>(f.type), xs);
    using std::sqrt;
    const J d = sqrt(d2);
    const J e = d - f.dhat;
    const J db = (-2.0 * e * log_of(d / f.dhat) - e * e / d) / (f.dhat * f.dhat);
    J force = -(f.c * f.dhat) * db;
    if (f.kind == PairKind::kEdgeEdge && f.mollifier_eps > 0) force = force * edge_mollifier(xs, f.mollifier_eps);
    const std::array<J, 4> wts = closest_weights(f.kind, f.type, xs);
    J r[3];
    for (int a = 0; a < 3; ++a) {
      r[a] = J(0.0);
      for (int k = 0; k < 4; ++k) r[a] = r[a] + wts[k] * xs[3 * k + a];
    }
    const J rn = sqrt(dot3(r, r));
    J nn[3];
    for (int a = 0; a < 3; ++a) nn[a] = r[a] / rn;
    // Gamma applied to the held slip X - X_t, to lambda and to w; then the projector
    double X[12], l12[12], w12[12];
    for (int k = 0; k < 4; ++k)
      for (int a = 0; a < 3; ++a) {
        const bool cloth = f.v[k] < num_cloth_;
        X[3 * k + a] = cloth ? x[3 * f.v[k] + a] : obstacle_(f.v[k] - num_cloth_, a);
        l12[3 * k + a] = cloth ? lambda[3 * f.v[k] + a] : 0.0;
        w12[3 * k + a] = cloth ? w[3 * f.v[k] + a] : 0.0;
      }
    J gd[3], gl[3], gw[3];
    for (int a = 0; a < 3; ++a) {
      gd[a] = gl[a] = gw[a] = J(0.0);
      for (int k = 0; k < 4; ++k) {
        gd[a] = gd[a] + wts[k] * (X[3 * k + a] - f.start[3 * k + a]);
        gl[a] = gl[a] + wts[k] * l12[3 * k + a];
        gw[a] = gw[a] + wts[k] * w12[3 * k + a];
      }
    }
    const J nd = dot3(nn, gd), nl = dot3(nn, gl), nw = dot3(nn, gw);
    J u[3], Tl[3], Tw[3];
    for (int a = 0; a < 3; ++a) {
      u[a] = gd[a] - nn[a] * nd;
      Tl[a] = gl[a] - nn[a] * nl;
      Tw[a] = gw[a] - nn[a] * nw;
    }
    const J u2 = dot3(u, u), lu = dot3(Tl, u), lw = dot3(Tl, Tw);
    const double eps = eps_u_;
    J phi;
    if (u2.a < 1e-20 * eps * eps) {
      phi = (2.0 / eps) * (lu + c * lw);
    } else {
      const J un = sqrt(u2), wu = dot3(Tw, u);
      J f1_over_u, df1;
      if (un.a >= eps) {
        f1_over_u = 1.0 / un;
        df1 = J(0.0);
      } else {
        f1_over_u = -un / (eps * eps) + 2.0 / eps;
        df1 = -2.0 * un / (eps * eps) + 2.0 / eps;
      }
      phi = f1_over_u * lu + c * (f1_over_u * (lw - lu * wu / u2) + df1 * lu * wu / u2);
    }
    const J total = mu * force * phi;
    for (int k = 0; k < 4; ++k)
      if (f.v[k] < num_cloth_)
        for (int a = 0; a < 3; ++a) gxt[3 * f.v[k] + a] += total.v[3 * k + a];
  }
}

void PairContactTerm::add_friction_step_matrix_derivatives(const Eigen::VectorXd& x, const Eigen::VectorXd& p,
                                                           const Eigen::VectorXd& lambda, const Eigen::VectorXd& w,
                                                           double scale, Eigen::VectorXd& gx,
                                                           Eigen::VectorXd* gp) const {
  auto pair_vector = [&](const std::array<int, 4>& v, const Eigen::VectorXd& src, double* out12) {
    for (int k = 0; k < 4; ++k)
      for (int a = 0; a < 3; ++a) out12[3 * k + a] = v[k] < num_cloth_ ? src[3 * v[k] + a] : 0.0;
  };
  // Friction: phi = mu lambda_f (T l)^T S(u) (T w), u = T (X - X_t) (lagged lambda_f, T held constant).
  const double mu = friction(p);
  for (const auto& f : friction_pairs_) {
    double l12[12], w12[12];
    pair_vector(f.v, lambda, l12);
    pair_vector(f.v, w, w12);
    const Eigen::Vector3d tl = f.T * Eigen::Map<const Eigen::Matrix<double, 12, 1>>(l12);
    const Eigen::Vector3d tw = f.T * Eigen::Map<const Eigen::Matrix<double, 12, 1>>(w12);
    const Eigen::Vector3d r = slip(f, x);
    using J = Jet<double, 3>;
    J u[3], S[9];
    for (int a = 0; a < 3; ++a) u[a] = J(r[a], a);
    friction_curvature(u, eps_u_, S);
    J phi(0.0);
    for (int a = 0; a < 3; ++a)
      for (int b = 0; b < 3; ++b) phi = phi + S[3 * a + b] * (tl[a] * tw[b]);
    const Eigen::Vector3d dphi_du(phi.v[0], phi.v[1], phi.v[2]);
    const Eigen::Matrix<double, 12, 1> dphi = f.T.transpose() * dphi_du;
    for (int k = 0; k < 4; ++k)
      if (f.v[k] < num_cloth_)
        for (int a = 0; a < 3; ++a) gx[3 * f.v[k] + a] += scale * mu * f.normal_force * dphi[3 * k + a];
    if (gp && friction_index() >= 0) (*gp)[friction_index()] += scale * f.normal_force * phi.a;
  }
}

}  // namespace drapelab
