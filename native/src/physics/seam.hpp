// Seams of a garment: a sewn garment's pattern pieces are separate (u, v) islands whose seam vertices come in
// pairs (one per piece) that are one point of the garment. Each pair is held together by a zero-length spring
//   E = 1/2 k_s |x_a - x_b|^2   [J]
// of stiffness k_s = ModelOptions::seam_stiffness [N/m] (a constant of the model, not a fitted parameter).
#pragma once
#include <array>
#include <vector>

#include "physics/element_term.hpp"

namespace drapelab {

class SeamTerm : public ElementTerm<SeamTerm, 2, 0, 3> {
 public:
  SeamTerm(std::vector<std::array<int, 2>> pairs, double stiffness) : pairs_(std::move(pairs)), k_(stiffness) {}
  std::string name() const override { return "seam"; }
  int num_elements() const { return static_cast<int>(pairs_.size()); }
  const std::array<int, 2>& element_vertices(int e) const { return pairs_[e]; }
  int parameter_offset(int) const { return 0; }

  template <class T>
  T element_energy(int, const T* x, const T*) const {
    T s = T(0.0);
    for (int k = 0; k < 3; ++k) {
      const T d = x[k] - x[3 + k];
      s += d * d;
    }
    return 0.5 * k_ * s;
  }
  template <class T>
  void element_gauss_newton(int, const T* x, const T*, T* r, T* S) const {
    for (int k = 0; k < 3; ++k) r[k] = x[k] - x[3 + k];
    for (int k = 0; k < 9; ++k) S[k] = T(0.0);
    for (int k = 0; k < 3; ++k) S[4 * k] = T(k_);
  }

 private:
  std::vector<std::array<int, 2>> pairs_;
  double k_;
};

}  // namespace drapelab
