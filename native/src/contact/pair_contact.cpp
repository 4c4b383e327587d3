#include "contact/pair_contact.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

#include "contact/ccd.hpp"
#include "contact/diagnostics.hpp"
#include "physics/sparse_pattern.hpp"
#include "util/error.hpp"

namespace drapelab {

PairContactTerm::PairContactTerm(ContactSurfaces surfaces, int num_cloth, std::vector<double> unit_stiffness,
                                 PairFilter filter)
    : surfaces_(std::move(surfaces)),
      num_cloth_(num_cloth),
      obstacle_(surfaces_.num_vertices() - num_cloth, 3),
      unit_stiffness_(std::move(unit_stiffness)),
      filter_(filter) {
  obstacle_.setZero();
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

std::vector<ActivePair> PairContactTerm::active_pairs(const Eigen::VectorXd& x, double dh) const {
  if (!(dh > 0)) return {};
  {
    std::lock_guard<std::mutex> lock(cache_mutex_);
    if (cache_.dhat == dh && cache_.x.size() == x.size() && cache_.x == x && cache_.obstacle.rows() == obstacle_.rows() &&
        cache_.obstacle == obstacle_)
      return cache_.pairs;
  }
  const ContactPositions P = positions(x);
  const CandidatePairs c = broad_phase(surfaces_, P, nullptr, dh, filter_);
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
  auto consider = [&](PairKind kind, const std::array<int, 4>& v) {
    ActivePair q{kind, 0, v, stiffness(v)};
    double x12[12];
    gather(q, P, x12);
    q.type = pair_type(kind, x12);
    if (pair_distance2(kind, q.type, x12) < dh * dh) pairs.push_back(q);
  };
  for (const auto& pt : c.point_triangle) {
    const auto& f = surfaces_.faces[pt[1]];
    consider(PairKind::kPointTriangle, {pt[0], f[0], f[1], f[2]});
  }
  for (const auto& ee : c.edge_edge) {
    const auto &e = surfaces_.edges[ee[0]], &o = surfaces_.edges[ee[1]];
    consider(PairKind::kEdgeEdge, {e[0], e[1], o[0], o[1]});
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
    E += pair_barrier_energy(q.kind, q.type, x12, dh, q.c * dh);
  }
  return E;
}

void PairContactTerm::add_gradient(const Eigen::VectorXd& x, const Eigen::VectorXd& p, Eigen::VectorXd& g) const {
  const double dh = dhat(p);
  const ContactPositions P = positions(x);
  for (const auto& q : active_pairs(x, dh)) {
    double x12[12], g12[12];
    gather(q, P, x12);
    pair_barrier_gradient(q.kind, q.type, x12, dh, q.c * dh, g12);
    for (int k = 0; k < 4; ++k)
      if (q.v[k] < num_cloth_)
        for (int a = 0; a < 3; ++a) g[3 * q.v[k] + a] += g12[3 * k + a];
  }
}

template <class F>
void PairContactTerm::for_each_pair_hessian(const Eigen::VectorXd& x, const Eigen::VectorXd& p, bool project,
                                            const F& f) const {
  const double dh = dhat(p);
  const ContactPositions P = positions(x);
  for (const auto& q : active_pairs(x, dh)) {
    double x12[12], H[144];
    gather(q, P, x12);
    pair_barrier_hessian(q.kind, q.type, x12, dh, q.c * dh, project, H);
    f(q, H);
  }
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
}

void PairContactTerm::add_step_matrix(const Eigen::VectorXd& x, const Eigen::VectorXd& p, double scale,
                                      Eigen::VectorXd& values) const {
  add_diagonal_blocks(x, p, true, scale, values);
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
}

void PairContactTerm::add_energy_parameter_gradient(const Eigen::VectorXd& x, const Eigen::VectorXd& p,
                                                    Eigen::VectorXd& gp) const {
  const int k = dhat_index();
  if (k < 0) return;
  const double dh = dhat(p);
  const ContactPositions P = positions(x);
  for (const auto& q : active_pairs(x, dh)) {
    double x12[12], dg[12], dE;
    gather(q, P, x12);
    pair_barrier_dhat_derivatives(q.kind, q.type, x12, dh, q.c, dE, dg);
    gp[k] += dE;
  }
}

void PairContactTerm::add_gradient_parameter_product(const Eigen::VectorXd& x, const Eigen::VectorXd& p,
                                                     const Eigen::VectorXd& lambda, double scale,
                                                     Eigen::VectorXd& gp) const {
  const int k = dhat_index();
  if (k < 0) return;
  const double dh = dhat(p);
  const ContactPositions P = positions(x);
  double sum = 0;
  for (const auto& q : active_pairs(x, dh)) {
    double x12[12], dg[12], dE;
    gather(q, P, x12);
    pair_barrier_dhat_derivatives(q.kind, q.type, x12, dh, q.c, dE, dg);
    for (int m = 0; m < 4; ++m)
      if (q.v[m] < num_cloth_)
        for (int a = 0; a < 3; ++a) sum += lambda[3 * q.v[m] + a] * dg[3 * m + a];
  }
  gp[k] += scale * sum;
}

double PairContactTerm::max_step(const Eigen::VectorXd& x, const Eigen::VectorXd& dx, const Eigen::VectorXd& p) const {
  if (!(dhat(p) > 0)) return 1.0;
  const ContactPositions P0 = positions(x), P1 = positions(x + dx);
  const CandidatePairs c = broad_phase(surfaces_, P0, &P1, 0.0, filter_);
  const ContactPositions D = P1 - P0;
  double alpha = 1.0;
  for (const auto& pt : c.point_triangle) {
    const auto& f = surfaces_.faces[pt[1]];
    alpha = std::min(alpha, point_triangle_ccd(P0.row(pt[0]), P0.row(f[0]), P0.row(f[1]), P0.row(f[2]), D.row(pt[0]),
                                               D.row(f[0]), D.row(f[1]), D.row(f[2])));
  }
  for (const auto& ee : c.edge_edge) {
    const auto &e = surfaces_.edges[ee[0]], &o = surfaces_.edges[ee[1]];
    alpha = std::min(alpha, edge_edge_ccd(P0.row(e[0]), P0.row(e[1]), P0.row(o[0]), P0.row(o[1]), D.row(e[0]),
                                          D.row(e[1]), D.row(o[0]), D.row(o[1])));
  }
  return alpha;
}

void PairContactTerm::begin_step(const Eigen::VectorXd& x, const Eigen::VectorXd& p, double h) {
  if (!(dhat(p) > 0)) return;
  const ContactPositions P = positions(x);
  std::vector<std::array<int, 2>> first;
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
  if (first.empty()) return;
  int cloth_faces = 0;
  for (size_t f = 0; f < surfaces_.faces.size(); ++f) cloth_faces += surfaces_.face_group(static_cast<int>(f)) == 0;
  auto triangle = [&](int f) {
    std::ostringstream s;
    if (f < cloth_faces) s << "cloth triangle " << f;
    else s << "obstacle triangle " << f - cloth_faces;
    return s.str();
  };
  std::ostringstream s;
  s << name() << ": " << triangle(first[0][0]) << " and " << triangle(first[0][1])
    << " intersect at the start of a step (contact needs an intersection-free state)";
  throw SolverError(s.str());
}

}  // namespace drapelab
