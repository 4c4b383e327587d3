// Sparse SPD solves with CHOLMOD on a fixed pattern: symbolic analysis once, numeric factorisation per
// matrix, factors kept (for the adjoint, which reuses the forward factorisation) and solved repeatedly.
#pragma once
#include <cholmod.h>

#include <Eigen/Core>
#include <memory>
#include <vector>

#include "physics/sparse_pattern.hpp"

namespace drapelab {

class CholmodSolver {
 public:
  explicit CholmodSolver(const SparsePattern& pattern);
  ~CholmodSolver();
  CholmodSolver(const CholmodSolver&) = delete;
  CholmodSolver& operator=(const CholmodSolver&) = delete;

  // Numeric factorisation of the matrix with these values (upper triangle, pattern order).
  // Returns false if the matrix is not positive definite.
  bool factorize(const Eigen::VectorXd& values);
  // x = A^-1 b with the current factor.
  Eigen::VectorXd solve(const Eigen::VectorXd& b) const;

  // A detached copy of the current factor (kept per step for the adjoint) and solves with it.
  using Factor = std::shared_ptr<cholmod_factor>;
  Factor keep_factor() const;
  Eigen::VectorXd solve_with(const Factor& factor, const Eigen::VectorXd& b) const;
  size_t factor_bytes() const;

 private:
  const SparsePattern& pattern_;
  mutable cholmod_common common_;
  cholmod_sparse* matrix_ = nullptr;
  cholmod_factor* factor_ = nullptr;
  Eigen::VectorXd solve_impl(cholmod_factor* factor, const Eigen::VectorXd& b) const;
};

// y = A x for a symmetric matrix stored as the upper triangle of `pattern` with `values`.
Eigen::VectorXd symmetric_multiply(const SparsePattern& pattern, const Eigen::VectorXd& values,
                                   const Eigen::VectorXd& x);

}  // namespace drapelab
