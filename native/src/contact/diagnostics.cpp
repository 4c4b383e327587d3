#include "contact/diagnostics.hpp"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>

#include "contact/ccd.hpp"

namespace drapelab {

namespace {
double orient(const Eigen::Vector3d& a, const Eigen::Vector3d& b, const Eigen::Vector3d& c, const Eigen::Vector3d& d) {
  return (b - a).cross(c - a).dot(d - a);
}
}  // namespace

bool segment_triangle_intersect(const Eigen::Vector3d& p, const Eigen::Vector3d& q, const Eigen::Vector3d& a,
                                const Eigen::Vector3d& b, const Eigen::Vector3d& c) {
  const double sp = orient(a, b, c, p), sq = orient(a, b, c, q);
  // Coplanar up to round-off (both ends within 1e-12 relative of the plane): not counted (their orientation
  // signs would be noise).
  const double tol = 1e-12 * (b - a).cross(c - a).norm() * std::max((p - a).norm(), (q - a).norm());
  if (std::abs(sp) <= tol && std::abs(sq) <= tol) return false;
  if ((sp > 0 && sq > 0) || (sp < 0 && sq < 0)) return false;
  // The line pq pierces the plane: inside iff the three edge orientations around pq agree in sign.
  const double s0 = orient(p, q, a, b), s1 = orient(p, q, b, c), s2 = orient(p, q, c, a);
  return (s0 >= 0 && s1 >= 0 && s2 >= 0) || (s0 <= 0 && s1 <= 0 && s2 <= 0);
}

bool triangles_intersect(const Eigen::Vector3d t0[3], const Eigen::Vector3d t1[3]) {
  for (int k = 0; k < 3; ++k) {
    if (segment_triangle_intersect(t0[k], t0[(k + 1) % 3], t1[0], t1[1], t1[2])) return true;
    if (segment_triangle_intersect(t1[k], t1[(k + 1) % 3], t0[0], t0[1], t0[2])) return true;
  }
  return false;
}

ContactReport contact_report(const ContactSurfaces& s, const ContactPositions& x, PairFilter filter,
                             double search_radius, int max_listed) {
  ContactReport r;
  r.search_radius_m = search_radius > 0 ? search_radius : s.mean_edge_length(x);
  const CandidatePairs c = broad_phase(s, x, nullptr, r.search_radius_m, filter);
  for (const auto& q : c.point_triangle) {
    const auto& f = s.faces[q[1]];
    r.min_distance_m = std::min(r.min_distance_m, point_triangle_unsigned_distance(x.row(q[0]), x.row(f[0]), x.row(f[1]),
                                                                          x.row(f[2])));
  }
  for (const auto& q : c.edge_edge) {
    const auto &e = s.edges[q[0]], &o = s.edges[q[1]];
    r.min_distance_m = std::min(r.min_distance_m, edge_edge_unsigned_distance(x.row(e[0]), x.row(e[1]), x.row(o[0]),
                                                                     x.row(o[1])));
  }
  if (r.min_distance_m > r.search_radius_m) r.min_distance_m = std::numeric_limits<double>::infinity();
  for (const auto& q : triangle_pairs(s, x, 0.0, filter)) {
    Eigen::Vector3d t0[3], t1[3];
    for (int k = 0; k < 3; ++k) {
      t0[k] = x.row(s.faces[q[0]][k]);
      t1[k] = x.row(s.faces[q[1]][k]);
    }
    if (triangles_intersect(t0, t1)) {
      if (static_cast<int>(r.first_pairs.size()) < max_listed) r.first_pairs.push_back(q);
      ++r.intersecting_pairs;
    }
  }
  return r;
}

ContactSurfaces make_contact_surfaces(const MatrixX3i& cloth_faces, int cloth_vertices, const ObstacleMesh* obstacle) {
  ContactSurfaces s;
  const int nb = obstacle ? static_cast<int>(obstacle->positions.rows()) : 0;
  s.vertex_group.assign(cloth_vertices, 0);
  s.vertex_group.resize(cloth_vertices + nb, 1);
  for (int f = 0; f < cloth_faces.rows(); ++f) s.faces.push_back({cloth_faces(f, 0), cloth_faces(f, 1), cloth_faces(f, 2)});
  if (obstacle)
    for (int f = 0; f < obstacle->faces.rows(); ++f)
      s.faces.push_back({cloth_vertices + obstacle->faces(f, 0), cloth_vertices + obstacle->faces(f, 1),
                         cloth_vertices + obstacle->faces(f, 2)});
  s.edges = unique_edges(s.faces);
  return s;
}

ContactReport contact_report(const MatrixX3i& faces, const Eigen::VectorXd& x, const ObstacleMesh* obstacle,
                             double search_radius, int max_listed) {
  const int nv = static_cast<int>(x.size() / 3);
  const ContactSurfaces s = make_contact_surfaces(faces, nv, obstacle);
  ContactPositions P(s.num_vertices(), 3);
  for (int i = 0; i < nv; ++i) P.row(i) = x.segment<3>(3 * i).transpose();
  if (obstacle) P.bottomRows(obstacle->positions.rows()) = obstacle->positions;
  return contact_report(s, P, PairFilter::kAll, search_radius, max_listed);
}

}  // namespace drapelab
