// Coulomb friction between a garment and its kinematic body (garment/revolved_body.hpp): IPC's lagged, smoothed
// friction potential (Li et al. 2020, sec. 5), per cloth vertex and body part, as disk_contact has it on the
// Cusick disk.
//
// At the start of each step (begin_step: the cloth at x_t, the body at its start pose) every vertex i within the
// body's barrier reach of part k (0 < g_ik < dhat) fixes
//   lambda_ik = kappa_i |b'(g_ik)| |grad g_ik|   the barrier's normal force [N],
//   P_ik = I - n n^T, n = grad g_ik / |grad g_ik|   the tangent projector,
//   s_ik = T_end(T_start^-1(x_t,i)) - x_t,i       the body's own slip there over the step: the rigid motion of the
//                                                  material point of part k at x_t,i (not of the closest surface
//                                                  point: they differ by omega x (g n), g < dhat, sub-micrometre)
// and within the step the vertex's slip relative to the body is u = P_ik (x_i - x_t,i - s_ik), its dissipation
// potential D = mu lambda_ik f0(|u|, eps_v h) [J] (f0 smooths the stick/slip switch over a slip speed eps_v).
// Lagging is IPC's approximation: lambda, P and s are those of the step's start. The energy, gradient and step
// matrix are exact in x (element_term.hpp's jets; the step matrix mu lambda [f1/u (I - u u^T/u^2) + f1' u u^T/u^2]
// is PSD since f1 >= 0, f1' >= 0), and a vertex's blocks lie on the model's pattern (the diagonal). The lagged
// quantities' dependence on x_t is not differentiated: like the body's barrier (provides_step_matrix_derivatives
// false), a rollout with a garment body is not recorded for an adjoint. A static drape (h = 0) has no friction.
#pragma once
#include <algorithm>
#include <array>
#include <vector>

#include "contact/barrier.hpp"
#include "garment/revolved_body.hpp"
#include "physics/element_term.hpp"

namespace drapelab {

class BodyFriction : public ElementTerm<BodyFriction, 1, 0, 3> {
 public:
  // body: the model's body term (it outlives this one: both belong to the model); mu: Coulomb coefficient.
  BodyFriction(const RevolvedBodyContact& body, int num_vertices, double mu);
  std::string name() const override { return "body_friction"; }
  bool is_contact() const override { return true; }
  bool provides_step_matrix_derivatives() const override { return false; }
  void begin_step(const Eigen::VectorXd& x, const Eigen::VectorXd& p, double h) override;
  double friction() const { return mu_; }
  // (vertex, part) pairs with a lagged normal force this step.
  int num_active() const {
    return static_cast<int>(std::count_if(lag_.begin(), lag_.end(), [](const Lag& l) { return l.normal_force > 0; }));
  }

  // Elements: one per (vertex, part), e = i * parts + k.
  int num_elements() const { return static_cast<int>(vertices_.size()); }
  const std::array<int, 1>& element_vertices(int e) const { return vertices_[e]; }
  int parameter_offset(int) const { return 0; }

  template <class T>
  T element_energy(int e, const T* x, const T*) const {
    const Lag& l = lag_[e];
    if (l.normal_force == 0) return T(0.0);
    T u[3];
    slip(l, x, u);
    return mu_ * l.normal_force * friction_f0_of_squared(u[0] * u[0] + u[1] * u[1] + u[2] * u[2], eps_u_);
  }
  // r = u = P (x - x_t - s); S = mu lambda friction_curvature(u) (contact/barrier.hpp, PSD).
  template <class T>
  void element_gauss_newton(int e, const T* x, const T*, T* r, T* S) const {
    const Lag& l = lag_[e];
    slip(l, x, r);
    for (int k = 0; k < 9; ++k) S[k] = T(0.0);
    if (l.normal_force == 0) return;
    friction_curvature(r, eps_u_, S);
    for (int k = 0; k < 9; ++k) S[k] *= mu_ * l.normal_force;
  }

 private:
  struct Lag {
    double normal_force = 0;  // lambda [N]; 0: no friction this step
    Eigen::Matrix3d projector = Eigen::Matrix3d::Zero();
    Eigen::Vector3d origin = Eigen::Vector3d::Zero();  // x_t + s: where the vertex would be if it stuck
  };
  template <class T>
  void slip(const Lag& l, const T* x, T* u) const {
    for (int a = 0; a < 3; ++a) {
      u[a] = T(0.0);
      for (int b = 0; b < 3; ++b) u[a] += l.projector(a, b) * (x[b] - l.origin[b]);
    }
  }
  const RevolvedBodyContact& body_;
  double mu_;
  double eps_u_ = 0;
  std::vector<std::array<int, 1>> vertices_;
  std::vector<Lag> lag_;
};

}  // namespace drapelab
