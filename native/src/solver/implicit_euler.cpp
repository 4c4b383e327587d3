#include "solver/implicit_euler.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <sstream>
#include <cstdio>
#include <cstdlib>

#include "contact/stepped_contact.hpp"
#include "solver/contact_linear_solve.hpp"
#include "util/error.hpp"

namespace drapelab {

namespace {
double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

// Every step kind ends here: a non-finite or faster-than-max_speed velocity means the rollout diverged.
void check_not_diverged(const Eigen::VectorXd& v_next, const RolloutOptions& options, int step) {
  double max_speed = 0;
  for (Eigen::Index i = 0; i < v_next.size() / 3; ++i) max_speed = std::max(max_speed, v_next.segment<3>(3 * i).norm());
  if (!v_next.allFinite() || max_speed > options.max_speed) {
    std::ostringstream s;
    s << "rollout: step " << step << " diverged (max vertex speed " << max_speed << " m/s > " << options.max_speed
      << " m/s); reduce the time step or check the parameters";
    throw SolverError(s.str());
  }
}

// Factorises a step's matrix (the contact-free step and each linearised contact iteration); a matrix that is not
// positive definite ends the rollout.
void factorize_step(CholmodSolver& solver, const Eigen::VectorXd& A, int step) {
  if (!solver.factorize(A)) {
    std::ostringstream s;
    s << "rollout: step " << step << " matrix is not positive definite (";
    if (solver.failed_dof() >= 0) s << "at vertex " << solver.failed_dof() / 3 << "; ";
    s << "some term's Hessian made it indefinite: check the material's stiffness tables, the mesh for degenerate "
         "triangles, or reduce the time step)";
    throw SolverError(s.str());
  }
}

// Moving obstacles (Term::obstacle_progress, a garment's body): each advances toward its end pose with the cloth
// near it carried along (obstacle_carry), as far as collision detection allows: the obstacle's own check on the
// relative motion and every other term's max_step on the cloth's move (self contact's CCD). Returns true when
// every obstacle is at its end pose; x stays intersection-free and clear of the obstacles.
bool advance_obstacles(const Model& model, Eigen::VectorXd& x, const Eigen::VectorXd& p) {
  bool done = true;
  for (const auto& t : model.terms()) {
    if (t->obstacle_progress() >= 1) continue;
    Eigen::VectorXd u = Eigen::VectorXd::Zero(x.size());
    t->obstacle_carry(x, u);
    double tau = t->obstacle_max_advance(x, u);
    const double own = tau;
    if (u.lpNorm<Eigen::Infinity>() > 0)
      for (const auto& o : model.terms())
        if (o.get() != t.get()) tau = std::min(tau, o->max_step(x, u, p));
    if (std::getenv("DRAPELAB_DEBUG_CROSSING"))
      std::fprintf(stderr, "obstacle advance: %.3g (its own bound %.3g), carry up to %.3g m\n", tau, own,
                   u.lpNorm<Eigen::Infinity>());
    if (tau > 0) {
      x += tau * u;
      t->advance_obstacle(tau);
    }
    done = done && t->obstacle_progress() >= 1;
  }
  return done;
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
  if (!(options.contact_direction_tolerance > 0) || !(options.contact_direction_tolerance < 1))
    throw InputError("rollout: contact_direction_tolerance must be in (0, 1)");
  if (options.record && options.contact_direction_tolerance > RolloutOptions{}.contact_direction_tolerance)
    throw InputError("rollout: contact_direction_tolerance above 1e-10 needs record = false (the adjoint "
                     "differentiates exact solves)");
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
  const bool contact = has_contact();
  for (int step = 0; step < options.steps; ++step) {
    if (contact && options.contact_step == RolloutOptions::ContactStep::kLinearised) {
      std::vector<ContactIterate> iterates;
      std::vector<std::shared_ptr<const void>> states;
      Eigen::VectorXd v_next = linear_contact_step(p, options, step, options.record ? &iterates : nullptr,
                                                   options.record ? &states : nullptr, kept_bytes);
      if (options.record)
        tape_.push_back({x_, v_, v_next - v_, CholmodSolver::Factor(), true, std::move(iterates), std::move(states)});
      x_ = x_ + h_ * v_next;
      v_ = std::move(v_next);
      if (progress) progress->step(step + 1, options.steps);
      continue;
    }
    if (contact) {
      Eigen::VectorXd v_next = contact_step(p, options, step);
      if (options.record) tape_.push_back({x_, v_, v_next - v_, CholmodSolver::Factor(), true, {}});
      x_ = x_ + h_ * v_next;
      v_ = std::move(v_next);
      if (progress) progress->step(step + 1, options.steps);
      continue;
    }
    for (const auto& t : model_.terms()) t->begin_step(x_, p, h_);  // step-start state (damping's x_t)
    auto t0 = std::chrono::steady_clock::now();
    step_system(x_, v_, p, h_, A, b);
    timing_.assemble += seconds_since(t0);
    t0 = std::chrono::steady_clock::now();
    factorize_step(solver_, A, step);
    timing_.factorize += seconds_since(t0);
    t0 = std::chrono::steady_clock::now();
    const Eigen::VectorXd y = solver_.solve(b);
    timing_.solve += seconds_since(t0);
    Eigen::VectorXd v_next = v_ + y;
    check_not_diverged(v_next, options, step);
    if (options.record) {
      CholmodSolver::Factor kept;
      const double bytes = static_cast<double>(solver_.kept_factor_bytes());
      if (kept_bytes + bytes <= options.factor_memory_mb * 1048576.0) {
        kept = solver_.keep_factor();
        kept_bytes += bytes;
      }
      tape_.push_back({x_, v_, y, std::move(kept), false, {}});
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
                                        ProgressSink* progress, const std::vector<Eigen::VectorXd>* alternatives,
                                        std::vector<Eigen::VectorXd>* alternative_gradients) {
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
  Eigen::VectorXd K, tmp, start_bar;
  const int T = static_cast<int>(tape_.size());
  timing_.backward_solve = timing_.backward_refactorize = timing_.backward_terms = timing_.backward_start = 0;
  timing_.backward_refactorizations = 0;
  // the alternatives (header): per alternative, the terms that read a parameter that differs, and their dL/dp
  // contributions at the alternative (plus) and at the recorded parameters (minus)
  const int num_alternatives = alternatives ? static_cast<int>(alternatives->size()) : 0;
  if (num_alternatives > 0 && !alternative_gradients)
    throw InputError("backward: alternatives need somewhere to put their gradients");
  std::vector<std::vector<int>> alternative_terms(num_alternatives);
  std::vector<Eigen::VectorXd> plus(num_alternatives), minus(num_alternatives);
  for (int a = 0; a < num_alternatives; ++a) {
    const Eigen::VectorXd& q = (*alternatives)[a];
    if (q.size() != p_.size() || !q.allFinite())
      throw InputError("backward: alternative parameters " + std::to_string(a) + " have the wrong size or are not "
                       "finite");
    std::vector<char> mask(p_.size(), 0);
    for (Eigen::Index i = 0; i < p_.size(); ++i) mask[i] = q[i] != p_[i];
    for (int i = density_block.offset; i < density_block.offset + density_block.size; ++i)
      if (mask[i]) throw InputError("backward: an alternative's density differs from the rollout's (the masses)");
    for (int k = 0; k < static_cast<int>(model_.terms().size()); ++k)
      if (model_.terms()[k]->reads_parameters(mask)) alternative_terms[a].push_back(k);
    plus[a].setZero(p_.size());
    minus[a].setZero(p_.size());
  }
  if (num_alternatives > 0)
    for (const auto& r : tape_)
      if (r.contact) throw InputError("backward: alternative parameters are not supported with contact steps");
  Eigen::VectorXd scratch_x, scratch_v;
  if (num_alternatives > 0) {
    scratch_x.setZero(n);
    scratch_v.setZero(n);
  }
  for (const auto& r : tape_)
    if (!r.iterates.empty()) {
      for (const auto& term : model_.terms())
        if (!term->provides_step_matrix_derivatives())
          throw InputError("backward: term " + term->name() + " cannot differentiate linearised contact steps "
                           "(roll out with contact_step = newton)");
      break;
    }
  for (int t = T - 1; t >= 0; --t) {
    const StepRecord& r = tape_[t];
    if (r.contact) {
      if (r.iterates.empty()) contact_step_adjoint(r, gx, gv, gp);
      else linear_contact_step_adjoint(r, gx, gv, gp);
      if (progress) progress->step(T - t, T);
      continue;
    }
    // x' = x + h v', v' = v + y
    for (const auto& term : model_.terms()) term->resume_step(r.x, p_, h);  // the step's start state, as forward
    const Eigen::VectorXd gv_total = gv + h * gx;
    Eigen::VectorXd lambda;
    auto t0 = std::chrono::steady_clock::now();
    if (r.factor) {
      lambda = solver_.solve_with(r.factor, gv_total);
      timing_.backward_solve += seconds_since(t0);
    } else {  // not kept (memory budget): the same matrix, refactorised
      Eigen::VectorXd A, b;
      step_system(r.x, r.v, p_, h, A, b);
      if (!solver_.factorize(A)) throw SolverError("backward: step matrix is not positive definite");
      ++timing_.backward_refactorizations;
      timing_.backward_refactorize += seconds_since(t0);
      t0 = std::chrono::steady_clock::now();
      lambda = solver_.solve(gv_total);
      timing_.backward_solve += seconds_since(t0);
    }
    t0 = std::chrono::steady_clock::now();
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
    for (int a = 0; a < num_alternatives; ++a)
      for (int k : alternative_terms[a]) {  // only their dL/dp is kept; the scratch takes the rest
        Term& term = *model_.terms()[k];
        term.resume_step(r.x, (*alternatives)[a], h);
        term.add_step_adjoint(r.x, (*alternatives)[a], lambda, v_next, h, scratch_x, scratch_v, plus[a]);
        term.resume_step(r.x, p_, h);
        term.add_step_adjoint(r.x, p_, lambda, v_next, h, scratch_x, scratch_v, minus[a]);
      }
    timing_.backward_terms += seconds_since(t0);
    t0 = std::chrono::steady_clock::now();
    // Terms that depend on the step start x_t besides x (damping): the x_t-derivative of lambda . (h grad E +
    // h^2 K v') at fixed x (Term::add_step_start_adjoint).
    start_bar.setZero(n);
    for (const auto& term : model_.terms()) term->add_step_start_adjoint(r.x, p_, lambda, v_next, h, start_bar);
    gx_prev -= h * start_bar;
    timing_.backward_start += seconds_since(t0);
    double gdensity = 0;
    for (int i = 0; i < model_.num_vertices(); ++i) gdensity -= w[i] * lambda.segment<3>(3 * i).dot(r.y.segment<3>(3 * i));
    gp[density_block.offset] += gdensity;
    gx = std::move(gx_prev);
    gv = std::move(gv_prev);
    if (progress) progress->step(T - t, T);
  }
  if (num_alternatives > 0) {
    alternative_gradients->resize(num_alternatives);
    for (int a = 0; a < num_alternatives; ++a) (*alternative_gradients)[a] = gp + plus[a] - minus[a];
  }
  return {gp, gx, gv};
}

void ImplicitEuler::contact_matrix(int kind, const Eigen::VectorXd& x, const Eigen::VectorXd& p, double inv_h2,
                                   const Eigen::VectorXd& m, Eigen::VectorXd& A) const {
  const SparsePattern& pattern = model_.pattern();
  A.setZero(pattern.nnz());
  for (const auto& t : model_.terms()) {
    if (kind == 3) t->add_step_matrix(x, p, 1.0, A);
    else if (kind == 0 || (t->is_contact() && kind == 1)) t->add_hessian(x, p, 1.0, A);
    else if (t->is_contact()) t->add_projected_hessian(x, p, 1.0, A);
    else t->add_static_newton_matrix(x, p, 1.0, A);
  }
  for (int i = 0; i < model_.num_vertices(); ++i)
    for (int k = 0; k < 3; ++k) A[pattern.diagonal(3 * i + k)] += inv_h2 * m[i];
}

bool ImplicitEuler::has_contact() const {
  for (const auto& t : model_.terms())
    if (t->is_contact()) return true;
  return false;
}

namespace {
constexpr double kStandardGravity = 9.8;  // m/s^2: residual forces are measured in vertex weights
constexpr double kArmijo = 1e-4;          // sufficient decrease of the incremental potential
constexpr double kMinStep = 1e-6;         // smallest line-search step tried
// A Newton move this small (m) ends the iterations: the incremental potential no longer resolves it in double
// precision (a 10 cm specimen's potential changes by ~1e-16 relative), and the state is then as converged as
// the residual test can see.
constexpr double kNegligibleMove = 1e-9;
// Relative residual of the preconditioned CG solves with off-pattern contact couplings (Newton directions and
// adjoints): far below the Newton iterations' own accuracy.
constexpr double kOffpatternTolerance = 1e-10;
constexpr int kOffpatternMaxIterations = 200;
// Inexact linearised moves (unrecorded rollouts, contact_direction_tolerance above 1e-10): CG's iteration cap
// (6k viscose walking: 30 instead of 200 cut the time in CG by ~40 %, same outcome: no crossing, no penetration).
constexpr int kInexactDirectionMaxIterations = 30;
// The Newton directions of the contact step only need to descend (the line search and the residual test decide):
// CG stops at this relative residual (inexact Newton: a forcing term this small keeps the local convergence),
// and a capped CG's iterate is used if it descends.
constexpr double kNewtonDirectionTolerance = 1e-3;
// Linearised contact steps: the shortest cut move (a fraction of the linearised move) before the step gives up.
constexpr double kMinCut = 1.0 / (1 << 30);
// The remainder that goes with contact_matrix's kind.
OffpatternOperator offpattern_operator(int kind) {
  return kind == 0 || kind == 1 ? OffpatternOperator::kExactHessian
         : kind == 2            ? OffpatternOperator::kProjectedHessian
                                : OffpatternOperator::kStepMatrix;
}
}  // namespace

Eigen::VectorXd ImplicitEuler::contact_step(const Eigen::VectorXd& p, const RolloutOptions& options, int step) {
  const int n = model_.num_dofs(), nv = model_.num_vertices();
  const double h = h_, inv_h2 = 1.0 / (h * h);
  const Eigen::VectorXd m = model_.masses(p);
  for (const auto& t : model_.terms()) t->begin_step(x_, p, h);
  const Eigen::VectorXd x_hat = x_ + h * v_;
  auto potential = [&](const Eigen::VectorXd& x) {
    double inertia = 0;
    for (int i = 0; i < nv; ++i) inertia += m[i] * (x.segment<3>(3 * i) - x_hat.segment<3>(3 * i)).squaredNorm();
    return 0.5 * inv_h2 * inertia + model_.energy(x, p);
  };
  auto gradient = [&](const Eigen::VectorXd& x, Eigen::VectorXd& g) {
    g.setZero(n);
    model_.add_gradient(x, p, g);
    for (int i = 0; i < nv; ++i) g.segment<3>(3 * i) += inv_h2 * m[i] * (x.segment<3>(3 * i) - x_hat.segment<3>(3 * i));
  };
  auto residual = [&](const Eigen::VectorXd& g) {
    double r = 0;
    for (int i = 0; i < nv; ++i) r = std::max(r, g.segment<3>(3 * i).norm() / (m[i] * kStandardGravity));
    return r;
  };
  const bool offpattern = has_offpattern_terms(model_);
  Eigen::VectorXd x = x_, g, A, dx, xn;
  // The body moves within the step (its start pose first): as far as collision detection allows now, the rest
  // between Newton iterations (which move the cloth it presses out of its way).
  bool obstacles_done = advance_obstacles(model_, x, p);
  const bool debug_crossing = std::getenv("DRAPELAB_DEBUG_CROSSING") != nullptr;
  auto crossed = [&](const Eigen::VectorXd& y, const char* where) {
    if (!debug_crossing) return;
    for (const auto& t : model_.terms()) {
      try {
        t->begin_step(y, p, h);
      } catch (const std::exception& e) {
        std::fprintf(stderr, "step %d CROSSED %s: %s\n", step, where, e.what());
      }
      t->begin_step(x_, p, h);
    }
  };
  crossed(x, "after the body's first advance");
  double Phi = potential(x);
  if (!std::isfinite(Phi)) {
    std::ostringstream s;
    s << "rollout: step " << step << " starts in contact (a vertex touches an obstacle or the cloth itself, or a "
      << "moving obstacle passed through the cloth: use shorter steps)";
    throw SolverError(s.str());
  }
  // Start from the inertial prediction x_hat as far as collision detection allows (x_t if that is no better):
  // away from first impacts it is within a Newton step or two of the minimiser.
  {
    dx = x_hat - x;
    double alpha = 1.0;
    for (const auto& t : model_.terms()) alpha = std::min(alpha, t->max_step(x, dx, p));
    xn = x + alpha * dx;
    const double Pn = potential(xn);
    if (std::isfinite(Pn) && Pn < Phi) {
      x = xn;
      Phi = Pn;
      crossed(x, "after the inertial start");
    }
  }
  gradient(x, g);
  // Each iteration starts with the matrix kind that served the last one (every 4th iteration tries from the exact
  // Hessian again): a kind that did not factorise usually fails again next iteration, and each failure costs an
  // assembly and a factorisation (soft viscose walking: kinds 0-2 failed in most iterations, 4 factorisations each).
  int last_kind = 0, since_probe = 0;
  bool probe_exact = false;
  for (int it = 0; it < options.contact_max_iterations; ++it) {
    if (!obstacles_done) {
      obstacles_done = advance_obstacles(model_, x, p);
      Phi = potential(x);
      gradient(x, g);
      crossed(x, "after the body's advance");
      if (debug_crossing) {
        double progress = 1;
        for (const auto& t : model_.terms()) progress = std::min(progress, t->obstacle_progress());
        std::fprintf(stderr, "step %d it %d body at %.6f of its motion, potential %.6g\n", step, it, progress, Phi);
      }
    }
    const double r = residual(g);
    if (r < options.contact_force_tolerance && obstacles_done) break;
    auto t0 = std::chrono::steady_clock::now();
    // Newton matrix: the static solve's (exact stretch with its compression softening, Gauss-Newton bending;
    // StaticSolver) plus the contact terms' exact Hessians (over the rounded rim the barrier's Hessian is
    // indefinite sideways; the inertia M/h^2 usually holds the sum definite, and projecting it per vertex
    // made convergence linear); failing that, their PSD projections; failing that, the PSD step matrix K
    // (K alone drops the membrane's compression softening and crawls: 10-50 iterations per step).
    // Terms with couplings outside the pattern (self contact): the direction solves the full operator by
    // preconditioned CG (solver/contact_linear_solve.hpp); an indefinite full operator moves on to the next kind.
    bool factorised = false;
    double solve_seconds = 0;
    const int first_kind = (last_kind == 0 || probe_exact || ++since_probe % 4 == 0) ? 0 : last_kind;
    if (first_kind == 0) since_probe = 0;
    const bool probed = probe_exact;
    probe_exact = false;
    // From the last kind that worked up; failing all those, the ones before it.
    for (int k = 0; k < 4 && !factorised; ++k) {
      const int kind = (first_kind + k) % 4;
      if (k > 0 && kind == 0 && debug_crossing)
        std::fprintf(stderr, "step %d it %d kinds %d-3 failed: from 0\n", step, it, first_kind);
      contact_matrix(kind, x, p, inv_h2, m, A);
      factorised = solver_.factorize(A);
      ++timing_.factorizations;
      if (debug_crossing && !factorised) std::fprintf(stderr, "step %d it %d kind %d not factorised\n", step, it, kind);
      if (factorised) {
        const auto ts = std::chrono::steady_clock::now();
        if (offpattern) {
          Eigen::VectorXd y;
          // an indefinite full operator may still let CG finish: a direction that does not descend moves on too
          OffpatternSolveStats cg;
          bool solved = solve_with_offpattern(model_, solver_, A, x, p, offpattern_operator(kind), g, y,
                                              kNewtonDirectionTolerance, kOffpatternMaxIterations, &cg);
          // CG that ran out of iterations on a definite operator still gives a descent direction (every CG
          // iterate does): an inexact Newton step (a stiff contact's ill-conditioned operator; before, the step
          // failed as "not positive definite").
          if (!solved && cg.iterations == kOffpatternMaxIterations) solved = y.allFinite();
          timing_.cg_iterations += cg.iterations;
          factorised = solved && g.dot(y) > 0;
          if (debug_crossing && !factorised)
            std::fprintf(stderr, "step %d it %d kind %d CG %s after %d iterations (relative residual %.3g), g.y %.3g\n",
                         step, it, kind, solved ? "solved" : "failed", cg.iterations, cg.relative_residual, g.dot(y));
          dx = -y;
        } else {
          dx = -solver_.solve(g);
        }
        solve_seconds += seconds_since(ts);
      }
      if (factorised) last_kind = kind;
    }
    if (!factorised) {
      std::ostringstream s;
      s << "rollout: step " << step << " contact Newton matrix is not positive definite";
      throw SolverError(s.str());
    }
    timing_.factorize += seconds_since(t0) - solve_seconds;
    timing_.solve += solve_seconds;
    ++timing_.newton_iterations;
    if (dx.lpNorm<Eigen::Infinity>() < kNegligibleMove) {  // below what the potential resolves
      xn = x + dx;
      if (std::isfinite(potential(xn))) x = xn;
      // Converged only if the exact Hessian gave the move: a substitute (projected or step matrix) can give a
      // negligible move while soft directions still carry force (the adjoint differentiates the minimiser).
      if ((last_kind == 0 || probed) && obstacles_done) break;  // (the exact Hessian was tried and did not
      probe_exact = true;                   // factorise: as converged as the substitutes can make it)
      gradient(x, g);
      continue;
    }
    double alpha = 1.0;
    for (const auto& t : model_.terms()) alpha = std::min(alpha, t->max_step(x, dx, p));
    const double bound = alpha;  // collision detection's bound: no move beyond it
    const double slope = g.dot(dx);
    bool accepted = false;
    for (; alpha > kMinStep; alpha *= 0.5) {
      xn = x + alpha * dx;
      const double Pn = potential(xn);
      if (std::isfinite(Pn) && Pn <= Phi + kArmijo * alpha * slope) {
        x = xn;
        Phi = Pn;
        accepted = true;
        crossed(x, "after a line search");
        break;
      }
    }
    if (std::getenv("DRAPELAB_DEBUG_CONTACT"))
      std::fprintf(stderr, "step %d it %d kind %d residual %.3g cap %.3g alpha %.3g |dx| %.3g\n", step, it, last_kind, r,
                   [&] { double c = 1; for (const auto& t : model_.terms()) c = std::min(c, t->max_step(x, dx, p)); return c; }(),
                   accepted ? alpha : 0.0, dx.lpNorm<Eigen::Infinity>());
    if (!accepted) {
      // Round-off: the potential no longer resolves the decrease (its value is large against the step's change).
      // The Newton direction still lowers the residual: backtrack on the residual instead, from the collision
      // bound down, and keep the first step that lowers it (the line search on the potential ends near 1e-6 of
      // the weight, which left the forward short of the minimiser its adjoint differentiates).
      Eigen::VectorXd gn;
      bool lowered = false;
      for (double a = bound; a > kMinStep && !lowered; a *= 0.5) {
        xn = x + a * dx;
        if (!std::isfinite(potential(xn))) continue;
        gradient(xn, gn);
        lowered = residual(gn) < r;
      }
      if (debug_crossing) std::fprintf(stderr, "step %d it %d round-off fallback %s\n", step, it, lowered ? "lowered" : "failed");
      if (lowered) {
        x = xn;
        crossed(x, "after the round-off fallback");
        Phi = potential(x);
        g = gn;
        continue;
      }
      if (obstacles_done) break;  // the last collision-free iterate is kept
      continue;                   // (the body still moves: its advance changes the state)
    }
    gradient(x, g);
  }
  if (!obstacles_done) {
    std::ostringstream s;
    s << "rollout: step " << step << " the moving body did not reach its end pose in "
      << options.contact_max_iterations << " Newton iterations (cloth caught against it): use shorter steps";
    throw SolverError(s.str());
  }
  if (debug_crossing) { gradient(x, g); std::fprintf(stderr, "step %d end residual %.3g kind %d\n", step, residual(g), last_kind); }
  Eigen::VectorXd v_next = (x - x_) / h;
  check_not_diverged(v_next, options, step);
  return v_next;
}

void ImplicitEuler::contact_step_adjoint(const StepRecord& r, Eigen::VectorXd& gx, Eigen::VectorXd& gv,
                                         Eigen::VectorXd& gp) {
  // Forward: x' = argmin Phi(x; x_hat, p), x_hat = x + h v, v' = (x' - x)/h. With gbar = dL/dx' + dL/dv' / h and
  // H lambda = gbar (H = M/h^2 + Hess E at x'): dL/dx_hat = M lambda / h^2, dL/dp = -lambda . d(grad Phi)/dp.
  const int nv = model_.num_vertices();
  const double h = h_, inv_h2 = 1.0 / (h * h);
  const Eigen::VectorXd m = model_.masses(p_);
  const Eigen::VectorXd v_next = r.v + r.y;
  const Eigen::VectorXd x_next = r.x + h * v_next, x_hat = r.x + h * r.v;
  // The lagged friction state of this step, as the forward had it.
  for (const auto& t : model_.terms()) t->resume_step(r.x, p_, h);
  const Eigen::VectorXd gbar = gx + gv / h;
  // The exact Hessian of the potential; where the minimiser is only a saddle of its quadratic model (the
  // Newton iterations then ran on a definite substitute, see contact_step), the same substitutes in turn: the
  // gradient is then that of the substitute's linearisation (counted in timing().inexact_adjoint_steps). With
  // off-pattern couplings (self contact) each is the assembled part plus their products: CG preconditioned with
  // the assembled part's factor (solver/contact_linear_solve.hpp).
  const bool offpattern = has_offpattern_terms(model_);
  Eigen::VectorXd H, lambda;
  bool solved = false;
  for (int kind = 0; kind < 4 && !solved; ++kind) {
    contact_matrix(kind, x_next, p_, inv_h2, m, H);
    solved = solver_.factorize(H);
    if (solved) {
      if (offpattern) solved = solve_with_offpattern(model_, solver_, H, x_next, p_, offpattern_operator(kind), gbar,
                                                     lambda, kOffpatternTolerance);
      else lambda = solver_.solve(gbar);
    }
    if (solved && kind > 0) ++timing_.inexact_adjoint_steps;
  }
  if (!solved) throw SolverError("backward: no definite matrix for a contact step's adjoint");
  for (const auto& t : model_.terms()) t->add_gradient_parameter_product(x_next, p_, lambda, -1.0, gp);
  const auto& density_block = model_.layout().block("density");
  const Eigen::VectorXd& w = model_.area_weights();
  double gdensity = 0;
  for (int i = 0; i < nv; ++i)
    gdensity -= inv_h2 * w[i] * lambda.segment<3>(3 * i).dot(x_next.segment<3>(3 * i) - x_hat.segment<3>(3 * i));
  gp[density_block.offset] += gdensity;
  // The lagged friction's slip starts at x_t: dL/dx_t -= lambda . d(grad E)/dx_t.
  Eigen::VectorXd start_bar = Eigen::VectorXd::Zero(lambda.size());
  for (const auto& t : model_.terms()) t->add_step_start_adjoint(x_next, p_, lambda, lambda, 0.0, start_bar);
  Eigen::VectorXd Ml(lambda.size());
  for (int i = 0; i < nv; ++i) Ml.segment<3>(3 * i) = m[i] * lambda.segment<3>(3 * i);
  gx = inv_h2 * Ml - gv / h - start_bar;
  gv = Ml / h;
}

void ImplicitEuler::linear_contact_system(const Eigen::VectorXd& x, const Eigen::VectorXd& x_hat,
                                          const Eigen::VectorXd& p, double inv_h2, const Eigen::VectorXd& m,
                                          Eigen::VectorXd& A, Eigen::VectorXd& g) const {
  const SparsePattern& pattern = model_.pattern();
  const int n = model_.num_dofs();
  A.setZero(pattern.nnz());
  g.setZero(n);
  // The terms' fused passes (Term::add_step_system) with v = 0: K(x) and grad E(x).
  const Eigen::VectorXd zero = Eigen::VectorXd::Zero(n);
  Eigen::VectorXd unused = Eigen::VectorXd::Zero(n);
  for (const auto& t : model_.terms())
    if (!t->add_step_system(x, p, zero, 1.0, A, unused, g)) {
      t->add_step_matrix(x, p, 1.0, A);
      t->add_gradient(x, p, g);
    }
  for (int i = 0; i < model_.num_vertices(); ++i)
    for (int k = 0; k < 3; ++k) {
      A[pattern.diagonal(3 * i + k)] += inv_h2 * m[i];
      g[3 * i + k] += inv_h2 * m[i] * (x[3 * i + k] - x_hat[3 * i + k]);
    }
}

Eigen::VectorXd ImplicitEuler::linear_contact_step(const Eigen::VectorXd& p, const RolloutOptions& options, int step,
                                                   std::vector<ContactIterate>* iterates,
                                                   std::vector<std::shared_ptr<const void>>* term_states,
                                                   double& kept_bytes) {
  const double h = h_, inv_h2 = 1.0 / (h * h);
  const Eigen::VectorXd m = model_.masses(p);
  // The rollout's first state is checked (begin_step: intersection-free); every later one is the end of a step
  // whose moves were all bounded by max_step (CCD), hence intersection-free too: continue_step skips the check.
  for (const auto& t : model_.terms()) {
    auto* stepped = dynamic_cast<SteppedContact*>(t.get());
    if (stepped && step > 0) stepped->continue_step(x_, p, h);
    else t->begin_step(x_, p, h);
    if (term_states) term_states->push_back(stepped ? stepped->step_state() : nullptr);
  }
  const Eigen::VectorXd x_hat = x_ + h * v_;
  Eigen::VectorXd x = x_, A, g, dx;
  // A moving body (a garment's) advances as far as collision detection allows, and again after each iteration
  // (which moves the cloth it presses out of its way) until it is at its end pose; the step ends with the body
  // there and an uncut move. Recorded rollouts (the adjoint) need the body's motion done in the first advance.
  bool obstacles_done = advance_obstacles(model_, x, p);
  if (!obstacles_done && iterates) {
    std::ostringstream s;
    s << "rollout: step " << step << " the moving body cannot reach its end pose within collision detection's "
      << "bound in one move (use contact_step = newton, or shorter steps)";
    throw SolverError(s.str());
  }
  // Only a contact term's energy can be infinite (a state in contact).
  double contact_energy = 0;
  for (const auto& t : model_.terms())
    if (t->is_contact()) contact_energy += t->energy(x, p);
  if (!std::isfinite(contact_energy)) {
    std::ostringstream s;
    s << "rollout: step " << step << " starts in contact (a vertex touches an obstacle or the cloth itself, or a "
      << "moving obstacle passed through the cloth: use shorter steps)";
    throw SolverError(s.str());
  }
  const bool offpattern = has_offpattern_terms(model_);
  for (int it = 0; it < std::max(1, options.contact_max_iterations); ++it) {
    if (it > 0 && !obstacles_done) obstacles_done = advance_obstacles(model_, x, p);
    auto t0 = std::chrono::steady_clock::now();
    bool coupled = false;  // off-pattern couplings present (then the adjoint's CG needs the matrix values)
    linear_contact_system(x, x_hat, p, inv_h2, m, A, g);
    timing_.assemble += seconds_since(t0);
    t0 = std::chrono::steady_clock::now();
    const bool inexact = !iterates && offpattern && options.contact_direction_tolerance > kOffpatternTolerance;
    factorize_step(solver_, A, step);
    ++timing_.factorizations;
    timing_.factorize += seconds_since(t0);
    t0 = std::chrono::steady_clock::now();
    if (offpattern) {
      Eigen::VectorXd y;
      OffpatternSolveStats stats;
      bool solved = solve_with_offpattern(model_, solver_, A, x, p, OffpatternOperator::kStepMatrix, g, y,
                                          options.contact_direction_tolerance,
                                          inexact ? kInexactDirectionMaxIterations : kOffpatternMaxIterations, &stats);
      // An inexact direction (not recorded): CG's last iterate, capped or stopped where the step matrix's pair
      // couplings lost definiteness (truncated CG), serves if it descends.
      if (!solved && !iterates && options.contact_direction_tolerance > kOffpatternTolerance)
        solved = y.allFinite() && g.dot(y) > 0;
      if (!solved) {
        std::ostringstream s;
        s << "rollout: step " << step << " contact solve did not converge";
        throw SolverError(s.str());
      }
      timing_.cg_iterations += stats.iterations;
      coupled = stats.coupled;
      dx = -y;
    } else {
      dx = -solver_.solve(g);
    }
    timing_.solve += seconds_since(t0);
    t0 = std::chrono::steady_clock::now();
    double bound = 1.0;
    const Term* binding = nullptr;  // the term whose collision detection allows least (for the debug line)
    for (const auto& t : model_.terms()) {
      const double b = t->max_step(x, dx, p);
      if (b < bound) {
        bound = b;
        binding = t.get();
      }
    }
    // The largest power-of-two fraction within the bound: piecewise constant in the step's inputs (the bound
    // itself varies continuously), so that holding it constant is the exact adjoint almost everywhere.
    double alpha = 1.0;
    while (alpha > bound && alpha > kMinCut) alpha *= 0.5;
    if (alpha > bound) {
      std::ostringstream s;
      s << "rollout: step " << step << " collision detection allows no move (a contact closed to round-off)";
      throw SolverError(s.str());
    }
    timing_.collision += seconds_since(t0);
    ++timing_.newton_iterations;
    if (std::getenv("DRAPELAB_DEBUG_CONTACT"))
      std::fprintf(stderr, "step %d linear it %d cap %.3g bound %.3g by %s |dx| %.3g\n", step, it, alpha, bound,
                   binding ? binding->name().c_str() : "-", dx.lpNorm<Eigen::Infinity>());
    if (iterates) {
      ContactIterate r{x, dx, alpha, CholmodSolver::Factor(), Eigen::VectorXd(), {}};
      for (const auto& t : model_.terms()) {  // what the terms found at x (the adjoint restores it)
        auto* stepped = dynamic_cast<SteppedContact*>(t.get());
        r.term_states.push_back(stepped ? stepped->iterate_state(x) : nullptr);
      }
      const double bytes = static_cast<double>(solver_.kept_factor_bytes()) + (coupled ? 8.0 * A.size() : 0.0);
      if (kept_bytes + bytes <= options.factor_memory_mb * options.contact_factor_memory_scale * 1048576.0) {
        r.factor = solver_.keep_factor();
        if (coupled) r.matrix = A;
        kept_bytes += bytes;
      }
      iterates->push_back(std::move(r));
    }
    x += alpha * dx;
    if (alpha >= 1.0 && obstacles_done) break;
    if (alpha < 1.0) ++timing_.cut_iterations;
  }
  if (!obstacles_done) {
    std::ostringstream s;
    s << "rollout: step " << step << " the moving body did not reach its end pose in "
      << options.contact_max_iterations << " iterations (cloth caught against it): use shorter steps";
    throw SolverError(s.str());
  }
  Eigen::VectorXd v_next = (x - x_) / h;
  check_not_diverged(v_next, options, step);
  return v_next;
}

void ImplicitEuler::linear_contact_step_adjoint(const StepRecord& r, Eigen::VectorXd& gx, Eigen::VectorXd& gv,
                                                Eigen::VectorXd& gp) {
  // Iteration k: x_{k+1} = x_k - alpha_k A_k^-1 g_k, A_k = M/h^2 + K(x_k), g_k = M (x_k - x_hat)/h^2 + grad E(x_k).
  // With xbar = dL/dx_{k+1} and lambda = alpha_k A_k^-1 xbar:
  //   dL/dx_k = xbar - (M/h^2 + Hess E) lambda - d(lambda^T K dx_k)/dx,   dL/dx_hat += M lambda / h^2,
  //   dL/dp -= d(lambda . grad E)/dp + d(lambda^T K dx_k)/dp (+ the masses' part).
  // The last iterate is x_{t+1} = x_t + h v_{t+1}; x_0 = x_t (a moving obstacle's carried start: held as x_t).
  const int n = model_.num_dofs(), nv = model_.num_vertices();
  const double h = h_, inv_h2 = 1.0 / (h * h);
  const Eigen::VectorXd m = model_.masses(p_);
  const Eigen::VectorXd x_hat = r.x + h * r.v;
  const auto& density_block = model_.layout().block("density");
  const Eigen::VectorXd& w = model_.area_weights();
  const bool offpattern = has_offpattern_terms(model_);
  // The step's lagged friction state (and, for SteppedContact terms, the pairs the forward found at its start).
  for (size_t i = 0; i < model_.terms().size(); ++i) {
    const auto& t = model_.terms()[i];
    auto* stepped = dynamic_cast<SteppedContact*>(t.get());
    if (stepped && i < r.term_states.size() && r.term_states[i]) stepped->restore_step(r.term_states[i]);
    else t->resume_step(r.x, p_, h);
  }
  Eigen::VectorXd xbar = gx + gv / h, xt_bar = -gv / h, xhat_bar = Eigen::VectorXd::Zero(n);
  Eigen::VectorXd start_bar = Eigen::VectorXd::Zero(n);  // d(sum_k lambda_k . (g_k + A_k dx_k))/dx_t at fixed x_k
  Eigen::VectorXd A, g, lambda, unused(n);
  for (int k = static_cast<int>(r.iterates.size()) - 1; k >= 0; --k) {
    const ContactIterate& it = r.iterates[k];
    for (size_t i = 0; i < it.term_states.size(); ++i)
      if (it.term_states[i])
        dynamic_cast<SteppedContact*>(model_.terms()[i].get())->restore_iterate(it.term_states[i], it.x);
    const Eigen::VectorXd rhs = it.alpha * xbar;
    const Eigen::VectorXd* values = &it.matrix;
    const CholmodSolver::Factor* factor = it.factor ? &it.factor : nullptr;
    auto t0 = std::chrono::steady_clock::now();
    if (!factor) {  // not kept (memory budget): the same matrix, refactorised
      linear_contact_system(it.x, x_hat, p_, inv_h2, m, A, g);
      if (!solver_.factorize(A)) throw SolverError("backward: a contact step's matrix is not positive definite");
      values = &A;
      ++timing_.backward_refactorizations;
      timing_.backward_refactorize += seconds_since(t0);
      t0 = std::chrono::steady_clock::now();
    }
    if (offpattern) {
      OffpatternSolveStats stats;
      bool solved = solve_with_offpattern(model_, solver_, *values, it.x, p_, OffpatternOperator::kStepMatrix, rhs,
                                          lambda, kOffpatternTolerance, kOffpatternMaxIterations, &stats, factor);
      if (!solved && stats.needs_matrix) {  // the forward kept no values (it saw no coupling): assemble them
        linear_contact_system(it.x, x_hat, p_, inv_h2, m, A, g);
        solved = solve_with_offpattern(model_, solver_, A, it.x, p_, OffpatternOperator::kStepMatrix, rhs, lambda,
                                       kOffpatternTolerance, kOffpatternMaxIterations, nullptr, factor);
      }
      if (!solved) throw SolverError("backward: a contact step's solve did not converge");
    } else {
      lambda = factor ? solver_.solve_with(*factor, rhs) : solver_.solve(rhs);
    }
    timing_.backward_solve += seconds_since(t0);
    Eigen::VectorXd xbar_prev = xbar;
    unused.setZero();
    for (const auto& t : model_.terms()) {
      t0 = std::chrono::steady_clock::now();
      t->add_step_adjoint(it.x, p_, lambda, it.dx, 1.0, xbar_prev, unused, gp);
      timing_.backward_terms += seconds_since(t0);
      t0 = std::chrono::steady_clock::now();
      t->add_step_start_adjoint(it.x, p_, lambda, it.dx, 1.0, start_bar);  // the lagged friction's slip start
      timing_.backward_start += seconds_since(t0);
    }
    double gdensity = 0;
    for (int i = 0; i < nv; ++i) {
      const Eigen::Vector3d l = lambda.segment<3>(3 * i);
      xbar_prev.segment<3>(3 * i) -= inv_h2 * m[i] * l;
      xhat_bar.segment<3>(3 * i) += inv_h2 * m[i] * l;
      gdensity -= inv_h2 * w[i] *
                  l.dot(it.x.segment<3>(3 * i) - x_hat.segment<3>(3 * i) + it.dx.segment<3>(3 * i));
    }
    gp[density_block.offset] += gdensity;
    xbar = std::move(xbar_prev);
  }
  gx = xt_bar + xbar + xhat_bar - start_bar;
  gv = h * xhat_bar;
}

}  // namespace drapelab
