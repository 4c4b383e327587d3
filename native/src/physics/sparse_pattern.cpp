#include "physics/sparse_pattern.hpp"

#include <algorithm>
#include <stdexcept>

namespace drapelab {

SparsePattern::SparsePattern(int num_vertices, const std::vector<std::vector<int>>& stencils) : n_(3 * num_vertices) {
  std::vector<std::vector<int>> vertex_cols(num_vertices);  // for vertex column j: vertices i <= j coupled
  for (int i = 0; i < num_vertices; ++i) vertex_cols[i].push_back(i);
  for (const auto& s : stencils)
    for (int a : s)
      for (int b : s)
        if (a <= b) vertex_cols[b].push_back(a);
  column_start_.assign(n_ + 1, 0);
  for (int j = 0; j < num_vertices; ++j) {
    auto& c = vertex_cols[j];
    std::sort(c.begin(), c.end());
    c.erase(std::unique(c.begin(), c.end()), c.end());
  }
  for (int j = 0; j < num_vertices; ++j)
    for (int cj = 0; cj < 3; ++cj) {
      const int col = 3 * j + cj;
      for (int i : vertex_cols[j])
        for (int ci = 0; ci < 3; ++ci) {
          const int row = 3 * i + ci;
          if (row <= col) row_index_.push_back(row);
        }
      column_start_[col + 1] = static_cast<int>(row_index_.size());
    }
  diagonal_.resize(n_);
  for (int d = 0; d < n_; ++d) diagonal_[d] = index(d, d);
}

int SparsePattern::index(int row, int col) const {
  const auto begin = row_index_.begin() + column_start_[col];
  const auto end = row_index_.begin() + column_start_[col + 1];
  const auto it = std::lower_bound(begin, end, row);
  if (it == end || *it != row) throw std::logic_error("SparsePattern: entry outside the pattern");
  return static_cast<int>(it - row_index_.begin());
}

}  // namespace drapelab
