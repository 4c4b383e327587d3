// Linear solves with contact couplings outside the model's sparsity pattern (Term::has_offpattern_hessian,
// contact/pair_contact.hpp): (A + R) y = b, with A the assembled matrix (pattern values, already factorised by
// CHOLMOD) and R the terms' remainder, applied as products. Conjugate gradients preconditioned with A's factor:
// the first iterate is A^-1 b, returned as it is when no pair couples vertices outside the pattern (R y = 0: the
// direct solve, bit for bit); each further iteration costs one CHOLMOD solve and one operator product.
// Fails (returns false) if the operator shows a non-positive curvature (an exact Hessian that is indefinite:
// the caller falls back to a projected matrix) or CG does not reach the tolerance in max_iterations.
#pragma once
#include <Eigen/Core>

#include "physics/model.hpp"
#include "solver/cholmod_solver.hpp"

namespace drapelab {

// True if any of the model's terms can couple vertices outside its pattern.
bool has_offpattern_terms(const Model& model);

struct OffpatternSolveStats {
  int iterations = 0;          // CG iterations after the preconditioner's first solve
  double relative_residual = 0;
  bool coupled = false;        // the remainder was not zero (some pair couples vertices outside the pattern)
  bool needs_matrix = false;   // failed because A was empty (size 0) and the remainder was not zero
};

// Which matrix the assembled part belongs to, hence which remainder R is: the exact Hessian's
// (Term::add_offpattern_hessian_product, projected = false), the projected Hessian's (projected = true), or the
// step matrix's (Term::add_offpattern_step_matrix_product).
enum class OffpatternOperator { kExactHessian, kProjectedHessian, kStepMatrix };

// y = (A + R(x, p))^-1 b. A: the assembled values that `solver` has factorised (the caller's
// matrix, including whatever diagonal it added), or whose factor `factor` is (kept by the solver earlier);
// R: the sum over terms of the remainder of `op` at (x, p). A may be empty (size 0) when a factor is given: enough
// where R y = 0 (the direct solve); else the solve fails with stats->needs_matrix set.
bool solve_with_offpattern(const Model& model, const CholmodSolver& solver, const Eigen::VectorXd& A,
                           const Eigen::VectorXd& x, const Eigen::VectorXd& p, OffpatternOperator op,
                           const Eigen::VectorXd& b, Eigen::VectorXd& y, double tolerance = 1e-10,
                           int max_iterations = 200, OffpatternSolveStats* stats = nullptr,
                           const CholmodSolver::Factor* factor = nullptr);
// The Hessians' form: projected ? kProjectedHessian : kExactHessian.
bool solve_with_offpattern(const Model& model, const CholmodSolver& solver, const Eigen::VectorXd& A,
                           const Eigen::VectorXd& x, const Eigen::VectorXd& p, bool projected,
                           const Eigen::VectorXd& b, Eigen::VectorXd& y, double tolerance = 1e-10,
                           int max_iterations = 200, OffpatternSolveStats* stats = nullptr);

}  // namespace drapelab
