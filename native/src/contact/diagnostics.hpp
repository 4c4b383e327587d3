// Contact diagnostics of any state: the smallest distance between non-adjacent surface primitives and the
// triangle pairs that intersect (used by tests, by the contact terms' input check, the garment bench and,
// through the bindings, the add-on).
//
// Intersection: two triangles that share no vertex intersect iff an edge of one crosses the other (tested with
// the signs of orientation determinants in double precision; coplanar pairs, within 1e-12 relative, are not
// counted).
// Distance: the minimum over point-triangle and edge-edge pairs found by the broad phase within
// search_radius_m (default: the mean edge length); +inf when no pair is that close.
#pragma once
#include <array>
#include <limits>
#include <string>
#include <vector>

#include "contact/broad_phase.hpp"
#include "geometry/mesh.hpp"

namespace drapelab {

struct ContactReport {
  double min_distance_m = std::numeric_limits<double>::infinity();
  double search_radius_m = 0;
  int intersecting_pairs = 0;
  std::vector<std::array<int, 2>> first_pairs;  // up to max_listed intersecting (face, face), face indices of s
};

ContactReport contact_report(const ContactSurfaces& s, const ContactPositions& x, PairFilter filter,
                             double search_radius = 0, int max_listed = 8);

// A cloth (faces F x 3, positions x as 3V flat) alone (self contact), or against an obstacle mesh (then both
// self and cloth-obstacle pairs count, obstacle-obstacle pairs do not; obstacle faces are numbered after the
// cloth's, from num_faces).
struct ObstacleMesh {
  MatrixX3d positions;
  MatrixX3i faces;
};
ContactReport contact_report(const MatrixX3i& faces, const Eigen::VectorXd& x, const ObstacleMesh* obstacle = nullptr,
                             double search_radius = 0, int max_listed = 8);

// Builds combined surfaces (cloth rows first, group 0; obstacle rows after, group 1).
ContactSurfaces make_contact_surfaces(const MatrixX3i& cloth_faces, int cloth_vertices,
                                      const ObstacleMesh* obstacle = nullptr);

// Whether segment (p, q) crosses triangle (a, b, c) (touching counts; coplanar, within 1e-12 relative, does not).
bool segment_triangle_intersect(const Eigen::Vector3d& p, const Eigen::Vector3d& q, const Eigen::Vector3d& a,
                                const Eigen::Vector3d& b, const Eigen::Vector3d& c);
bool triangles_intersect(const Eigen::Vector3d t0[3], const Eigen::Vector3d t1[3]);

}  // namespace drapelab
