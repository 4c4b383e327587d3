// Continuous collision detection for point-triangle and edge-edge pairs: additive CCD (ACCD; Li, Kaufman,
// Jiang 2021, "Codimensional Incremental Potential Contact", sec. 4 and Alg. 1).
//
// Along the linear motion x(t) = x0 + t dx, t in [0, 1], the pair's unsigned distance d(t) changes at most as
// fast as l_p = (largest displacement of one side) + (largest of the other), after subtracting the pair's
// mean displacement (a common translation changes no distance). So from any t the pair cannot touch before
// t + d(t) / l_p. ACCD advances t by such safe increments (the first by (1 - s) d(0) / l_p, later ones by
// 0.9 d(t) / l_p) and stops as soon as d(t) falls below s d(0): the returned time of impact t* is then a time
// at which the pair is still at least s d(0) apart, and every time before it is collision-free. No step can
// tunnel: the increments are bounds, not samples.
//
// Returns t* in (0, 1]: 1 when the pair stays apart (by at least s d(0)) over the whole motion. s is the
// minimum-separation fraction (0 < s < 1). A pair that already touches (d(0) = 0) returns 0. The iteration
// count is capped (kMaxIterations): a capped search returns the last safe time (conservative, never late).
#pragma once
#include <Eigen/Core>

namespace drapelab {

constexpr double kDefaultCcdSeparation = 0.1;  // s: a step closes at most 90 % of a pair's distance

// Unsigned distances (not squared) [m].
double point_triangle_unsigned_distance(const Eigen::Vector3d& p, const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                               const Eigen::Vector3d& c);
double edge_edge_unsigned_distance(const Eigen::Vector3d& a0, const Eigen::Vector3d& b0, const Eigen::Vector3d& a1,
                          const Eigen::Vector3d& b1);

// Point p moving by dp against triangle (a, b, c) moving by (da, db, dc).
double point_triangle_ccd(const Eigen::Vector3d& p, const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                          const Eigen::Vector3d& c, const Eigen::Vector3d& dp, const Eigen::Vector3d& da,
                          const Eigen::Vector3d& db, const Eigen::Vector3d& dc,
                          double separation = kDefaultCcdSeparation);
// Edge (a0, b0) moving by (da0, db0) against edge (a1, b1) moving by (da1, db1).
double edge_edge_ccd(const Eigen::Vector3d& a0, const Eigen::Vector3d& b0, const Eigen::Vector3d& a1,
                     const Eigen::Vector3d& b1, const Eigen::Vector3d& da0, const Eigen::Vector3d& db0,
                     const Eigen::Vector3d& da1, const Eigen::Vector3d& db1, double separation = kDefaultCcdSeparation);

}  // namespace drapelab
