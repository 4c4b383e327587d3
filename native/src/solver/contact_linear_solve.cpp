#include "solver/contact_linear_solve.hpp"

#include <cmath>

namespace drapelab {

bool has_offpattern_terms(const Model& model) {
  for (const auto& t : model.terms())
    if (t->has_offpattern_hessian()) return true;
  return false;
}

bool solve_with_offpattern(const Model& model, const CholmodSolver& solver, const Eigen::VectorXd& A,
                           const Eigen::VectorXd& x, const Eigen::VectorXd& p, bool projected,
                           const Eigen::VectorXd& b, Eigen::VectorXd& y, double tolerance, int max_iterations,
                           OffpatternSolveStats* stats) {
  return solve_with_offpattern(model, solver, A, x, p,
                               projected ? OffpatternOperator::kProjectedHessian : OffpatternOperator::kExactHessian,
                               b, y, tolerance, max_iterations, stats);
}

bool solve_with_offpattern(const Model& model, const CholmodSolver& solver, const Eigen::VectorXd& A,
                           const Eigen::VectorXd& x, const Eigen::VectorXd& p, OffpatternOperator op,
                           const Eigen::VectorXd& b, Eigen::VectorXd& y, double tolerance, int max_iterations,
                           OffpatternSolveStats* stats, const CholmodSolver::Factor* factor) {
  const SparsePattern& pattern = model.pattern();
  auto precondition = [&](const Eigen::VectorXd& v) { return factor ? solver.solve_with(*factor, v) : solver.solve(v); };
  auto remainder = [&](const Eigen::VectorXd& v) {
    Eigen::VectorXd out = Eigen::VectorXd::Zero(v.size());
    for (const auto& t : model.terms()) {
      if (!t->has_offpattern_hessian()) continue;
      if (op == OffpatternOperator::kStepMatrix) t->add_offpattern_step_matrix_product(x, p, v, out);
      else t->add_offpattern_hessian_product(x, p, v, op == OffpatternOperator::kProjectedHessian, out);
    }
    return out;
  };
  y = precondition(b);
  // r = b - (A + R) y = (b - A y) - R y; b - A y is round-off of the factor's solve. No pair couples vertices
  // outside the pattern (R y = 0 exactly): y is the direct solve's answer.
  const Eigen::VectorXd Ry = remainder(y);
  OffpatternSolveStats local;
  OffpatternSolveStats& s = stats ? *stats : local;
  s = {};
  if (!Ry.any()) return y.allFinite();
  s.coupled = true;
  if (A.size() == 0) {
    s.needs_matrix = true;
    return false;
  }
  Eigen::VectorXd r = b - symmetric_multiply(pattern, A, y) - Ry;
  const double bnorm = b.norm();
  s.relative_residual = bnorm > 0 ? r.norm() / bnorm : 0.0;
  if (s.relative_residual <= tolerance || !std::isfinite(s.relative_residual)) return std::isfinite(s.relative_residual);
  Eigen::VectorXd z = precondition(r), d = z;
  double rz = r.dot(z);
  for (int it = 0; it < max_iterations; ++it) {
    const Eigen::VectorXd q = symmetric_multiply(pattern, A, d) + remainder(d);
    const double dq = d.dot(q);
    if (!(dq > 0)) return false;  // indefinite operator
    const double a = rz / dq;
    y += a * d;
    r -= a * q;
    s.iterations = it + 1;
    s.relative_residual = r.norm() / bnorm;
    if (s.relative_residual <= tolerance) return true;
    z = precondition(r);
    const double rz_new = r.dot(z);
    d = z + (rz_new / rz) * d;
    rz = rz_new;
  }
  return false;
}

}  // namespace drapelab
