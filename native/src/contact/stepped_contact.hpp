// What a time stepper (solver/implicit_euler.cpp) may ask of a contact term beyond Term, found by dynamic_cast
// (a capability of the pair contact terms, contact/pair_contact.hpp; other terms use Term's defaults):
//  - continue_step: begin the next step of a rollout from where the previous one ended, every move of which was
//    bounded by max_step, without begin_step's check that the state is intersection-free (the CCD bound keeps it
//    so; the rollout's first state is checked by begin_step);
//  - step_state / restore_step: the state a step began with (lagged friction, active pairs and broad-phase
//    candidates at the step's start), kept by the forward and handed back to the adjoint, so that the adjoint
//    resumes each step without a broad phase;
//  - iterate_state / restore_iterate: the same for each iteration of a linearised step (the active pairs at the
//    iterate), so that the adjoint of an iteration after a cut move (whose iterate is away from the step's start,
//    outside the restored candidates' reach) needs no broad phase either.
#pragma once
#include <Eigen/Core>
#include <memory>

namespace drapelab {

class SteppedContact {
 public:
  virtual ~SteppedContact() = default;
  virtual void continue_step(const Eigen::VectorXd& x, const Eigen::VectorXd& p, double h) = 0;
  // Taken right after begin_step or continue_step (opaque to the stepper).
  virtual std::shared_ptr<const void> step_state() const = 0;
  // The adjoint's return to the step that state was taken at (Term::resume_step, without its broad phase).
  virtual void restore_step(const std::shared_ptr<const void>& state) = 0;
  // Taken after an iteration's solve at iterate x (what the term found at x); null if it holds nothing for x.
  virtual std::shared_ptr<const void> iterate_state(const Eigen::VectorXd& x) const = 0;
  // The adjoint's return to iterate x (after restore_step of its step), with what iterate_state(x) took.
  virtual void restore_iterate(const std::shared_ptr<const void>& state, const Eigen::VectorXd& x) = 0;
};

}  // namespace drapelab
