#include "solver/static_solve.hpp"

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <sstream>

#include "util/error.hpp"

namespace drapelab {

namespace {
constexpr double kStandardGravity = 9.8;  // m/s^2: residual forces are measured in units of weight
constexpr double kInitialShift = 400.0;   // 1/s^2: mu M = M / h^2 of a 0.05 s step at the start
constexpr double kMinShift = 1e-3;        // below this the shift is dropped (pure Newton)
constexpr double kExactHessianBelow = 1.0; // residual (in vertex weights) below which Newton uses the exact Hessian
}  // namespace

StaticSolver::StaticSolver(const Model& model) : model_(model), solver_(model.pattern()) {}

double StaticSolver::residual(const Eigen::VectorXd& g, const Eigen::VectorXd& masses) const {
  double r = 0;
  for (int i = 0; i < model_.num_vertices(); ++i)
    r = std::max(r, g.segment<3>(3 * i).norm() / (masses[i] * kStandardGravity));
  return r;
}

StaticResult StaticSolver::solve(const Eigen::VectorXd& p, const StaticOptions& options, ProgressSink* progress,
                                 const Eigen::VectorXd* x0) {
  model_.validate_parameters(p);
  if (!(options.force_tolerance > 0)) throw InputError("static solve: force tolerance must be > 0");
  const int n = model_.num_dofs();
  const SparsePattern& pattern = model_.pattern();
  Eigen::VectorXd x = x0 ? *x0 : model_.rest_positions();
  if (x.size() != n || !x.allFinite()) throw InputError("static solve: start positions have the wrong size or are not finite");
  const Eigen::VectorXd m = model_.masses(p);
  double mu = kInitialShift;
  have_solution_ = false;
  Eigen::VectorXd g(n), A(pattern.nnz());
  double E = model_.energy(x, p);
  StaticResult result;
  for (int it = 0; it < options.max_iterations; ++it) {
    g.setZero();
    model_.add_gradient(x, p, g);
    result.residual = residual(g, m);
    result.iterations = it;
    if (result.residual < options.force_tolerance) {
      x_ = x;
      p_ = p;
      have_solution_ = true;
      result.positions = x;
      return result;
    }
    A.setZero();
    // Far from equilibrium the PSD step matrix (cheap, robust); close to it the exact Hessian (fast
    // local convergence, also in compressed folds where the step matrix is a poor model).
    const bool exact = result.residual < kExactHessianBelow;
    for (const auto& t : model_.terms()) {
      if (exact) t->add_hessian(x, p, 1.0, A);
      else t->add_step_matrix(x, p, 1.0, A);
    }
    bool accepted = false;
    for (int attempt = 0; attempt < 30 && !accepted; ++attempt) {
      Eigen::VectorXd As = A;
      for (int i = 0; i < model_.num_vertices(); ++i)
        for (int k = 0; k < 3; ++k) As[pattern.diagonal(3 * i + k)] += mu * m[i];
      if (!solver_.factorize(As)) {
        mu = std::max(10 * mu, kInitialShift);
        continue;
      }
      const Eigen::VectorXd dx = -solver_.solve(g);
      const double slope = g.dot(dx);
      double alpha = 1.0;
      while (alpha > 1e-4) {
        const Eigen::VectorXd xn = x + alpha * dx;
        const double En = model_.energy(xn, p);
        // Armijo on E; where E no longer resolves the decrease (round-off), on the residual instead.
        bool ok = std::isfinite(En) && En <= E + 1e-4 * alpha * slope;
        if (!ok && std::isfinite(En) && std::abs(En - E) <= 1e-11 * std::abs(E)) {
          Eigen::VectorXd gn = Eigen::VectorXd::Zero(n);
          model_.add_gradient(xn, p, gn);
          ok = residual(gn, m) < result.residual;
        }
        if (ok) {
          x = xn;
          E = En;
          accepted = true;
          break;
        }
        alpha *= 0.5;
      }
      if (!accepted) mu = std::max(10 * mu, kInitialShift);
      else if (alpha == 1.0) mu = (mu * 0.25 < kMinShift) ? 0.0 : mu * 0.25;
    }
    if (!accepted) {
      std::ostringstream s;
      s << "static solve: no descent step at iteration " << it << " (residual " << result.residual
        << " of vertex weight)";
      throw SolverError(s.str());
    }
    if (std::getenv("DRAPELAB_DEBUG_STATIC")) fprintf(stderr, "it %d res %g E %.10g mu %g\n", it, result.residual, E, mu);
    if (progress) progress->step(it + 1, options.max_iterations);
  }
  g.setZero();
  model_.add_gradient(x, p, g);
  std::ostringstream s;
  s << "static solve: not converged after " << options.max_iterations << " iterations (largest residual force "
    << residual(g, m) << " of a vertex's weight, tolerance " << options.force_tolerance << ")";
  throw SolverError(s.str());
}

Eigen::VectorXd StaticSolver::adjoint(const Eigen::VectorXd& dL_dx) {
  if (!have_solution_) throw InputError("static adjoint: solve first");
  if (dL_dx.size() != model_.num_dofs() || !dL_dx.allFinite())
    throw InputError("static adjoint: dL/dx has the wrong size or is not finite");
  Eigen::VectorXd H = Eigen::VectorXd::Zero(model_.pattern().nnz());
  for (const auto& t : model_.terms()) t->add_hessian(x_, p_, 1.0, H);
  if (!solver_.factorize(H))
    throw SolverError("static adjoint: the Hessian at the equilibrium is not positive definite (unstable equilibrium)");
  const Eigen::VectorXd lambda = solver_.solve(dL_dx);
  Eigen::VectorXd gp = Eigen::VectorXd::Zero(p_.size());
  for (const auto& t : model_.terms()) t->add_gradient_parameter_product(x_, p_, lambda, -1.0, gp);
  return gp;
}

}  // namespace drapelab
