#include "solver/cholmod_solver.hpp"

#include <dlfcn.h>
#include <sys/mman.h>

#include <algorithm>

#include <cstdlib>
#include <cstring>
#include <vector>

#include "util/error.hpp"

namespace drapelab {

namespace {
// Runs a scope with OpenMP parallel regions disabled on the calling thread (max-active-levels is a
// per-thread ICV in libgomp >= 11), restored afterwards. Looked up at run time: libgomp comes with
// CHOLMOD, and without it there is nothing to switch off.
class SerialOpenMP {
 public:
  SerialOpenMP() {
    static const Api api = lookup();
    api_ = &api;
    if (api_->get && api_->set) {
      saved_ = api_->get();
      api_->set(0);
    }
  }
  ~SerialOpenMP() {
    if (api_->get && api_->set) api_->set(saved_);
  }
  SerialOpenMP(const SerialOpenMP&) = delete;
  SerialOpenMP& operator=(const SerialOpenMP&) = delete;

 private:
  struct Api {
    int (*get)() = nullptr;
    void (*set)(int) = nullptr;
  };
  static Api lookup() {
    Api a;
    a.get = reinterpret_cast<int (*)()>(dlsym(RTLD_DEFAULT, "omp_get_max_active_levels"));
    a.set = reinterpret_cast<void (*)(int)>(dlsym(RTLD_DEFAULT, "omp_set_max_active_levels"));
    return a;
  }
  const Api* api_ = nullptr;
  int saved_ = 1;
};

// Fill-reducing ordering of the dofs: nested dissection of the vertex graph, 3 dofs per vertex kept together.
// Empty if the partitioner is unavailable (CHOLMOD then chooses).
std::vector<int> vertex_block_ordering(const SparsePattern& pattern, cholmod_common* common) {
  const int n = pattern.size(), nv = n / 3;
  const auto& cs = pattern.column_start();
  const auto& ri = pattern.row_index();
  std::vector<int> gp(nv + 1, 0), gi;
  for (int j = 0; j < nv; ++j) {
    for (int k = cs[3 * j]; k < cs[3 * j + 1]; ++k)
      if (ri[k] % 3 == 0) gi.push_back(ri[k] / 3);
    gp[j + 1] = static_cast<int>(gi.size());
  }
  cholmod_sparse* graph =
      cholmod_allocate_sparse(nv, nv, gi.size(), /*sorted*/ 1, /*packed*/ 1, /*stype upper*/ 1, CHOLMOD_PATTERN, common);
  if (!graph) return {};
  std::memcpy(graph->p, gp.data(), sizeof(int) * (nv + 1));
  std::memcpy(graph->i, gi.data(), sizeof(int) * gi.size());
  std::vector<int> vperm(nv), cparent(nv), cmember(nv);
  const long ncomp = cholmod_nested_dissection(graph, nullptr, 0, vperm.data(), cparent.data(), cmember.data(), common);
  cholmod_free_sparse(&graph, common);
  if (ncomp <= 0 || common->status != CHOLMOD_OK) return {};
  std::vector<int> perm(n);
  for (int i = 0; i < nv; ++i)
    for (int k = 0; k < 3; ++k) perm[3 * i + k] = 3 * vperm[i] + k;
  return perm;
}
}  // namespace

// Value buffers (all of one size, mmap'd) of the factors, reused by later factorisations once released.
// New buffers are mapped with MAP_POPULATE: a recorded rollout writes ~10 MB of factor values per step
// (circle3), and first-touch page faults on fresh memory cost 13.6 ms per 10 MB on this machine (its VM), against
// 5.1 ms populated in one call and 0.4 ms to rewrite memory already held (tools: a 100 x 10 MB memset test).
// Transparent huge pages were slower still (27.8 ms).
struct CholmodSolver::BufferPool {
  explicit BufferPool(size_t bytes) : bytes(bytes) {}
  const size_t bytes;
  std::mutex mutex;
  std::vector<void*> free_buffers;
  ~BufferPool() { clear(); }
  void give(void* b) {
    std::lock_guard<std::mutex> lock(mutex);
    free_buffers.push_back(b);
  }
  void* take() {
    std::lock_guard<std::mutex> lock(mutex);
    if (!free_buffers.empty()) {
      void* b = free_buffers.back();
      free_buffers.pop_back();
      return b;
    }
    void* b = mmap(nullptr, bytes, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS | MAP_POPULATE, -1, 0);
    if (b == MAP_FAILED) throw SolverError("CHOLMOD: out of memory for the factor");
    return b;
  }
  void clear() {
    std::lock_guard<std::mutex> lock(mutex);
    for (void* b : free_buffers) munmap(b, bytes);
    free_buffers.clear();
  }
};

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
  SerialOpenMP serial;
  common_.supernodal = CHOLMOD_SUPERNODAL;
  std::vector<int> perm = vertex_block_ordering(pattern, &common_);
  common_.status = CHOLMOD_OK;
  if (!perm.empty()) {
    common_.nmethods = 1;
    common_.method[0].ordering = CHOLMOD_GIVEN;
    factor_ = cholmod_analyze_p(matrix_, perm.data(), nullptr, 0, &common_);
  }
  if (!factor_) {
    common_.nmethods = 0;
    common_.status = CHOLMOD_OK;
    factor_ = cholmod_analyze(matrix_, &common_);
  }
  if (!factor_) throw SolverError("CHOLMOD: symbolic analysis failed");
  lnz_ = common_.lnz;
  flops_ = common_.fl;
  prepermute();
}

// The final ordering (fill-reducing, then postordered) is applied once, to the pattern: values are written
// straight into the lower triangle of P A P^T, which is what the supernodal factorisation reads, so that
// CHOLMOD neither permutes nor transposes the matrix at every factorisation (about 15 % of its time).
void CholmodSolver::prepermute() {
  const int n = pattern_.size();
  perm_.assign(static_cast<const int*>(factor_->Perm), static_cast<const int*>(factor_->Perm) + n);
  std::vector<int> inverse(n);
  for (int i = 0; i < n; ++i) inverse[perm_[i]] = i;
  const auto& cs = pattern_.column_start();
  const auto& ri = pattern_.row_index();
  std::vector<std::vector<std::pair<int, int>>> columns(n);  // per permuted column: (row, pattern position)
  for (int c = 0; c < n; ++c)
    for (int k = cs[c]; k < cs[c + 1]; ++k) {
      const int i = inverse[ri[k]], j = inverse[c];
      columns[std::min(i, j)].push_back({std::max(i, j), k});
    }
  cholmod_sparse* lower = cholmod_allocate_sparse(n, n, pattern_.nnz(), /*sorted*/ 1, /*packed*/ 1, /*stype lower*/ -1,
                                                  CHOLMOD_REAL, &common_);
  if (!lower) throw SolverError("CHOLMOD: cannot allocate the permuted system matrix");
  position_.assign(pattern_.nnz(), 0);
  int* lp = static_cast<int*>(lower->p);
  int* li = static_cast<int*>(lower->i);
  int q = 0;
  for (int j = 0; j < n; ++j) {
    lp[j] = q;
    std::sort(columns[j].begin(), columns[j].end());  // increasing row order
    for (const auto& [row, k] : columns[j]) {
      li[q] = row;
      position_[k] = q++;
    }
  }
  lp[n] = q;
  double* lx = static_cast<double*>(lower->x);
  for (int k = 0; k < pattern_.nnz(); ++k) lx[position_[k]] = static_cast<const double*>(matrix_->x)[k];
  cholmod_free_sparse(&matrix_, &common_);
  matrix_ = lower;
  // Analyse the permuted matrix in its natural order (already postordered: same supernodes, no permutation).
  SerialOpenMP serial;
  cholmod_free_factor(&factor_, &common_);
  common_.nmethods = 1;
  common_.method[0].ordering = CHOLMOD_NATURAL;
  common_.postorder = 0;
  common_.status = CHOLMOD_OK;
  factor_ = cholmod_analyze(matrix_, &common_);
  if (!factor_) throw SolverError("CHOLMOD: symbolic analysis of the permuted matrix failed");
  // One numeric factorisation (of the identity-diagonal matrix) makes CHOLMOD allocate the values; they move to
  // a pool buffer at once, so that every factorisation writes into memory of the same alignment (OpenBLAS's
  // rounding depends on it: results would otherwise depend on which solver instance ran which draw).
  cholmod_factorize(matrix_, factor_, &common_);
  if (common_.status != CHOLMOD_OK || !factor_->x) throw SolverError("CHOLMOD: cannot allocate the factor");
  pool_ = std::make_shared<BufferPool>(factor_->xsize * sizeof(double));
  if (factor_->is_super) {  // (simplicial values are CHOLMOD's to reallocate: they stay its own)
    std::free(factor_->x);
    take_values_buffer();
  }
}

void CholmodSolver::take_values_buffer() {
  std::shared_ptr<BufferPool> pool = pool_;
  values_ = std::shared_ptr<void>(pool_->take(), [pool](void* x) { pool->give(x); });
  factor_->x = values_.get();
  values_kept_ = false;
}

CholmodSolver::~CholmodSolver() {
  if (factor_ && values_) factor_->x = nullptr;  // the pool's (or the kept factors'), not CHOLMOD's
  values_.reset();
  if (factor_) cholmod_free_factor(&factor_, &common_);
  if (matrix_) cholmod_free_sparse(&matrix_, &common_);
  cholmod_finish(&common_);
}

bool CholmodSolver::factorize(const Eigen::VectorXd& values) {
  double* x = static_cast<double*>(matrix_->x);
  for (int k = 0; k < pattern_.nnz(); ++k) x[position_[k]] = values[k];
  SerialOpenMP serial;
  if (values_kept_) take_values_buffer();  // the values belong to a kept factor: factorise into a new buffer
  cholmod_factorize(matrix_, factor_, &common_);
  return common_.status == CHOLMOD_OK;
}

int CholmodSolver::failed_dof() const {
  if (!factor_ || factor_->minor >= factor_->n || perm_.empty()) return -1;
  return perm_[factor_->minor];
}

Eigen::VectorXd CholmodSolver::solve_impl(cholmod_factor* factor, const Eigen::VectorXd& b) const {
  const int n = pattern_.size();
  cholmod_dense rhs;
  rhs.nrow = n;
  rhs.ncol = 1;
  rhs.nzmax = n;
  rhs.d = n;
  Eigen::VectorXd permuted(n);
  for (int i = 0; i < n; ++i) permuted[i] = b[perm_[i]];
  rhs.x = permuted.data();
  rhs.z = nullptr;
  rhs.xtype = CHOLMOD_REAL;
  rhs.dtype = CHOLMOD_DOUBLE;
  SerialOpenMP serial;
  cholmod_dense* sol = cholmod_solve(CHOLMOD_A, factor, &rhs, &common_);
  if (!sol) throw SolverError("CHOLMOD: solve failed");
  Eigen::VectorXd x(n);
  const double* xs = static_cast<const double*>(sol->x);
  for (int i = 0; i < n; ++i) x[perm_[i]] = xs[i];
  cholmod_free_dense(&sol, &common_);
  return x;
}

Eigen::VectorXd CholmodSolver::solve(const Eigen::VectorXd& b) const { return solve_impl(factor_, b); }

CholmodSolver::Factor CholmodSolver::keep_factor() const {
  if (!factor_->is_super) {  // simplicial factors change structure when refactorised: a full copy
    cholmod_factor* copy = cholmod_copy_factor(factor_, &common_);
    if (!copy) throw SolverError("CHOLMOD: out of memory keeping a factor for the adjoint");
    cholmod_common* c = &common_;
    return Factor(copy, [c](cholmod_factor* f) { cholmod_free_factor(&f, c); });
  }
  // Supernodal: the structure is fixed by the analysis; keep the header and share the numeric values (no copy).
  values_kept_ = true;
  auto* copy = new cholmod_factor(*factor_);
  copy->z = nullptr;
  auto values = values_;
  return Factor(copy, [values](cholmod_factor* f) mutable {
    values.reset();
    delete f;
  });
}

void CholmodSolver::release_unused_buffers() { pool_->clear(); }

size_t CholmodSolver::kept_factor_bytes() const {
  if (factor_->is_super) return factor_->xsize * sizeof(double);
  return factor_bytes();
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
