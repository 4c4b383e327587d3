// Implicit Euler rollout (Baraff & Witkin 1998, one linearised solve per step, as in the paper) and its
// adjoint through the whole rollout.
//
// Step t: A = M + h^2 K(x_t),  b = h F(x_t) - h^2 K(x_t) v_t,  A y = b,  v_{t+1} = v_t + y,
//         x_{t+1} = x_t + h v_{t+1};  F = -dE/dx, K = the terms' PSD step matrix, M = lumped masses.
// The adjoint differentiates exactly this map (including dK/dx and dK/dp) and solves A^T lambda = ...
// With a contact term active (Term::is_contact: disk_contact, self_contact) a step works on IPC's incremental
// potential (Li et al. 2020, sec. 3), of which the step above is one Newton iteration from x_t:
//   Phi(x) = 1/(2h^2) (x - x_hat)^T M (x - x_hat) + E(x),   x_hat = x_t + h v_t,  v_{t+1} = (x_{t+1} - x_t)/h.
// RolloutOptions::contact_step chooses how:
// - kLinearised (default): the step above with the contact terms' step matrices and forces included, in position
//   form, x_{k+1} = x_k - alpha_k (M/h^2 + K(x_k))^-1 grad Phi(x_k) from x_0 = x_t, each move cut to what
//   continuous collision detection allows (alpha_k = min over terms of Term::max_step, so no iterate crosses a
//   contact); when the cut shortened the move (alpha_k < 1), another such iteration from x_{k+1}, up to
//   contact_max_iterations; the step ends with the first uncut move. Its adjoint differentiates exactly this
//   map (as the contact-free step's, through Term::add_step_adjoint, the alphas held constant: they are
//   piecewise constant in the inputs), iteration by iteration.
// - kNewton: the minimiser of Phi, found by Newton iterations whose every step is first bounded by collision
//   detection and then by an Armijo line search on the potential; converged when every vertex's residual force
//   is below RolloutOptions::contact_force_tolerance of its weight. Its adjoint is the implicit function theorem
//   at the minimiser (exact Hessian of the potential, lagged friction quantities held constant).
// Without contact terms the rollout is the linearised step above, bit for bit.
// The linearised adjoint keeps the forward factorisation for each step while the kept factors fit in
// RolloutOptions::factor_memory_mb (memory grows by (x_t, v_t, y_t, factor_t) per step; a linearised contact
// step keeps a factor per iteration, within contact_factor_memory_scale times that budget); later steps keep
// (x_t, v_t, y_t) only and the backward refactorises their matrix (same values, same result).
#pragma once
#include <Eigen/Core>
#include <memory>
#include <vector>

#include "physics/model.hpp"
#include "solver/cholmod_solver.hpp"
#include "util/progress.hpp"

namespace drapelab {

struct RolloutOptions {
  double time_step = 0.05;  // s
  int steps = 100;
  double max_speed = 50.0;  // m/s: a step producing a faster vertex is reported as diverged
  bool record = true;       // keep what the adjoint needs
  double factor_memory_mb = 1024.0;  // budget for the factors kept for the adjoint (beyond it: refactorised)
  // A linearised contact rollout keeps one factor per iteration, not per step (landing steps take several while
  // collision detection cuts the moves): its budget is this multiple of factor_memory_mb, so that as many of its
  // iterates are kept as a contact-free rollout keeps steps (circle3, 100 steps: ~140 iterates of 10.2 MB against
  // 100 within the default 1024 MB). 1 keeps the contact-free budget; factor_memory_mb = 0 keeps none either way.
  double contact_factor_memory_scale = 1.6;
  // Contact steps: linearised (one Newton iteration of the incremental potential, more only while collision
  // detection cuts the move) or Newton to the potential's minimiser (IPC); see the header.
  enum class ContactStep { kLinearised, kNewton };
  ContactStep contact_step = ContactStep::kLinearised;
  // kNewton: iterations end when every residual force is below this fraction of the vertex's weight, or after
  // contact_max_iterations (then the last collision-free iterate is kept). kLinearised: at most
  // contact_max_iterations iterations, another only while a move was cut or a moving obstacle (a garment's body,
  // unrecorded rollouts only) is still advancing (then the last, collision-free, iterate is kept; an obstacle
  // short of its end pose is a SolverError).
  double contact_force_tolerance = 1e-6;
  int contact_max_iterations = 50;
  // kLinearised with off-pattern couplings (self contact): relative residual of the CG solve of each move.
  // Recorded rollouts need the default (the adjoint differentiates exact solves); an animation that is not
  // differentiated (a garment) may solve to 1e-3 (inexact Newton), a capped CG's iterate then serving if it descends.
  double contact_direction_tolerance = 1e-10;
};

struct RolloutGradient {
  Eigen::VectorXd parameters;  // dL/dp (model layout)
  Eigen::VectorXd positions0;  // dL/dx_0
  Eigen::VectorXd velocities0; // dL/dv_0
};

class ImplicitEuler {
 public:
  explicit ImplicitEuler(const Model& model);

  // Rolls out from (x0, v0) (default: rest positions at rest). Returns the final positions.
  Eigen::VectorXd forward(const Eigen::VectorXd& parameters, const RolloutOptions& options,
                          ProgressSink* progress = nullptr, const Eigen::VectorXd* x0 = nullptr,
                          const Eigen::VectorXd* v0 = nullptr);
  // dL/d(p, x0, v0) given dL/dx_T (and optionally dL/dv_T) of the last forward (record = true).
  // `alternatives`: parameter vectors at which the step map is the same function of the state as at the recorded
  // parameters (a direction parameter while its amplitude is off: a tilt's azimuth at zero angle), so that the
  // rollout and its adjoint are the same; the caller's promise, checked only for the density (the masses). Their
  // dL/dp go to `alternative_gradients` from this one adjoint: the terms that read a parameter that differs
  // (Term::reads_parameters) are evaluated at both and their difference added. Not with contact steps.
  RolloutGradient backward(const Eigen::VectorXd& dL_dx, const Eigen::VectorXd* dL_dv = nullptr,
                           ProgressSink* progress = nullptr,
                           const std::vector<Eigen::VectorXd>* alternatives = nullptr,
                           std::vector<Eigen::VectorXd>* alternative_gradients = nullptr);

  const Eigen::VectorXd& positions() const { return x_; }
  const Eigen::VectorXd& velocities() const { return v_; }
  // Timing split of the last forward (seconds): assembly, factorisation, solves.
  struct Timing {
    double assemble = 0, factorize = 0, solve = 0;
    int newton_iterations = 0, factorizations = 0;  // contact steps (both kinds)
    int inexact_adjoint_steps = 0;  // contact steps whose adjoint used a definite substitute of the Hessian
    double collision = 0;           // contact steps: seconds in continuous collision detection (Term::max_step)
    int cg_iterations = 0;          // contact steps: CG iterations of solves with off-pattern couplings
    int cut_iterations = 0;         // linearised contact steps: iterations whose move collision detection cut
    // The last backward (seconds): solves with kept factors (CG included), refactorisations of iterates past the
    // factor budget (assembly + factorisation), the terms' adjoint passes, their step-start adjoints
    // (lagged friction); and how many iterates (contact steps) or steps it refactorised.
    double backward_solve = 0, backward_refactorize = 0, backward_terms = 0, backward_start = 0;
    int backward_refactorizations = 0;
  };
  const Timing& timing() const { return timing_; }
  CholmodSolver& linear_solver() { return solver_; }
  // A = M + h^2 K(x) (upper-triangle values) and b for one step; exposed for tests and benchmarks.
  void step_system(const Eigen::VectorXd& x, const Eigen::VectorXd& v, const Eigen::VectorXd& p, double h,
                   Eigen::VectorXd& A, Eigen::VectorXd& b) const;

 private:
  // One iteration of a linearised contact step: x_{k+1} = x + alpha dx, with its matrix's factor and values
  // (values only where off-pattern couplings are present: the adjoint's CG operator) when kept within
  // factor_memory_mb.
  struct ContactIterate {
    Eigen::VectorXd x, dx;
    double alpha = 1;
    CholmodSolver::Factor factor;
    Eigen::VectorXd matrix;
    // per term, its SteppedContact::iterate_state at x (null for other terms): the adjoint needs no broad phase
    std::vector<std::shared_ptr<const void>> term_states;
  };
  struct StepRecord {
    Eigen::VectorXd x, v, y;  // contact steps: y = v_{t+1} - v_t as well
    CholmodSolver::Factor factor;
    bool contact = false;
    std::vector<ContactIterate> iterates;  // linearised contact steps
    // linearised contact steps: per term, its SteppedContact::step_state (null for other terms)
    std::vector<std::shared_ptr<const void>> term_states;
  };
  bool has_contact() const;
  // The Newton matrix of a contact step, kind 0..3: M/h^2 + the exact Hessian; + exact contact Hessians and the
  // static solve's matrix for the rest; + projected contact Hessians and the static solve's matrix; + the PSD
  // step matrix K (each definite where the one before is not).
  void contact_matrix(int kind, const Eigen::VectorXd& x, const Eigen::VectorXd& p, double inv_h2,
                      const Eigen::VectorXd& m, Eigen::VectorXd& A) const;
  // One IPC step from (x_, v_): returns v_{t+1}. Throws SolverError naming the step if no descent is found.
  Eigen::VectorXd contact_step(const Eigen::VectorXd& p, const RolloutOptions& options, int step);
  // The adjoint of one IPC step (see the header): updates gx, gv (dL/dx_t, dL/dv_t) and gp.
  void contact_step_adjoint(const StepRecord& r, Eigen::VectorXd& gx, Eigen::VectorXd& gv, Eigen::VectorXd& gp);
  // A linearised contact step's matrix M/h^2 + K(x) (pattern values) and the potential's gradient at x.
  void linear_contact_system(const Eigen::VectorXd& x, const Eigen::VectorXd& x_hat, const Eigen::VectorXd& p,
                             double inv_h2, const Eigen::VectorXd& m, Eigen::VectorXd& A, Eigen::VectorXd& g) const;
  // One linearised contact step from (x_, v_): returns v_{t+1}; its iterations go to `iterates` and the terms'
  // step states to `term_states` (if recording), the factors kept while kept_bytes stays within the budget.
  // Steps after a rollout's first continue the previous one (SteppedContact::continue_step).
  Eigen::VectorXd linear_contact_step(const Eigen::VectorXd& p, const RolloutOptions& options, int step,
                                      std::vector<ContactIterate>* iterates,
                                      std::vector<std::shared_ptr<const void>>* term_states, double& kept_bytes);
  // Its adjoint: updates gx, gv (dL/dx_t, dL/dv_t) and gp.
  void linear_contact_step_adjoint(const StepRecord& r, Eigen::VectorXd& gx, Eigen::VectorXd& gv,
                                   Eigen::VectorXd& gp);
  const Model& model_;
  CholmodSolver solver_;
  std::vector<StepRecord> tape_;  // declared after solver_: factors freed before the solver
  Eigen::VectorXd x_, v_, p_;
  double h_ = 0;
  Timing timing_;
};

}  // namespace drapelab
