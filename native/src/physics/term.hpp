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
  virtual void add_hessian_product(const Eigen::VectorXd& x, const Eigen::VectorXd& p, const Eigen::VectorXd& dir,
                                   Eigen::VectorXd& out) const = 0;
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
};

}  // namespace drapelab
