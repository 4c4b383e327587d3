// Fixed sparsity pattern of the 3V x 3V system matrices (upper triangle, compressed columns), built once
// per model from the terms' vertex stencils, so that every step refills values without allocating and
// CHOLMOD's symbolic analysis runs once.
#pragma once
#include <vector>

namespace drapelab {

class SparsePattern {
 public:
  SparsePattern() = default;
  SparsePattern(int num_vertices, const std::vector<std::vector<int>>& stencils);

  int size() const { return n_; }  // 3V
  int nnz() const { return static_cast<int>(row_index_.size()); }
  const std::vector<int>& column_start() const { return column_start_; }
  const std::vector<int>& row_index() const { return row_index_; }
  // Position of entry (row, col) in the value array; requires row <= col and the entry in the pattern.
  int index(int row, int col) const;
  int diagonal(int dof) const { return diagonal_[dof]; }

 private:
  int n_ = 0;
  std::vector<int> column_start_, row_index_, diagonal_;
};

}  // namespace drapelab
