#include "solver/implicit_euler.hpp"

#include <chrono>
#include <cmath>
#include <sstream>

#include "util/error.hpp"

namespace drapelab {

namespace {
double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}
}  // namespace

ImplicitEuler::ImplicitEuler(const Model& model) : model_(model), solver_(model.pattern()) {}

void ImplicitEuler::step_system(const Eigen::VectorXd& x, const Eigen::VectorXd& v, const Eigen::VectorXd& p,
                                double h, Eigen::VectorXd& A, Eigen::VectorXd& b) const {
  const SparsePattern& pattern = model_.pattern();
  A.setZero(pattern.nnz());
  // b = h F - h^2 K v = -h grad E - h^2 K v; one fused pass per term (Term::add_step_system), else assembled.
  Eigen::VectorXd Kv = Eigen::VectorXd::Zero(x.size()), g = Eigen::VectorXd::Zero(x.size()), other;
  for (const auto& t : model_.terms())
    if (!t->add_step_system(x, p, v, h * h, A, Kv, g)) {
      if (other.size() == 0) other.setZero(pattern.nnz());
      t->add_step_matrix(x, p, h * h, other);
      t->add_gradient(x, p, g);
    }
  if (other.size() != 0) {
    Kv += symmetric_multiply(pattern, other, v);
    A += other;
  }
  b = -Kv - h * g;
  const Eigen::VectorXd m = model_.masses(p);
  for (int i = 0; i < model_.num_vertices(); ++i)
    for (int k = 0; k < 3; ++k) A[pattern.diagonal(3 * i + k)] += m[i];
}

Eigen::VectorXd ImplicitEuler::forward(const Eigen::VectorXd& p, const RolloutOptions& options,
                                       ProgressSink* progress, const Eigen::VectorXd* x0,
                                       const Eigen::VectorXd* v0) {
  model_.validate_parameters(p);
  if (!(options.time_step > 0) || !std::isfinite(options.time_step))
    throw InputError("rollout: time step must be > 0 s");
  if (options.steps < 1) throw InputError("rollout: need at least one step");
  const int n = model_.num_dofs();
  x_ = x0 ? *x0 : model_.rest_positions();
  v_ = v0 ? *v0 : Eigen::VectorXd::Zero(n);
  if (x_.size() != n || v_.size() != n) throw InputError("rollout: initial state has the wrong size");
  if (!x_.allFinite() || !v_.allFinite()) throw InputError("rollout: initial state is not finite");
  p_ = p;
  h_ = options.time_step;
  tape_.clear();  // the kept factors' buffers go back to the solver's pool, for this rollout's factors
  if (options.record) tape_.reserve(options.steps);
  timing_ = {};
  Eigen::VectorXd A, b;
  double kept_bytes = 0;
  for (int step = 0; step < options.steps; ++step) {
    auto t0 = std::chrono::steady_clock::now();
    step_system(x_, v_, p, h_, A, b);
    timing_.assemble += seconds_since(t0);
    t0 = std::chrono::steady_clock::now();
    if (!solver_.factorize(A)) {
      std::ostringstream s;
      s << "rollout: step " << step << " matrix is not positive definite (stiffness tables invalid?)";
      throw SolverError(s.str());
    }
    timing_.factorize += seconds_since(t0);
    t0 = std::chrono::steady_clock::now();
    const Eigen::VectorXd y = solver_.solve(b);
    timing_.solve += seconds_since(t0);
    Eigen::VectorXd v_next = v_ + y;
    double max_speed = 0;
    for (int i = 0; i < model_.num_vertices(); ++i) max_speed = std::max(max_speed, v_next.segment<3>(3 * i).norm());
    if (!v_next.allFinite() || max_speed > options.max_speed) {
      std::ostringstream s;
      s << "rollout: step " << step << " diverged (max vertex speed " << max_speed << " m/s > " << options.max_speed
        << " m/s); reduce the time step or check the parameters";
      throw SolverError(s.str());
    }
    if (options.record) {
      CholmodSolver::Factor kept;
      const double bytes = static_cast<double>(solver_.kept_factor_bytes());
      if (kept_bytes + bytes <= options.factor_memory_mb * 1048576.0) {
        kept = solver_.keep_factor();
        kept_bytes += bytes;
      }
      tape_.push_back({x_, v_, y, std::move(kept)});
    }
    x_ = x_ + h_ * v_next;
    v_ = std::move(v_next);
    if (progress) progress->step(step + 1, options.steps);
  }
  // Buffers of an earlier, longer recorded rollout that this one did not need go back to the system; an
  // unrecorded rollout (evaluation, warm start) keeps them for the next recorded one (fresh pages cost more
  // than the factorisation, see cholmod_solver.cpp).
  if (options.record) solver_.release_unused_buffers();
  return x_;
}

RolloutGradient ImplicitEuler::backward(const Eigen::VectorXd& dL_dx, const Eigen::VectorXd* dL_dv,
                                        ProgressSink* progress) {
  const int n = model_.num_dofs();
  if (tape_.empty()) throw InputError("backward: run forward with record = true first");
  if (dL_dx.size() != n) throw InputError("backward: dL/dx has the wrong size");
  if (!dL_dx.allFinite()) throw InputError("backward: dL/dx is not finite");
  const SparsePattern& pattern = model_.pattern();
  const double h = h_;
  const auto& density_block = model_.layout().block("density");
  const Eigen::VectorXd& w = model_.area_weights();
  Eigen::VectorXd gx = dL_dx;
  Eigen::VectorXd gv = dL_dv ? *dL_dv : Eigen::VectorXd::Zero(n);
  Eigen::VectorXd gp = Eigen::VectorXd::Zero(p_.size());
  Eigen::VectorXd K, tmp;
  const int T = static_cast<int>(tape_.size());
  for (int t = T - 1; t >= 0; --t) {
    const StepRecord& r = tape_[t];
    // x' = x + h v', v' = v + y
    const Eigen::VectorXd gv_total = gv + h * gx;
    Eigen::VectorXd lambda;
    if (r.factor) {
      lambda = solver_.solve_with(r.factor, gv_total);
    } else {  // not kept (memory budget): the same matrix, refactorised
      Eigen::VectorXd A, b;
      step_system(r.x, r.v, p_, h, A, b);
      if (!solver_.factorize(A)) throw SolverError("backward: step matrix is not positive definite");
      lambda = solver_.solve(gv_total);
    }
    const Eigen::VectorXd v_next = r.v + r.y;
    Eigen::VectorXd gx_prev = gx;
    Eigen::VectorXd gv_prev = gv_total;
    // b = h F(x) - h^2 K(x) v and A = M(rho) + h^2 K(x): one fused pass per term (Term::add_step_adjoint);
    // terms that do not provide K lambda get it from the assembled K.
    K.setZero(0);
    for (const auto& term : model_.terms())
      if (!term->add_step_adjoint(r.x, p_, lambda, v_next, h, gx_prev, gv_prev, gp)) {
        if (K.size() == 0) K.setZero(pattern.nnz());
        term->add_step_matrix(r.x, p_, h * h, K);
      }
    if (K.size() != 0) gv_prev -= symmetric_multiply(pattern, K, lambda);
    double gdensity = 0;
    for (int i = 0; i < model_.num_vertices(); ++i) gdensity -= w[i] * lambda.segment<3>(3 * i).dot(r.y.segment<3>(3 * i));
    gp[density_block.offset] += gdensity;
    gx = std::move(gx_prev);
    gv = std::move(gv_prev);
    if (progress) progress->step(T - t, T);
  }
  return {gp, gx, gv};
}

}  // namespace drapelab
