// Gravity: E = -sum_i m_i g . x_i with lumped masses m_i = rho * sum_{faces at i} A_f / 3  [J].
// Parameter: "density" rho [kg/m^2] (shared with the mass matrix). g = (0, 0, -gravity) m/s^2.
#pragma once
#include <array>
#include <vector>

#include "physics/element_term.hpp"

namespace drapelab {

class GravityTerm : public ElementTerm<GravityTerm, 1, 1, 0> {
 public:
  // area_weights[i] = sum of A_f / 3 over faces at vertex i [m^2]; density_offset: the "density" block.
  GravityTerm(const Eigen::VectorXd& area_weights, int density_offset, double gravity)
      : weights_(area_weights.data(), area_weights.data() + area_weights.size()),
        offset_(density_offset),
        g_(gravity) {
    for (int i = 0; i < static_cast<int>(weights_.size()); ++i) verts_.push_back({i});
  }
  std::string name() const override { return "gravity"; }
  int num_elements() const { return static_cast<int>(verts_.size()); }
  const std::array<int, 1>& element_vertices(int e) const { return verts_[e]; }
  int parameter_offset(int) const { return offset_; }

  template <class T>
  T element_energy(int e, const T* x, const T* p) const {
    return p[0] * (weights_[e] * g_) * x[2];
  }
  template <class T>
  void element_gauss_newton(int, const T*, const T*, T*, T*) const {}

 private:
  std::vector<double> weights_;
  std::vector<std::array<int, 1>> verts_;
  int offset_;
  double g_;
};

}  // namespace drapelab
