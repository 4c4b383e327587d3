#include "solver/static_solve.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <sstream>

#include "solver/contact_linear_solve.hpp"
#include "util/error.hpp"

namespace drapelab {

namespace {
constexpr double kStandardGravity = 9.8;   // m/s^2: residual forces are measured in units of weight
constexpr double kInitialShift = 400.0;    // 1/s^2: mu M = M / h^2 of a 0.05 s implicit step at the start
constexpr double kShiftIncrease = 10.0;    // mu *= this when no step is found (or the matrix does not factorise)
constexpr double kShiftDecrease = 0.25;    // mu *= this after a full step
constexpr double kMinShift = 1e-3;         // 1/s^2: below this the shift is dropped (phase 2 of the header)
// Residual (vertex weights) below which phase 2 starts at once: the state already carries most of its weight
// by internal forces (a warm start near an equilibrium); the flat start has 1.
constexpr double kNearEquilibriumResidual = 0.5;
constexpr int kMaxMatrixAttempts = 30;     // matrices tried per iteration before a step is declared impossible
constexpr double kArmijo = 1e-4;           // sufficient-decrease constant of the line search
constexpr double kMinStep = 1e-4;          // smallest step length tried
constexpr double kMaxExtension = 8.0;      // longest step length tried when a full step is accepted
constexpr int kMaxExactBackoff = 8;        // iterations between exact-Hessian attempts after repeated failures
constexpr double kEnergyRoundOff = 1e-11;  // relative change of E below which E cannot rank two states
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
  const bool debug = std::getenv("DRAPELAB_DEBUG_STATIC") != nullptr;
  have_solution_ = false;
  Eigen::VectorXd g(n), A(pattern.nnz()), dx(n), xn(n), gn(n);
  double E = model_.energy(x, p);
  double mu = kInitialShift;
  int next_exact = 0, exact_backoff = 1;  // the next iteration that tries the exact Hessian, and the back-off
  StaticResult result;

  enum class Matrix { kExact, kNewton, kShiftedStep };
  // Fills A with the matrix of this kind and factorises it; false if it is not positive definite.
  auto factorise = [&](Matrix kind) {
    A.setZero();
    for (const auto& t : model_.terms()) {
      if (kind == Matrix::kExact) t->add_hessian(x, p, 1.0, A);
      else if (kind == Matrix::kNewton) t->add_static_newton_matrix(x, p, 1.0, A);
      else t->add_step_matrix(x, p, 1.0, A);
    }
    if (kind == Matrix::kShiftedStep)
      for (int i = 0; i < model_.num_vertices(); ++i)
        for (int k = 0; k < 3; ++k) A[pattern.diagonal(3 * i + k)] += mu * m[i];
    return solver_.factorize(A);
  };
  // Armijo backtracking along dx from the full step; an accepted full step is extended (x2 up to
  // kMaxExtension) while E keeps falling. Where E no longer resolves the decrease (round-off near the
  // minimum), a decrease of the residual instead. Moves x and returns the step length, 0 if none.
  bool contact = false;
  const bool offpattern = has_offpattern_terms(model_);
  for (const auto& t : model_.terms()) {
    contact = contact || t->is_contact();
    t->begin_step(x, p, 0.0);  // a static drape: no friction
  }
  // Contact: the longest step (in units of dx, up to kMaxExtension) that continuous collision detection allows.
  auto step_cap = [&]() {
    if (!contact) return kMaxExtension;
    const Eigen::VectorXd longest = kMaxExtension * dx;
    double f = 1.0;
    for (const auto& t : model_.terms()) f = std::min(f, t->max_step(x, longest, p));
    return f * kMaxExtension;
  };
  auto line_search = [&](double residual_now) {
    const double slope = g.dot(dx);
    if (!(slope < 0)) return 0.0;
    const double cap = step_cap();
    double alpha = 0.0, E_best = E;
    for (double a = std::min(1.0, cap); a > kMinStep && alpha == 0.0; a *= 0.5) {
      xn = x + a * dx;
      const double En = model_.energy(xn, p);
      if (!std::isfinite(En)) continue;
      bool ok = En <= E + kArmijo * a * slope;
      if (!ok && std::abs(En - E) <= kEnergyRoundOff * std::abs(E)) {
        gn.setZero();
        model_.add_gradient(xn, p, gn);
        ok = residual(gn, m) < residual_now;
      }
      if (ok) {
        alpha = a;
        E_best = En;
      }
    }
    if (alpha == 1.0)
      for (double a = 2.0; a <= std::min(kMaxExtension, cap); a *= 2) {
        xn = x + a * dx;
        const double En = model_.energy(xn, p);
        if (!(std::isfinite(En) && En < E_best)) break;
        alpha = a;
        E_best = En;
      }
    if (alpha > 0) {
      x += alpha * dx;
      E = E_best;
    }
    return alpha;
  };

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
    if (result.residual < kNearEquilibriumResidual) mu = 0.0;
    double alpha = 0.0;
    Matrix used = Matrix::kShiftedStep;
    for (int attempt = 0; attempt < kMaxMatrixAttempts && alpha == 0.0; ++attempt) {
      bool factorised = false;
      if (mu == 0 && it >= next_exact) {
        used = Matrix::kExact;
        factorised = factorise(used);
        if (factorised) {
          exact_backoff = 1;
        } else {
          next_exact = it + exact_backoff;
          exact_backoff = std::min(2 * exact_backoff, kMaxExactBackoff);
        }
      }
      if (!factorised && mu == 0) factorised = factorise(used = Matrix::kNewton);
      if (!factorised) factorised = factorise(used = Matrix::kShiftedStep);
      if (factorised) {
        if (offpattern) {  // couplings outside the pattern (self contact): CG on the full operator
          Eigen::VectorXd y;
          const OffpatternOperator op = used == Matrix::kExact    ? OffpatternOperator::kExactHessian
                                        : used == Matrix::kNewton ? OffpatternOperator::kProjectedHessian
                                                                  : OffpatternOperator::kStepMatrix;
          if (solve_with_offpattern(model_, solver_, A, x, p, op, g, y)) {
            dx = -y;
            alpha = line_search(result.residual);
          }
        } else {
          dx = -solver_.solve(g);
          alpha = line_search(result.residual);
        }
      }
      if (alpha == 0.0) {
        // No descent with this matrix: a shifted step matrix next (shorter, gradient-like steps).
        mu = std::max(kShiftIncrease * mu, kInitialShift);
        next_exact = std::max(next_exact, it + 1);
      }
    }
    if (alpha == 0.0) {
      std::ostringstream s;
      s << "static solve: no descent step at iteration " << it << " (residual " << result.residual
        << " of vertex weight)";
      throw SolverError(s.str());
    }
    if (used == Matrix::kShiftedStep && alpha >= 1.0) mu = (mu * kShiftDecrease < kMinShift) ? 0.0 : mu * kShiftDecrease;
    if (debug)
      fprintf(stderr, "it %d res %g E %.12g %s alpha %g mu %g\n", it, result.residual, E,
              used == Matrix::kExact ? "exact" : (used == Matrix::kNewton ? "newton" : "step"), alpha, mu);
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
  Eigen::VectorXd lambda;
  if (!has_offpattern_terms(model_)) {
    lambda = solver_.solve(dL_dx);
  } else if (!solve_with_offpattern(model_, solver_, H, x_, p_, false, dL_dx, lambda)) {
    throw SolverError("static adjoint: the Hessian with contact couplings is not positive definite (unstable equilibrium)");
  }
  Eigen::VectorXd gp = Eigen::VectorXd::Zero(p_.size());
  for (const auto& t : model_.terms()) t->add_gradient_parameter_product(x_, p_, lambda, -1.0, gp);
  return gp;
}

}  // namespace drapelab
