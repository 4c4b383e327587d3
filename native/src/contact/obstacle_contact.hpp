// Contact of the cloth with a moving obstacle (a body under a garment): IPC barriers on cloth-point vs
// obstacle-triangle, obstacle-point vs cloth-triangle and cloth-edge vs obstacle-edge pairs closer than the
// activation distance `thickness` [m], CCD-bounded steps (contact/pair_contact.hpp).
//
// The obstacle's vertex positions are data set per time step: set_obstacle(at_t, at_t1). Within a step the
// obstacle stands at its end position at_t1 and the cloth's motion is swept against it, so the caller must make
// each obstacle move small enough (substeps) that at_t1 does not reach through the cloth's state at t (checked:
// the step fails with a SolverError naming the intersecting triangles, or, when the move sweeps through the cloth
// or brings a pair within 0.1 % of its distance, the pair it sweeps through). Not an effect: the garment
// simulator adds it to its model (Model::add_term). Friction: coefficient `friction` (lagged smoothed Coulomb, per
// pair; the body's own motion over the step drags the cloth).
#pragma once
#include "contact/diagnostics.hpp"
#include "contact/pair_contact.hpp"
#include "geometry/mesh.hpp"

namespace drapelab {

class ObstacleContact : public PairContactTerm {
 public:
  // cloth: the model's mesh; area_weights: per cloth vertex [m^2]; density [kg/m^2] and gravity [m/s^2] scale
  // the barrier as in disk_contact; obstacle: its faces and its positions at the start.
  ObstacleContact(const TriangleMesh& cloth, const Eigen::VectorXd& area_weights, double density, double gravity,
                  const ObstacleMesh& obstacle, double thickness, double friction = 0.0);
  std::string name() const override { return "obstacle_contact"; }
  // The obstacle's positions at the start and the end of the next step (rows as the faces index them).
  void set_obstacle(const MatrixX3d& at_t, const MatrixX3d& at_t1);
  const MatrixX3d& obstacle_start() const { return start_; }
  double thickness() const { return thickness_; }

 protected:
  double dhat(const Eigen::VectorXd&) const override { return thickness_; }
  int dhat_index() const override { return -1; }
  double friction(const Eigen::VectorXd&) const override { return friction_; }
  int friction_index() const override { return -1; }

 private:
  double thickness_, friction_;
  MatrixX3d start_;
};

}  // namespace drapelab
