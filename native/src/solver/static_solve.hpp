// Static equilibrium of the drape: minimise E(x; p) from the flat rest state with Newton's method
// (exact Hessian, shifted by mu M until it factorises, backtracking line search on E), and its
// implicit-function adjoint: at grad E(x*; p) = 0, dL/dp = -(d grad E / dp)^T H^-1 dL/dx (one extra solve
// with the exact Hessian at x*, which is positive definite at a stable equilibrium).
//
// Convergence test: every vertex's residual force |grad_i E| is below force_tolerance times its weight
// m_i g (default 1e-6), i.e. the drape is at rest to a millionth of its own weight.
#pragma once
#include <Eigen/Core>

#include "physics/model.hpp"
#include "solver/cholmod_solver.hpp"
#include "util/progress.hpp"

namespace drapelab {

struct StaticOptions {
  double force_tolerance = 1e-6;  // of each vertex's weight
  int max_iterations = 200;
};

struct StaticResult {
  Eigen::VectorXd positions;
  int iterations = 0;
  double residual = 0;  // max_i |grad_i E| / (m_i g) at the end
};

class StaticSolver {
 public:
  explicit StaticSolver(const Model& model);
  // Throws SolverError if not converged within max_iterations (naming the residual reached).
  StaticResult solve(const Eigen::VectorXd& parameters, const StaticOptions& options = {},
                     ProgressSink* progress = nullptr, const Eigen::VectorXd* x0 = nullptr);
  // dL/dp given dL/dx* at the last solution.
  Eigen::VectorXd adjoint(const Eigen::VectorXd& dL_dx);

 private:
  double residual(const Eigen::VectorXd& g, const Eigen::VectorXd& masses) const;
  const Model& model_;
  CholmodSolver solver_;
  Eigen::VectorXd x_, p_;
  bool have_solution_ = false;
};

}  // namespace drapelab
