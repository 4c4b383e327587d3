#include "solver/cholmod_solver.hpp"

#include <cstring>

#include "util/error.hpp"

namespace drapelab {

CholmodSolver::CholmodSolver(const SparsePattern& pattern) : pattern_(pattern) {
  cholmod_start(&common_);
  common_.print = 0;
  common_.error_handler = nullptr;
  common_.quick_return_if_not_posdef = 1;
  const int n = pattern.size();
  matrix_ = cholmod_allocate_sparse(n, n, pattern.nnz(), /*sorted*/ 1, /*packed*/ 1, /*stype upper*/ 1, CHOLMOD_REAL,
                                    &common_);
  if (!matrix_) throw SolverError("CHOLMOD: cannot allocate the system matrix");
  std::memcpy(matrix_->p, pattern.column_start().data(), sizeof(int) * (n + 1));
  std::memcpy(matrix_->i, pattern.row_index().data(), sizeof(int) * pattern.nnz());
  std::memset(matrix_->x, 0, sizeof(double) * pattern.nnz());
  // Symbolic analysis once per mesh: fill-reducing ordering and supernodal structure.
  for (int d = 0; d < n; ++d) static_cast<double*>(matrix_->x)[pattern.diagonal(d)] = 1.0;
  factor_ = cholmod_analyze(matrix_, &common_);
  if (!factor_) throw SolverError("CHOLMOD: symbolic analysis failed");
}

CholmodSolver::~CholmodSolver() {
  if (factor_) cholmod_free_factor(&factor_, &common_);
  if (matrix_) cholmod_free_sparse(&matrix_, &common_);
  cholmod_finish(&common_);
}

bool CholmodSolver::factorize(const Eigen::VectorXd& values) {
  std::memcpy(matrix_->x, values.data(), sizeof(double) * pattern_.nnz());
  cholmod_factorize(matrix_, factor_, &common_);
  return common_.status == CHOLMOD_OK;
}

Eigen::VectorXd CholmodSolver::solve_impl(cholmod_factor* factor, const Eigen::VectorXd& b) const {
  const int n = pattern_.size();
  cholmod_dense rhs;
  rhs.nrow = n;
  rhs.ncol = 1;
  rhs.nzmax = n;
  rhs.d = n;
  rhs.x = const_cast<double*>(b.data());
  rhs.z = nullptr;
  rhs.xtype = CHOLMOD_REAL;
  rhs.dtype = CHOLMOD_DOUBLE;
  cholmod_dense* sol = cholmod_solve(CHOLMOD_A, factor, &rhs, &common_);
  if (!sol) throw SolverError("CHOLMOD: solve failed");
  Eigen::VectorXd x = Eigen::Map<Eigen::VectorXd>(static_cast<double*>(sol->x), n);
  cholmod_free_dense(&sol, &common_);
  return x;
}

Eigen::VectorXd CholmodSolver::solve(const Eigen::VectorXd& b) const { return solve_impl(factor_, b); }

CholmodSolver::Factor CholmodSolver::keep_factor() const {
  cholmod_factor* copy = cholmod_copy_factor(factor_, &common_);
  if (!copy) throw SolverError("CHOLMOD: out of memory keeping a factor for the adjoint");
  cholmod_common* c = &common_;
  return Factor(copy, [c](cholmod_factor* f) { cholmod_free_factor(&f, c); });
}

Eigen::VectorXd CholmodSolver::solve_with(const Factor& factor, const Eigen::VectorXd& b) const {
  return solve_impl(factor.get(), b);
}

size_t CholmodSolver::factor_bytes() const {
  if (factor_->is_super) return factor_->xsize * sizeof(double) + factor_->ssize * sizeof(int);
  return factor_->nzmax * (sizeof(double) + sizeof(int));
}

Eigen::VectorXd symmetric_multiply(const SparsePattern& pattern, const Eigen::VectorXd& values,
                                   const Eigen::VectorXd& x) {
  Eigen::VectorXd y = Eigen::VectorXd::Zero(pattern.size());
  const auto& cs = pattern.column_start();
  const auto& ri = pattern.row_index();
  for (int c = 0; c < pattern.size(); ++c)
    for (int k = cs[c]; k < cs[c + 1]; ++k) {
      const int r = ri[k];
      y[r] += values[k] * x[c];
      if (r != c) y[c] += values[k] * x[r];
    }
  return y;
}

}  // namespace drapelab
