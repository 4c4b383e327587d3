// A kinematic body made of rigid parts, each a surface of revolution (the parametric dress form of
// drapelab.garment.body: pelvis and legs), as a contact obstacle for garments.
//
// Part k: an axis from `origin` pointing down (-z in the part's rest frame), a radius profile r(s) sampled at
// increasing s (piecewise linear, r = 0 at both apexes). At time t the part's rest frame is carried by a rigid
// transform T_k(t) = (R, c). The clearance of a cloth point q (the part's "distance" in the IPC barrier) is
// computed in the part's rest frame, y = R^T (q - c):
//   inside the axis range:  g(y) = rho(y) - r(s(y)),  rho = distance from the axis, s = origin_z - y_z
//   beyond an apex:          g(y) = |(rho, s - s_apex)|
// g < 0 inside the part. g is not a Euclidean distance on sloped parts but |grad g| <= L_k = sqrt(1 + max r'^2),
// which the collision check uses (conservative advancement with Lipschitz constant L_k).
// Energy (one contact per cloth vertex and part, as disk_contact): E = sum kappa_i b(g_ik) with the IPC barrier
// b of reach dhat (contact/barrier.hpp), kappa_i = weight-scaled as in disk_contact. Friction with the body is its own term
// (garment/body_friction.hpp), lagged on this term's poses and barrier.
// Within one time step the body moves from its start pose to its end pose (set_poses) as the stepper advances it
// (Term::obstacle_progress): its current pose is the geodesic interpolation (rotation about a fixed axis, linear
// translation) at the progress reached, and the energy, derivatives, max_step and clearance are those of the
// current pose. Each advance carries the cloth near the body along a smooth displacement field (obstacle_carry:
// a partition of unity over the parts, each part's rigid motion, times a falloff with the clearance, so stacked
// layers move together) and is bounded by conservative advancement on each vertex's motion relative to each moving
// part (obstacle_max_advance); the stepper bounds the same move by the self contact's CCD. No cloth is moved
// outside collision detection's bound.
// Cloth EDGES (the mesh's edges, given at construction): per edge e = (a, b) and part k, the segment's minimum
// clearance d_ek (garment/revolved_edge.hpp: exact gradient and Hessian through the implicit minimiser) carries
//   E_ek = kappa_e m_ek b(d_ek),  kappa_e = (kappa_a + kappa_b) / 6,  m_ek = q(dip_a / kEdgeDip) q(dip_b / kEdgeDip)
// with dip_a = g_k(x_a) - d_ek (contact/disk_edge.hpp dip_weight: a C2 smooth step from 0 to 1 over 0.1 mm), only
// where the minimum is inside the segment: as it moves to an end (dip -> 0) the edge hands over to that vertex's
// barrier continuously, nothing counted twice; cut between two vertices (d_ek -> 0, both dips > 0) E -> infinity.
// The edges' step matrix is their projected exact Hessian (b' times the minimum's curvature is what resists
// sliding a chord across a convex part; Gauss-Newton alone let Newton push hip chords to 1 nm).
// Step matrix cap (add_step_matrix only; energy, forces and the Hessians are exact): below kGaussNewtonDistanceFloor
// of the reach (contact/pair_barrier.hpp, as self contact) a vertex's Gauss-Newton curvature is b'' at the floor and
// an edge's projected Hessian is scaled by b''(floor) / b''(d): a contact pinched to 1e-13 m otherwise puts
// 1e19 N/m beside an inertia of 0.3 N/m and CHOLMOD fails on round-off (docs/lab/garment-speed.md).
// max_step and obstacle_max_advance bound every edge as every vertex (conservative advancement on d_ek; an
// edge's points move by convex combinations of its ends' moves, so its ends' speed bounds bound it). Edges out
// of reach are skipped on a bounding box test before any segment search.
#pragma once
#include <Eigen/Core>
#include <array>
#include <memory>
#include <vector>

#include "garment/revolved_edge.hpp"
#include "physics/term.hpp"

namespace drapelab {

struct RevolvedPart {
  Eigen::Vector3d origin;       // m, rest frame: top apex of the axis
  std::vector<double> s, r;     // m: profile samples along the downward axis (s increasing) and radii
};

struct RigidPose {
  Eigen::Matrix3d R = Eigen::Matrix3d::Identity();
  Eigen::Vector3d c = Eigen::Vector3d::Zero();
};

class RevolvedBodyContact : public Term {
 public:
  // kappa: each cloth vertex's barrier stiffness kappa_i [J] (e.g. weight * dhat); edges: the cloth's edges
  // (vertex pairs) kept off the body too (none: vertices only).
  RevolvedBodyContact(std::vector<RevolvedPart> parts, Eigen::VectorXd kappa, double activation,
                      std::vector<std::array<int, 2>> edges = {});
  std::string name() const override { return "body_contact"; }
  bool is_contact() const override { return true; }
  bool provides_step_matrix_derivatives() const override { return false; }
  // The poses at the start and the end of the next step (one per part); the body is at its start pose (progress 0).
  void set_poses(const std::vector<RigidPose>& start, const std::vector<RigidPose>& end);
  // Clearance of each point (N x 3 flat) against the body at its current pose (min over parts), metres.
  Eigen::VectorXd clearance(const Eigen::VectorXd& x) const;
  // Clearance of each edge (min over its points, ends included, and the parts) at the current pose, metres.
  Eigen::VectorXd edge_clearance(const Eigen::VectorXd& x) const;
  const std::vector<std::array<int, 2>>& edges() const { return edges_; }
  int num_parts() const { return static_cast<int>(parts_.size()); }
  // The poses the step goes from and to (set_poses), the barrier stiffness per vertex [J] and its reach [m].
  const RigidPose& start_pose(int k) const { return start_[k]; }
  const RigidPose& end_pose(int k) const { return end_[k]; }
  const Eigen::VectorXd& kappa() const { return kappa_; }
  double activation() const { return dhat_; }
  // The energy of the edges alone (the vertex barriers excluded), for tests.
  double edge_energy(const Eigen::VectorXd& x) const;

  std::vector<std::vector<int>> stencils() const override;
  void bind_pattern(const SparsePattern& pattern) override;
  double energy(const Eigen::VectorXd& x, const Eigen::VectorXd& p) const override;
  void add_gradient(const Eigen::VectorXd& x, const Eigen::VectorXd& p, Eigen::VectorXd& g) const override;
  void add_step_matrix(const Eigen::VectorXd& x, const Eigen::VectorXd& p, double scale,
                       Eigen::VectorXd& values) const override;
  void add_hessian(const Eigen::VectorXd& x, const Eigen::VectorXd& p, double scale,
                   Eigen::VectorXd& values) const override;
  void add_projected_hessian(const Eigen::VectorXd& x, const Eigen::VectorXd& p, double scale,
                             Eigen::VectorXd& values) const override;
  void add_hessian_product(const Eigen::VectorXd& x, const Eigen::VectorXd& p, const Eigen::VectorXd& dir,
                           Eigen::VectorXd& out) const override;
  void add_energy_parameter_gradient(const Eigen::VectorXd&, const Eigen::VectorXd&, Eigen::VectorXd&) const override {}
  void add_gradient_parameter_product(const Eigen::VectorXd&, const Eigen::VectorXd&, const Eigen::VectorXd&, double,
                                      Eigen::VectorXd&) const override {}
  void add_step_matrix_derivatives(const Eigen::VectorXd&, const Eigen::VectorXd&, const Eigen::VectorXd&,
                                   const Eigen::VectorXd&, double, Eigen::VectorXd&, Eigen::VectorXd&) const override;
  double max_step(const Eigen::VectorXd& x, const Eigen::VectorXd& dx, const Eigen::VectorXd& p) const override;

  // g and its gradient / Hessian (world frame) of point q against part k at its current pose.
  double part_clearance(int k, const Eigen::Vector3d& q, Eigen::Vector3d* grad = nullptr,
                        Eigen::Matrix3d* hess = nullptr) const;
  // The same at a given pose of the part.
  double part_clearance_at(int k, const RigidPose& pose, const Eigen::Vector3d& q,
                           Eigen::Vector3d* grad = nullptr, Eigen::Matrix3d* hess = nullptr) const;

  double obstacle_progress() const override { return progress_; }
  // u_i += f(c_i) sum_k w_ik D_k(q_i): D_k part k's rigid motion of q_i from its current to its end pose, w_ik a
  // partition of unity over the parts (softmin of the clearances g_k / L_k, its width at least kBlendWidth and
  // the spread of the D_k), f = 1 within kCarryFull of the body falling smoothly (C1) to 0 over at least
  // kCarryReach - kCarryFull and 4 |D|: the field's gradient stays below 1, stacked layers move together.
  void obstacle_carry(const Eigen::VectorXd& x, Eigen::VectorXd& u) const override;
  double obstacle_max_advance(const Eigen::VectorXd& x, const Eigen::VectorXd& u) const override;
  void advance_obstacle(double tau) override;
  // The pose between a and b at the fraction t (rotation about the fixed axis of a^T b, linear translation).
  static RigidPose interpolate(const RigidPose& a, const RigidPose& b, double t);

 private:
  // Per vertex: E_i = sum_k kappa_i b(g_ik); value, gradient and Hessian of kind 0 exact, 1 Gauss-Newton,
  // 2 projected, 3 the step matrix (Gauss-Newton with the curvature cap).
  double vertex_terms(int i, const Eigen::Vector3d& q, Eigen::Vector3d* g, Eigen::Matrix3d* H, int kind) const;
  // Per part: every vertex in the part's rest frame at its current pose (3V).
  std::vector<Eigen::VectorXd> local_positions(const Eigen::VectorXd& x) const;
  // Edge e against part k (local: local_positions): energy, and gradient / 6x6 Hessian (row-major) of kind 0
  // exact, 2 projected onto the PSD cone, 3 the step matrix (projected, with the curvature cap); false when out of
  // reach (nothing written).
  bool edge_part_terms(int e, int k, const std::vector<Eigen::VectorXd>& local, double* E, double* g, double* H,
                       int kind) const;
  // sum over edges and parts; out: gradient (3V) / Hessian values (pattern) / Hessian product, as requested.
  double edge_terms(const Eigen::VectorXd& x, Eigen::VectorXd* grad, int kind, double scale, Eigen::VectorXd* values,
                    const Eigen::VectorXd* dir, Eigen::VectorXd* product) const;
  double edges_max_step(const Eigen::VectorXd& x, const Eigen::VectorXd& dx, double alpha) const;
  double edges_max_advance(const Eigen::VectorXd& x, const Eigen::VectorXd& u, double alpha) const;
  std::vector<RevolvedPart> parts_;
  std::vector<ProfileView> views_;  // parts_' profiles for the edge code
  std::vector<double> lipschitz_;
  std::vector<RigidPose> start_, end_, current_;
  double progress_ = 1.0;
  Eigen::VectorXd kappa_;
  double dhat_;
  std::vector<int> diag_;  // pattern index of each vertex's 3x3 diagonal block, upper triangle (6 per vertex)
  std::vector<std::array<int, 2>> edges_;
  std::vector<double> edge_kappa_;
  std::vector<int> edge_scatter_;  // per edge 6 x 6 pattern indices (-1 below the diagonal)
};

}  // namespace drapelab
