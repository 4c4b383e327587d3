// Static equilibrium of the drape: minimise E(x; p) from the flat rest state, and its implicit-function
// adjoint: at grad E(x*; p) = 0, dL/dp = -(d grad E / dp)^T H^-1 dL/dx (one extra solve with the exact
// Hessian at x*, which is positive definite at a stable equilibrium).
//
// Minimisation: a line-search Newton method whose matrix is chosen per iteration (Nocedal & Wright,
// Numerical Optimization, 2nd ed. 2006, ch. 3.4 and 10.3; Levenberg-Marquardt shift as in ch. 10.3):
//  1. While the folds form (flat start, large motions): the PSD step matrix K plus a Levenberg-Marquardt
//     shift mu M (mu = 1 / h^2 of a 0.05 s implicit step at first), mu falling by 4 per full step to 0
//     (or at once where the residual is below half a vertex weight: a warm start near an equilibrium).
//  2. Then, where it factorises, the exact Hessian (quadratic convergence at the end). In a draped fold the
//     exact Hessian is indefinite for most of the way (the bending term's E'(theta) Hess theta); there each
//     term's static Newton matrix (Term::add_static_newton_matrix: exact stretch, Gauss-Newton bending),
//     which keeps the membrane's compression softening that K drops and so moves the folds to their
//     equilibrium in about half the iterations of K. A failed exact attempt is retried after an exponential
//     back-off (1, 2, 4, 8 iterations), so that an indefinite valley costs few wasted factorisations.
//  Line search: Armijo backtracking from the full step; a full step that is accepted is extended (2, 4, 8x)
//  while E keeps falling: along the drape's soft modes (folds migrating along the rim) the Newton step
//  undershoots (actual decrease > predicted, as in a quartic valley).
// Measured on circle1-5 (Cotton Blue, homogeneous and jittered): converges from flat in 43-131 iterations;
// on circle1-3 into the fold pattern of the 100-step dynamic rollout (6, 7, 8 folds, peaks within ~13
// degrees), 8 folds on circle4-5. The former K / shifted-exact Newton crawled along the folds' migration
// and did not converge within 200 iterations on circle2, 4 and 5.
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
