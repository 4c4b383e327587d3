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
// b of reach dhat (contact/barrier.hpp), kappa_i = weight-scaled as in disk_contact; no friction (yet).
// Within one time step the body is at its end pose (set before the step); the collision check follows each
// vertex's path relative to the part from the step's start pose to its end pose (both rigid).
#pragma once
#include <Eigen/Core>
#include <memory>
#include <vector>

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
  // vertex_weights: each cloth vertex's barrier stiffness kappa_i [J] (e.g. weight * dhat).
  RevolvedBodyContact(std::vector<RevolvedPart> parts, Eigen::VectorXd kappa, double activation);
  std::string name() const override { return "body_contact"; }
  bool is_contact() const override { return true; }
  bool provides_step_matrix_derivatives() const override { return false; }
  // The poses at the start and the end of the next step (one per part).
  void set_poses(const std::vector<RigidPose>& start, const std::vector<RigidPose>& end);
  // Clearance of each point (N x 3 flat) against the body at its end pose (min over parts), metres.
  Eigen::VectorXd clearance(const Eigen::VectorXd& x) const;

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

  // g and its gradient / Hessian (world frame) of point q against part k at its end pose.
  double part_clearance(int k, const Eigen::Vector3d& q, Eigen::Vector3d* grad = nullptr,
                        Eigen::Matrix3d* hess = nullptr, bool at_start = false) const;
  // Cloth vertices that the body at its end pose would reach (clearance below half the barrier's reach) and that
  // lay within kCarryReach of a part at the start pose move rigidly with that part to its end pose (where that
  // keeps them clear of every part): the IPC step's first iterate when the body moves; the others stay.
  void carry_start(Eigen::VectorXd& x) const override;

 private:
  // Per vertex: E_i = sum_k kappa_i b(g_ik); value, gradient and (exact or Gauss-Newton) Hessian.
  double vertex_terms(int i, const Eigen::Vector3d& q, Eigen::Vector3d* g, Eigen::Matrix3d* H, int kind) const;
  std::vector<RevolvedPart> parts_;
  std::vector<double> lipschitz_;
  std::vector<RigidPose> start_, end_;
  Eigen::VectorXd kappa_;
  double dhat_;
  std::vector<int> diag_;  // pattern index of each vertex's 3x3 diagonal block, upper triangle (6 per vertex)
};

}  // namespace drapelab
