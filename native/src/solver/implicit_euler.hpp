// Implicit Euler rollout (Baraff & Witkin 1998, one linearised solve per step, as in the paper) and its
// adjoint through the whole rollout.
//
// Step t: A = M + h^2 K(x_t),  b = h F(x_t) - h^2 K(x_t) v_t,  A y = b,  v_{t+1} = v_t + y,
//         x_{t+1} = x_t + h v_{t+1};  F = -dE/dx, K = the terms' PSD step matrix, M = lumped masses.
// The adjoint differentiates exactly this map (including dK/dx and dK/dp) and solves A^T lambda = ...
// with the forward factorisation kept for each step while the kept factors fit in
// RolloutOptions::factor_memory_mb (memory grows by (x_t, v_t, y_t, factor_t) per step); later steps keep
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
  RolloutGradient backward(const Eigen::VectorXd& dL_dx, const Eigen::VectorXd* dL_dv = nullptr,
                           ProgressSink* progress = nullptr);

  const Eigen::VectorXd& positions() const { return x_; }
  const Eigen::VectorXd& velocities() const { return v_; }
  // Timing split of the last forward (seconds): assembly, factorisation, solves.
  struct Timing { double assemble = 0, factorize = 0, solve = 0; };
  const Timing& timing() const { return timing_; }
  CholmodSolver& linear_solver() { return solver_; }
  // A = M + h^2 K(x) (upper-triangle values) and b for one step; exposed for tests and benchmarks.
  void step_system(const Eigen::VectorXd& x, const Eigen::VectorXd& v, const Eigen::VectorXd& p, double h,
                   Eigen::VectorXd& A, Eigen::VectorXd& b) const;

 private:
  struct StepRecord {
    Eigen::VectorXd x, v, y;
    CholmodSolver::Factor factor;
  };
  const Model& model_;
  CholmodSolver solver_;
  std::vector<StepRecord> tape_;  // declared after solver_: factors freed before the solver
  Eigen::VectorXd x_, v_, p_;
  double h_ = 0;
  Timing timing_;
};

}  // namespace drapelab
