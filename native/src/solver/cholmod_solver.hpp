// Sparse SPD solves with CHOLMOD on a fixed pattern: symbolic analysis once, numeric factorisation per
// matrix, factors kept (for the adjoint, which reuses the forward factorisation) and solved repeatedly.
//
// Ordering: nested dissection (METIS) of the vertex graph, expanded to the 3 dofs of each vertex (about 25 %
// fewer flops than CHOLMOD's default AMD choice on the Cusick meshes; vertex blocks line up with supernodes).
// CHOLMOD's own OpenMP loops are switched off on the calling thread during every CHOLMOD call (they ask for
// 4 threads whatever the machine and made the factorisation 2-4x slower on 2 shared cores); BLAS threading is
// left to OpenBLAS's own settings.
// Kept factors share the solver's symbolic structure and hold only the numeric values (keep_factor).
// The ordering is applied once to the pattern (the matrix is stored as the lower triangle of P A P^T), so the
// per-step factorisation neither permutes nor transposes.
#pragma once
#include <cholmod.h>

#include <Eigen/Core>
#include <memory>
#include <mutex>
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
  // After factorize() returned false: the dof (pattern order) at whose pivot the factorisation stopped, or -1.
  int failed_dof() const;
  // x = A^-1 b with the current factor.
  Eigen::VectorXd solve(const Eigen::VectorXd& b) const;

  // The current factor's numeric values, kept (per step for the adjoint), and solves with it. It shares the
  // symbolic structure of this solver's factor: it must not outlive the solver. Supernodal factors are
  // kept without a copy: the values move to the kept factor and the next factorize() writes a new buffer.
  using Factor = std::shared_ptr<cholmod_factor>;
  Factor keep_factor() const;
  Eigen::VectorXd solve_with(const Factor& factor, const Eigen::VectorXd& b) const;
  size_t factor_bytes() const;
  // Bytes held by one kept factor (its numeric values).
  size_t kept_factor_bytes() const;
  // Frees the value buffers of released kept factors that are waiting for reuse (see keep_factor: buffers of
  // kept factors that are released go to a pool that the next factorisations draw on, so that a rollout
  // after a rollout writes its factors into memory it already has instead of fresh pages).
  void release_unused_buffers();
  // Nonzeros of L and flops of one numeric factorisation (from the symbolic analysis).
  double factor_nonzeros() const { return lnz_; }
  double factor_flops() const { return flops_; }

 private:
  const SparsePattern& pattern_;
  mutable cholmod_common common_;
  cholmod_sparse* matrix_ = nullptr;
  cholmod_factor* factor_ = nullptr;
  double lnz_ = 0, flops_ = 0;
  // Owner of factor_->x, a pool buffer (supernodal factors; kept factors share it); values_kept_: the current
  // values belong to a kept factor, so the next factorisation writes a new buffer.
  mutable std::shared_ptr<void> values_;
  mutable bool values_kept_ = false;
  struct BufferPool;
  std::shared_ptr<BufferPool> pool_;  // shared with the kept factors' buffers (they may outlive the solver)
  // The matrix is held as the lower triangle of P A P^T (P: the analysis' final ordering, perm_), position_[k]
  // = where pattern entry k goes; factors are of P A P^T and solves permute in and out.
  std::vector<int> perm_, position_;
  void prepermute();
  void take_values_buffer();  // the current factor's values go to a fresh pool buffer
  Eigen::VectorXd solve_impl(cholmod_factor* factor, const Eigen::VectorXd& b) const;
};

// y = A x for a symmetric matrix stored as the upper triangle of `pattern` with `values`.
Eigen::VectorXd symmetric_multiply(const SparsePattern& pattern, const Eigen::VectorXd& values,
                                   const Eigen::VectorXd& x);

}  // namespace drapelab
