// One physical term of the cloth model (stretch, bend, gravity, handle, and later every optional effect).
//
// A term owns no state: it reads positions x (3V, metres) and the model's flat parameter vector p
// (see parameters.hpp) and adds its contributions. Everything a solver and its adjoint need:
//   energy E(x; p)                         [J]
//   gradient dE/dx                          [N]
//   step matrix K(x; p): a symmetric PSD approximation of d2E/dx2 (Gauss-Newton), used by the implicit
//     step A = M + h^2 K and as the Newton matrix of the static solve
//   exact Hessian d2E/dx2 and Hessian-vector products (adjoints)
//   parameter derivatives: dE/dp, d(lambda . dE/dx)/dp, and d(lambda^T K w)/d(x, p) (adjoint of A)
// Optional effects plug in as one more Term with its own named parameter block; off = not added.
#pragma once
#include <Eigen/Core>
#include <string>
#include <vector>

#include "physics/parameters.hpp"

namespace drapelab {

class SparsePattern;

class Term {
 public:
  virtual ~Term() = default;
  virtual std::string name() const = 0;

  // Vertex tuples coupled by this term (defines the sparsity pattern; once per model).
  virtual std::vector<std::vector<int>> stencils() const = 0;
  // Called once after the pattern is built: the term precomputes its scatter map.
  virtual void bind_pattern(const SparsePattern& pattern) = 0;

  virtual double energy(const Eigen::VectorXd& x, const Eigen::VectorXd& p) const = 0;
  virtual void add_gradient(const Eigen::VectorXd& x, const Eigen::VectorXd& p, Eigen::VectorXd& g) const = 0;
  virtual void add_step_matrix(const Eigen::VectorXd& x, const Eigen::VectorXd& p, double scale,
                               Eigen::VectorXd& values) const = 0;
  virtual void add_hessian(const Eigen::VectorXd& x, const Eigen::VectorXd& p, double scale,
                           Eigen::VectorXd& values) const = 0;
  // The exact Hessian with each element's block projected onto the PSD cone (util/psd_projection.hpp): the
  // static solve's Newton matrix where the exact Hessian is indefinite (folds still forming).
  virtual void add_projected_hessian(const Eigen::VectorXd& x, const Eigen::VectorXd& p, double scale,
                                     Eigen::VectorXd& values) const = 0;
  // The static solve's Newton matrix where the model's exact Hessian is indefinite (solver/static_solve.hpp):
  // the exact Hessian by default. A term whose exact Hessian carries an indefinite geometric part gives its
  // PSD step matrix instead (bending: E'(theta) Hess theta, the source of the indefiniteness in draped folds),
  // so the sum keeps the exact stretch Hessian, compression softening included, and stays factorisable.
  virtual void add_static_newton_matrix(const Eigen::VectorXd& x, const Eigen::VectorXd& p, double scale,
                                        Eigen::VectorXd& values) const {
    add_hessian(x, p, scale, values);
  }
  virtual void add_hessian_product(const Eigen::VectorXd& x, const Eigen::VectorXd& p, const Eigen::VectorXd& dir,
                                   Eigen::VectorXd& out) const = 0;
  // Whether anything the term computes reads a parameter i with mask[i] != 0 (mask: one entry per parameter).
  // ImplicitEuler::backward's alternative parameter vectors recompute only the terms that do. The default, true,
  // is always correct (the term is recomputed).
  virtual bool reads_parameters(const std::vector<char>& /*mask*/) const { return true; }
  // gp += dE/dp
  virtual void add_energy_parameter_gradient(const Eigen::VectorXd& x, const Eigen::VectorXd& p,
                                             Eigen::VectorXd& gp) const = 0;
  // gp += scale * d(lambda . dE/dx)/dp
  virtual void add_gradient_parameter_product(const Eigen::VectorXd& x, const Eigen::VectorXd& p,
                                              const Eigen::VectorXd& lambda, double scale,
                                              Eigen::VectorXd& gp) const = 0;
  // gx += scale * d(lambda^T K(x,p) w)/dx ; gp += scale * d(lambda^T K(x,p) w)/dp
  virtual void add_step_matrix_derivatives(const Eigen::VectorXd& x, const Eigen::VectorXd& p,
                                           const Eigen::VectorXd& lambda, const Eigen::VectorXd& w, double scale,
                                           Eigen::VectorXd& gx, Eigen::VectorXd& gp) const = 0;

  // Contact terms (contact/, physics effects disk_contact and self_contact) carry a barrier that is infinite
  // where surfaces touch; solvers then take nonlinear steps (solver/implicit_euler.hpp, static_solve.hpp)
  // bounded by max_step. Defaults: not a contact term, any step allowed, nothing lagged.
  virtual bool is_contact() const { return false; }
  // Largest fraction alpha in (0, 1] of the step dx from x such that every contact pair stays apart along
  // x + t dx for t in [0, alpha] (continuous collision detection, conservative).
  virtual double max_step(const Eigen::VectorXd& /*x*/, const Eigen::VectorXd& /*dx*/,
                          const Eigen::VectorXd& /*p*/) const {
    return 1.0;
  }
  // Called by a time stepper with the state at the start of each step (time step h [s]): lagged quantities
  // (friction's normal forces and tangent frames, IPC's lagged friction) are taken from it. h = 0: a
  // static solve (no friction: the static equilibrium is the frictionless one).
  virtual void begin_step(const Eigen::VectorXd& /*x*/, const Eigen::VectorXd& /*p*/, double /*h*/) {}
  // Kinematic obstacles that move within a step (a garment's body, garment/revolved_body.hpp). A step starts with
  // the obstacle at its start pose (progress 0; the start state is clear of it there) and must end with it at its
  // end pose (progress 1). The stepper advances it as far as collision detection allows, the cloth near it carried
  // along (obstacle_carry), every move checked (obstacle_max_advance on the relative motion, every other term's
  // max_step on the cloth's), and the rest between Newton iterations. Defaults: no moving obstacle.
  virtual double obstacle_progress() const { return 1.0; }
  // u += the cloth displacement that accompanies the rest of the obstacle's motion (zero away from it).
  virtual void obstacle_carry(const Eigen::VectorXd& /*x*/, Eigen::VectorXd& /*u*/) const {}
  // Largest fraction tau in [0, 1] of the rest of the obstacle's motion such that the cloth moving along
  // x + t u stays clear of the obstacle moving with it, t in [0, tau] (conservative).
  virtual double obstacle_max_advance(const Eigen::VectorXd& /*x*/, const Eigen::VectorXd& /*u*/) const { return 1.0; }
  // Moves the obstacle by the fraction tau of the rest of its motion (tau = 1: to its end pose).
  virtual void advance_obstacle(double /*tau*/) {}
  // The adjoint's return to a step that the forward began (begin_step) and accepted: the same lagged state,
  // without begin_step's checks (which that state passed). Default: begin_step.
  virtual void resume_step(const Eigen::VectorXd& x, const Eigen::VectorXd& p, double h) { begin_step(x, p, h); }
  // Contact between surfaces (self contact, a moving obstacle: contact/pair_contact.hpp) couples vertices that
  // are not neighbours in the mesh, outside the model's fixed sparsity pattern. Such a term assembles only the
  // part of its matrices that lies in the pattern (add_hessian, add_projected_hessian, add_step_matrix) and
  // gives the rest as a product: out += (H - H_assembled) dir, with H the exact Hessian (projected = false:
  // add_hessian's remainder) or the per-pair PSD-projected one (projected = true: the remainder of
  // add_projected_hessian and add_step_matrix). Solvers then solve with the full operator by conjugate
  // gradients preconditioned with the assembled matrix's factor (solver/contact_linear_solve.hpp).
  virtual bool has_offpattern_hessian() const { return false; }
  virtual void add_offpattern_hessian_product(const Eigen::VectorXd& /*x*/, const Eigen::VectorXd& /*p*/,
                                              const Eigen::VectorXd& /*dir*/, bool /*projected*/,
                                              Eigen::VectorXd& /*out*/) const {}
  // The same for the step matrix (add_step_matrix): out += (K - K_assembled) dir.
  virtual void add_offpattern_step_matrix_product(const Eigen::VectorXd& /*x*/, const Eigen::VectorXd& /*p*/,
                                                  const Eigen::VectorXd& /*dir*/, Eigen::VectorXd& /*out*/) const {}
  // False if add_step_matrix_derivatives is not provided (then a rollout's adjoint through linearised contact
  // steps, solver/implicit_euler.hpp, refuses to run).
  virtual bool provides_step_matrix_derivatives() const { return true; }
  // Terms whose energy depends on the step's start x_t (begin_step): lagged friction, through its slip
  // u = T (x - x_t) and through the normal forces and tangent frames taken at x_t (IPC's lagging): the
  // x_t-derivative of lambda . grad E(x) + c lambda^T K(x) w at fixed x, added to gxt (the slip's part is
  // -(Hess E lambda + c d(lambda^T K w)/dx) of the friction's energy). Default: no x_t dependence.
  virtual void add_step_start_adjoint(const Eigen::VectorXd& /*x*/, const Eigen::VectorXd& /*p*/,
                                      const Eigen::VectorXd& /*lambda*/, const Eigen::VectorXd& /*w*/, double /*c*/,
                                      Eigen::VectorXd& /*gxt*/) const {}

  // Optional, for speed (defaults are correct for every term):
  // out += scale * K(x; p) dir without assembling K. Returns false if the term does not provide it (the
  // caller then assembles K).
  virtual bool add_step_matrix_product(const Eigen::VectorXd& /*x*/, const Eigen::VectorXd& /*p*/,
                                       const Eigen::VectorXd& /*dir*/, double /*scale*/, Eigen::VectorXd& /*out*/) const {
    return false;
  }
  // The per-term part of one implicit Euler step's system (solver/implicit_euler.hpp), fused:
  //   values += scale * K(x) (upper triangle, pattern order), Kv += scale * K(x) v, g += grad E(x).
  // Returns false, having done nothing, if the term does not provide it (the caller then uses the methods above).
  virtual bool add_step_system(const Eigen::VectorXd& /*x*/, const Eigen::VectorXd& /*p*/, const Eigen::VectorXd& /*v*/,
                               double /*scale*/, Eigen::VectorXd& /*values*/, Eigen::VectorXd& /*Kv*/,
                               Eigen::VectorXd& /*g*/) const {
    return false;
  }
  // The per-term part of the adjoint of one implicit Euler step (solver/implicit_euler.hpp), fused so that a
  // term can share its per-element state between the products (one pass over the elements):
  //   gx -= h Hess E(x) lambda + h^2 d(lambda^T K w)/dx
  //   gp -= h^2 d(lambda^T K w)/dp + h d(lambda . grad E)/dp
  //   gv -= h^2 K lambda   (only if the return value is true; else the caller does it by assembling K)
  virtual bool add_step_adjoint(const Eigen::VectorXd& x, const Eigen::VectorXd& p, const Eigen::VectorXd& lambda,
                                const Eigen::VectorXd& w, double h, Eigen::VectorXd& gx, Eigen::VectorXd& gv,
                                Eigen::VectorXd& gp) const {
    Eigen::VectorXd Hl = Eigen::VectorXd::Zero(x.size());
    add_hessian_product(x, p, lambda, Hl);
    gx -= h * Hl;
    add_step_matrix_derivatives(x, p, lambda, w, -h * h, gx, gp);
    add_gradient_parameter_product(x, p, lambda, -h, gp);
    return add_step_matrix_product(x, p, lambda, -h * h, gv);
  }
};

}  // namespace drapelab
