#include "contact/ccd.hpp"

#include <algorithm>
#include <cmath>

#include "contact/distance.hpp"

namespace drapelab {

namespace {
constexpr int kMaxIterations = 100000;

// Alg. 1 of ACCD for a pair of 4 points q (a point-triangle or edge-edge pair: split = how many belong to the
// first primitive), with displacements dq and the pair's distance function.
template <class Distance>
double additive_ccd(Eigen::Vector3d q[4], Eigen::Vector3d dq[4], int split, double s, const Distance& distance) {
  const Eigen::Vector3d mean = 0.25 * (dq[0] + dq[1] + dq[2] + dq[3]);
  double l0 = 0, l1 = 0;
  for (int k = 0; k < 4; ++k) {
    dq[k] -= mean;
    (k < split ? l0 : l1) = std::max(k < split ? l0 : l1, dq[k].norm());
  }
  const double lp = l0 + l1;
  double d = distance(q);
  if (!(d > 0)) return 0.0;
  if (lp == 0 || lp <= (1.0 - s) * d) return 1.0;  // the first safe advancement already covers [0, 1]
  const double gap = s * d;
  double t = 0, step = (1.0 - s) * d / lp;
  for (int it = 0; it < kMaxIterations; ++it) {
    for (int k = 0; k < 4; ++k) q[k] += step * dq[k];
    d = distance(q);
    if (t > 0 && d < gap) return t;
    t += step;
    if (t >= 1.0) return 1.0;
    step = 0.9 * d / lp;
  }
  return t;
}
}  // namespace

double point_triangle_unsigned_distance(const Eigen::Vector3d& p, const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                               const Eigen::Vector3d& c) {
  const double x[12] = {p[0], p[1], p[2], a[0], a[1], a[2], b[0], b[1], b[2], c[0], c[1], c[2]};
  return std::sqrt(std::max(0.0, point_triangle_distance2(point_triangle_type(p, a, b, c), x)));
}

double edge_edge_unsigned_distance(const Eigen::Vector3d& a0, const Eigen::Vector3d& b0, const Eigen::Vector3d& a1,
                          const Eigen::Vector3d& b1) {
  const double x[12] = {a0[0], a0[1], a0[2], b0[0], b0[1], b0[2], a1[0], a1[1], a1[2], b1[0], b1[1], b1[2]};
  return std::sqrt(std::max(0.0, edge_edge_distance2(edge_edge_type(a0, b0, a1, b1), x)));
}

double point_triangle_ccd(const Eigen::Vector3d& p, const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                          const Eigen::Vector3d& c, const Eigen::Vector3d& dp, const Eigen::Vector3d& da,
                          const Eigen::Vector3d& db, const Eigen::Vector3d& dc, double separation) {
  Eigen::Vector3d q[4] = {p, a, b, c}, dq[4] = {dp, da, db, dc};
  return additive_ccd(q, dq, 1, separation,
                      [](const Eigen::Vector3d* y) { return point_triangle_unsigned_distance(y[0], y[1], y[2], y[3]); });
}

double edge_edge_ccd(const Eigen::Vector3d& a0, const Eigen::Vector3d& b0, const Eigen::Vector3d& a1,
                     const Eigen::Vector3d& b1, const Eigen::Vector3d& da0, const Eigen::Vector3d& db0,
                     const Eigen::Vector3d& da1, const Eigen::Vector3d& db1, double separation) {
  Eigen::Vector3d q[4] = {a0, b0, a1, b1}, dq[4] = {da0, db0, da1, db1};
  return additive_ccd(q, dq, 2, separation,
                      [](const Eigen::Vector3d* y) { return edge_edge_unsigned_distance(y[0], y[1], y[2], y[3]); });
}

}  // namespace drapelab
