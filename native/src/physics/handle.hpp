// Handle (the Cusick support disk): E = 1/2 k_h |x_i - anchor_i|^2 for every vertex whose rest radius is
// below the support radius (9 cm)  [J]. Parameter: "handle_stiffness" k_h [N/m] (paper: 1e3).
#pragma once
#include <array>
#include <vector>

#include "physics/element_term.hpp"

namespace drapelab {

class HandleTerm : public ElementTerm<HandleTerm, 1, 1, 3> {
 public:
  HandleTerm(const std::vector<int>& vertices, const std::vector<Eigen::Vector3d>& anchors, int stiffness_offset)
      : anchors_(anchors), offset_(stiffness_offset) {
    for (int v : vertices) verts_.push_back({v});
  }
  std::string name() const override { return "handle"; }
  int num_elements() const { return static_cast<int>(verts_.size()); }
  const std::array<int, 1>& element_vertices(int e) const { return verts_[e]; }
  int parameter_offset(int) const { return offset_; }
  const std::vector<std::array<int, 1>>& vertices() const { return verts_; }
  void set_anchors(const std::vector<Eigen::Vector3d>& anchors) { anchors_ = anchors; }

  template <class T>
  T element_energy(int e, const T* x, const T* p) const {
    T s = T(0.0);
    for (int k = 0; k < 3; ++k) {
      const T d = x[k] - anchors_[e][k];
      s += d * d;
    }
    return 0.5 * p[0] * s;
  }
  template <class T>
  void element_gauss_newton(int e, const T* x, const T* p, T* r, T* S) const {
    for (int k = 0; k < 3; ++k) r[k] = x[k] - anchors_[e][k];
    for (int k = 0; k < 9; ++k) S[k] = T(0.0);
    for (int k = 0; k < 3; ++k) S[4 * k] = p[0];
  }

 private:
  std::vector<Eigen::Vector3d> anchors_;
  std::vector<std::array<int, 1>> verts_;
  int offset_;
};

}  // namespace drapelab
