#include "contact/distance.hpp"

#include <cmath>

namespace drapelab {

namespace {
// Parameter of the closest point of segment [a, b] to p, clamped to [0, 1].
double segment_parameter(const Eigen::Vector3d& p, const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  const Eigen::Vector3d e = b - a;
  const double ee = e.squaredNorm();
  if (ee <= 0) return 0;
  return std::clamp((p - a).dot(e) / ee, 0.0, 1.0);
}
double point_segment_distance2(const Eigen::Vector3d& p, const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  return (a + segment_parameter(p, a, b) * (b - a) - p).squaredNorm();
}
constexpr double kParallel = 1e-10;  // |e0 x e1|^2 / (|e0|^2 |e1|^2) below which two edges count as parallel
}  // namespace

PointTriangleType point_triangle_type(const Eigen::Vector3d& p, const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                                      const Eigen::Vector3d& c) {
  // Barycentric coordinates of p's projection onto the plane; inside: the face.
  const Eigen::Vector3d e0 = b - a, e1 = c - a, w = p - a;
  const double d00 = e0.dot(e0), d01 = e0.dot(e1), d11 = e1.dot(e1), d20 = w.dot(e0), d21 = w.dot(e1);
  const double den = d00 * d11 - d01 * d01;
  if (den > 0) {
    const double v = (d11 * d20 - d01 * d21) / den, t = (d00 * d21 - d01 * d20) / den;
    if (v >= 0 && t >= 0 && v + t <= 1) return PointTriangleType::kFace;
  }
  // Outside: the nearest of the three edges, as its interior or one of its ends.
  const Eigen::Vector3d* v[3] = {&a, &b, &c};
  const PointTriangleType edge_types[3] = {PointTriangleType::kAB, PointTriangleType::kBC, PointTriangleType::kCA};
  const PointTriangleType vertex_types[3] = {PointTriangleType::kA, PointTriangleType::kB, PointTriangleType::kC};
  double best = INFINITY;
  PointTriangleType type = PointTriangleType::kA;
  for (int k = 0; k < 3; ++k) {
    const Eigen::Vector3d &s = *v[k], &e = *v[(k + 1) % 3];
    const double t = segment_parameter(p, s, e);
    const double d2 = (s + t * (e - s) - p).squaredNorm();
    if (d2 < best) {
      best = d2;
      type = t <= 0 ? vertex_types[k] : (t >= 1 ? vertex_types[(k + 1) % 3] : edge_types[k]);
    }
  }
  return type;
}

EdgeEdgeType edge_edge_type(const Eigen::Vector3d& a0, const Eigen::Vector3d& b0, const Eigen::Vector3d& a1,
                            const Eigen::Vector3d& b1) {
  const Eigen::Vector3d e0 = b0 - a0, e1 = b1 - a1, w = a0 - a1;
  const double a = e0.dot(e0), b = e0.dot(e1), c = e1.dot(e1), d = e0.dot(w), e = e1.dot(w);
  const double den = a * c - b * b;
  if (den > kParallel * a * c) {
    const double s = (b * e - c * d) / den, t = (a * e - b * d) / den;
    if (s > 0 && s < 1 && t > 0 && t < 1) return EdgeEdgeType::kLineLine;
  }
  // The segment distance is attained at an endpoint of one edge: the nearest of the four point-segment pairs.
  struct Candidate {
    double d2;
    double t;  // parameter along the other edge
    EdgeEdgeType interior, at_a, at_b;
  };
  const Candidate cands[4] = {
      {point_segment_distance2(a0, a1, b1), segment_parameter(a0, a1, b1), EdgeEdgeType::kA0_E1, EdgeEdgeType::kA0_A1,
       EdgeEdgeType::kA0_B1},
      {point_segment_distance2(b0, a1, b1), segment_parameter(b0, a1, b1), EdgeEdgeType::kB0_E1, EdgeEdgeType::kB0_A1,
       EdgeEdgeType::kB0_B1},
      {point_segment_distance2(a1, a0, b0), segment_parameter(a1, a0, b0), EdgeEdgeType::kA1_E0, EdgeEdgeType::kA0_A1,
       EdgeEdgeType::kB0_A1},
      {point_segment_distance2(b1, a0, b0), segment_parameter(b1, a0, b0), EdgeEdgeType::kB1_E0, EdgeEdgeType::kA0_B1,
       EdgeEdgeType::kB0_B1},
  };
  int best = 0;
  for (int k = 1; k < 4; ++k)
    if (cands[k].d2 < cands[best].d2) best = k;
  const Candidate& q = cands[best];
  return q.t <= 0 ? q.at_a : (q.t >= 1 ? q.at_b : q.interior);
}

}  // namespace drapelab
