// Nonlinear anisotropic bending (Bridson et al. 2003 discrete shells; Wang et al. 2011 data-driven tables).
//
// Per interior edge w with rest length L, rest heights h1, h2 of its two faces (h = 2 A / L, from the
// rest pattern), rest dihedral angle theta_rest (0: cloth is flat at rest) and current signed dihedral
// angle theta:
//   E_w = 2 k L / (h1 + h2) (1 - cos((theta - theta_rest) / 2))   [J]
// so that dE/dtheta = k L / (h1 + h2) sin((theta - theta_rest) / 2), the paper's bending force.
// k = B(beta, alpha) [N m] interpolates the edge's 3 x 5 table (row-major): linearly in the rows, the bias
// angles beta = 0, 45, 90 degrees between the rest edge and the weft (u) axis (folded to [0, 90]);
// columns are curvature samples alpha = k * kBendSampleCurvature, k = 0..4, of
//   alpha = |sin((theta - theta_rest) / 2)| / (h1 + h2)   [1/m]
// clamped to the table's range, blended between columns with s(f) = 3 f^2 - 2 f^3 (C1: the energy's
// gradient is continuous, also at theta = theta_rest). The energy includes dk/dalpha (conservative forces).
// Step matrix: K = max(d2E/dtheta2, 0) dtheta/dx dtheta/dx^T (see element_gauss_newton).
// Optionally (an effect's change, physics/base_term_changes.hpp) each edge's energy is multiplied by a smooth
// field m_w = exp(sum_k c_wk q_k) > 0 of effect parameters q_k: E_w -> m_w E_w, exact in x, the table and q.
// Optionally too (rest_curvature) the rest angles are linear in effect parameters q_k:
// theta_rest,w = sum_k a_wk q_k (a plastic set), so dE_w/dq_k = -a_wk E_w'(d), exact in every kernel.
// Optionally (high_curvature_bending) the energy is multiplied by M(d) = exp(q s(alpha(d))), s a smoothstep ramp
// of alpha beyond the table's range (CurvatureFactor): the stiffness at sharp folds, where the table is constant.
// M depends on the angle, so it enters E's d-derivatives (Leibniz) and the table coefficients; dE/dq = s M E.
// The jet-derived Reference (element_energy, element_gauss_newton) is the unmodulated, flat-rest term.
#pragma once
#include <array>
#include <vector>

#include "geometry/mesh.hpp"
#include "physics/base_term_changes.hpp"
#include "physics/element_term.hpp"

namespace drapelab {

constexpr double kBendSampleCurvature = 2.5;  // 1/m between table columns

class BendTerm : public ElementTerm<BendTerm, 4, 15, 1> {
 public:
  // modulation: an optional per-edge energy multiplier (one coefficient per bending edge and mode);
  // rest: optional rest angles linear in parameters (one coefficient per bending edge and parameter).
  BendTerm(const TriangleMesh& mesh, const std::vector<BendingEdge>& edges, int parameter_offset, bool shared,
           EnergyModulation modulation = {}, RestAngles rest = {}, CurvatureFactor curvature = {});
  std::string name() const override { return "bend"; }

  int num_elements() const { return static_cast<int>(verts_.size()); }
  const std::array<int, 4>& element_vertices(int e) const { return verts_[e]; }
  int parameter_offset(int e) const { return offset_ + (shared_ ? 0 : 15 * e); }
  // The energy modulation's and the rest angles' parameters (stiffness maps, rest curvature) besides the table.
  std::vector<int> extra_parameter_indices() const {
    std::vector<int> out = modulation_.indices;
    out.insert(out.end(), rest_.indices.begin(), rest_.indices.end());
    out.insert(out.end(), curvature_.indices.begin(), curvature_.indices.end());
    return out;
  }

  // Signed dihedral angle: 0 when flat, vertices (a, b, c, d) as in BendingEdge.
  template <class T>
  static T dihedral_angle(const T* x) {
    T e[3], ec[3], ed[3];
    for (int k = 0; k < 3; ++k) {
      e[k] = x[3 + k] - x[k];
      ec[k] = x[6 + k] - x[k];
      ed[k] = x[9 + k] - x[k];
    }
    // n1 = e x ec (face a, b, c), n2 = ed x e (face b, a, d), both +z for a flat counter-clockwise pair.
    T n1[3], n2[3], m[3];
    cross(e, ec, n1);
    cross(ed, e, n2);
    cross(n1, n2, m);
    const T len = sqrt(e[0] * e[0] + e[1] * e[1] + e[2] * e[2]);
    const T s = (m[0] * e[0] + m[1] * e[1] + m[2] * e[2]) / len;
    const T c = n1[0] * n2[0] + n1[1] * n2[1] + n1[2] * n2[2];
    return atan2(s, c);
  }

  // Table column cell of alpha = |sin(d / 2)| / (h1 + h2): left column k0 and C1 blend fraction f.
  template <class T>
  void curvature_cell(int e, const T& half_angle_sine, int& k0, T& f) const {
    const double hsum = height_sum_[e];
    T alpha = (value_of(half_angle_sine) >= 0 ? half_angle_sine : -half_angle_sine) / hsum;
    const T t = alpha / kBendSampleCurvature;
    const double tv = value_of(t);
    if (tv >= 4) {
      k0 = 3;
      f = T(1.0);
    } else {
      k0 = static_cast<int>(tv);
      if (k0 > 3) k0 = 3;
      f = smoothstep(t - static_cast<double>(k0));
    }
  }

  template <class T, class P>
  T stiffness(int e, const T& half_angle_sine, const P* p) const {
    int k0;
    T f;
    curvature_cell(e, half_angle_sine, k0, f);
    const auto& rw = row_weights_[e];
    T k = T(0.0);
    for (int r = 0; r < 2; ++r) {
      const int row = row_index_[e][r];
      if (rw[r] == 0.0) continue;
      k += rw[r] * ((1.0 - f) * p[5 * row + k0] + f * p[5 * row + k0 + 1]);
    }
    return k;
  }

  // E is linear in the table: E = sum_j phi_j(d) p[index_j] over the (at most 4) entries used at angle change
  // d. Writes index_j and phi_j(d) = dE/dp[index_j] (T: scalar jets in d give their d-derivatives); returns
  // the count.
  template <class T>
  int table_coefficients(int e, const T& d, int* index, T* phi) const {
    const T half_sine = sin(0.5 * d);
    int k0;
    T f;
    curvature_cell(e, half_sine, k0, f);
    const T G = 2.0 * (rest_length_[e] / height_sum_[e]) * (1.0 - cos(0.5 * d));
    const T gf = G * f, g1f = G - gf;
    const auto& rw = row_weights_[e];
    int n = 0;
    for (int r = 0; r < 2; ++r) {
      if (rw[r] == 0.0) continue;
      const int row = row_index_[e][r];
      index[n] = 5 * row + k0;
      phi[n++] = rw[r] * g1f;
      index[n] = 5 * row + k0 + 1;
      phi[n++] = rw[r] * gf;
    }
    return n;
  }

  // E(d) and its first three d-derivatives, and the table coefficients phi_j(d) (see table_coefficients) with
  // their first two d-derivatives, in closed form (one sincos): the hot paths' version of the jets above.
  struct AngleDerivatives {
    double E[4];
    int count;
    int index[4];
    double phi[4][3];
    double dq[3];  // with a curvature factor (modulated_angle_derivatives): dE/dq, dE'/dq, dE''/dq
  };
  void angle_derivatives(int e, double d, const double* p, AngleDerivatives& out) const;

  // Energy as a function of the angle change d = theta - theta_rest.
  template <class T, class P>
  T energy_of_angle(int e, const T& d, const P* p) const {
    const T k = stiffness(e, sin(0.5 * d), p);
    return 2.0 * k * (rest_length_[e] / height_sum_[e]) * (1.0 - cos(0.5 * d));
  }

  template <class T>
  T element_energy(int e, const T* x, const T* p) const {
    return energy_of_angle(e, dihedral_angle(x) - rest_angle_[e], p);
  }

  // r = theta - theta_rest, S = max(d2E/dtheta2, 0): exact along the angle (the tables stiffen several-fold
  // with curvature, and a step matrix that misses this makes the h = 0.05 s step oscillate), and
  // Gauss-Newton in x (drops dE/dtheta d2theta/dx2).
  template <class T>
  void element_gauss_newton(int e, const T* x, const T* p, T* r, T* S) const {
    r[0] = dihedral_angle(x) - rest_angle_[e];
    using J1 = Jet<T, 1>;
    using J2 = Jet<J1, 1>;
    J2 d{J1(r[0], 0)};
    d.v[0] = J1(T(1.0));
    J2 pj[15];
    for (int k = 0; k < 15; ++k) pj[k] = J2(J1(p[k]));
    const J2 E = energy_of_angle(e, d, pj);
    const T curvature = E.v[0].v[0];
    S[0] = value_of(curvature) > 0 ? curvature : T(0.0);
  }

  double bias_angle(int e) const { return bias_[e]; }
  double height_sum(int e) const { return height_sum_[e]; }
  // E(d)'s derivatives with every change applied (curvature factor, modulation), as the kernels use them (tests).
  AngleDerivatives changed_angle_derivatives(int e, double d, const Eigen::VectorXd& p) const {
    AngleDerivatives ad;
    double m;
    modulated_angle_derivatives(e, d, p, ad, m);
    return ad;
  }

  // Gradient of the dihedral angle in closed form (Bridson et al. 2003): with e = x_b - x_a and the
  // area-weighted normals n1 = e x (x_c - x_a), n2 = (x_d - x_a) x e,
  //   dtheta/dx_c = -|e| n1 / |n1|^2,  dtheta/dx_d = -|e| n2 / |n2|^2,
  //   dtheta/dx_b = -(a_c dtheta/dx_c + a_d dtheta/dx_d),  dtheta/dx_a = -(dtheta/dx_b + dtheta/dx_c + dtheta/dx_d),
  // a_k = (x_k - x_a) . e / |e|^2. Templated: with jets it gives the angle's Hessian (products).
  template <class T>
  static void dihedral_gradient(const T* x, T* g) {
    T e[3], ec[3], ed[3];
    for (int k = 0; k < 3; ++k) {
      e[k] = x[3 + k] - x[k];
      ec[k] = x[6 + k] - x[k];
      ed[k] = x[9 + k] - x[k];
    }
    T n1[3], n2[3];
    cross(e, ec, n1);
    cross(ed, e, n2);
    const T le2 = e[0] * e[0] + e[1] * e[1] + e[2] * e[2];
    const T le = sqrt(le2);
    const T s1 = -le / (n1[0] * n1[0] + n1[1] * n1[1] + n1[2] * n1[2]);
    const T s2 = -le / (n2[0] * n2[0] + n2[1] * n2[1] + n2[2] * n2[2]);
    const T ac = (ec[0] * e[0] + ec[1] * e[1] + ec[2] * e[2]) / le2;
    const T ad = (ed[0] * e[0] + ed[1] * e[1] + ed[2] * e[2]) / le2;
    for (int k = 0; k < 3; ++k) {
      const T gc = s1 * n1[k], gd = s2 * n2[k];
      const T gb = -(ac * gc + ad * gd);
      g[6 + k] = gc;
      g[9 + k] = gd;
      g[3 + k] = gb;
      g[k] = -(gb + gc + gd);
    }
  }

  // Hand-written kernels: E = E(theta) through the dihedral angle, its gradient in closed form (above),
  // jets only on the scalar E(theta) and on the closed-form gradient (for the angle's Hessian). Equal to the
  // jet-derived reference (ElementTerm's versions, kept as Reference) to round-off; see test_kernels.cpp.
  using Reference = ElementTerm<BendTerm, 4, 15, 1>;
  double energy(const Eigen::VectorXd& x, const Eigen::VectorXd& p) const override;
  void add_gradient(const Eigen::VectorXd& x, const Eigen::VectorXd& p, Eigen::VectorXd& g) const override;
  void add_step_matrix(const Eigen::VectorXd& x, const Eigen::VectorXd& p, double scale,
                       Eigen::VectorXd& values) const override;
  void add_hessian(const Eigen::VectorXd& x, const Eigen::VectorXd& p, double scale,
                   Eigen::VectorXd& values) const override;
  void add_projected_hessian(const Eigen::VectorXd& x, const Eigen::VectorXd& p, double scale,
                             Eigen::VectorXd& values) const override;
  // The Gauss-Newton step matrix: E'(theta) Hess theta is what makes draped folds' exact Hessian indefinite.
  void add_static_newton_matrix(const Eigen::VectorXd& x, const Eigen::VectorXd& p, double scale,
                                Eigen::VectorXd& values) const override {
    add_step_matrix(x, p, scale, values);
  }
  void add_hessian_product(const Eigen::VectorXd& x, const Eigen::VectorXd& p, const Eigen::VectorXd& dir,
                           Eigen::VectorXd& out) const override;
  void add_energy_parameter_gradient(const Eigen::VectorXd& x, const Eigen::VectorXd& p,
                                     Eigen::VectorXd& gp) const override;
  void add_gradient_parameter_product(const Eigen::VectorXd& x, const Eigen::VectorXd& p,
                                      const Eigen::VectorXd& lambda, double scale, Eigen::VectorXd& gp) const override;
  void add_step_matrix_derivatives(const Eigen::VectorXd& x, const Eigen::VectorXd& p, const Eigen::VectorXd& lambda,
                                   const Eigen::VectorXd& w, double scale, Eigen::VectorXd& gx,
                                   Eigen::VectorXd& gp) const override;
  bool add_step_matrix_product(const Eigen::VectorXd& x, const Eigen::VectorXd& p, const Eigen::VectorXd& dir,
                               double scale, Eigen::VectorXd& out) const override;
  bool add_step_system(const Eigen::VectorXd& x, const Eigen::VectorXd& p, const Eigen::VectorXd& v, double scale,
                       Eigen::VectorXd& values, Eigen::VectorXd& Kv, Eigen::VectorXd& g) const override;
  bool add_step_adjoint(const Eigen::VectorXd& x, const Eigen::VectorXd& p, const Eigen::VectorXd& lambda,
                        const Eigen::VectorXd& w, double h, Eigen::VectorXd& gx, Eigen::VectorXd& gv,
                        Eigen::VectorXd& gp) const override;

 private:
  // The exact element Hessians, each projected onto the PSD cone if `project` (add_projected_hessian).
  void add_element_hessians(const Eigen::VectorXd& x, const Eigen::VectorXd& p, double scale,
                            Eigen::VectorXd& values, bool project) const;
  // The edge's rest angle at p (the constant rest angle, untouched, without a rest change).
  double rest_angle(int e, const Eigen::VectorXd& p) const {
    return rest_.active() ? rest_angle_[e] + rest_.angle(e, p) : rest_angle_[e];
  }
  // Adds scale * d(value(d))/dq_k = -scale * a_ek * value' for every rest-angle parameter k (value': the derivative
  // of the quantity in the angle change d, already times m).
  void add_rest_gradient(int e, double derivative_in_d, double scale, Eigen::VectorXd& gp) const {
    for (size_t k = 0; k < rest_.indices.size(); ++k)
      gp[rest_.indices[k]] -= scale * rest_.coefficients[k][e] * derivative_in_d;
  }
  // angle_derivatives times the curvature factor M(d) (untouched without one) and the edge's multiplier m (m = 1,
  // untouched, without a modulation); p: the whole vector.
  void modulated_angle_derivatives(int e, double d, const Eigen::VectorXd& p, AngleDerivatives& out, double& m) const;
  // Adds scale * dm_e/dq_k * value to gp for every mode k (value: the unmodulated quantity, times m_e by the caller).
  void add_modulation_gradient(int e, double m_value, double scale, Eigen::VectorXd& gp) const {
    for (size_t k = 0; k < modulation_.indices.size(); ++k)
      gp[modulation_.indices[k]] += scale * modulation_.coefficients[k][e] * m_value;
  }
  void seed_directions(int e, const Eigen::VectorXd& x, const Eigen::VectorXd& lambda, const Eigen::VectorXd& w,
                       double* xe, Jet<double, 2>* xj, Jet<double, 2>* gj, double& gl, double& gw) const;
  void gather_local(int e, const Eigen::VectorXd& x, double* xe) const {
    const auto& v = verts_[e];
    for (int i = 0; i < 12; ++i) xe[i] = x[3 * v[i / 3] + i % 3];
  }
  template <class T>
  static void cross(const T* a, const T* b, T* out) {
    out[0] = a[1] * b[2] - a[2] * b[1];
    out[1] = a[2] * b[0] - a[0] * b[2];
    out[2] = a[0] * b[1] - a[1] * b[0];
  }

  std::vector<std::array<int, 4>> verts_;
  std::vector<double> rest_length_, height_sum_, rest_angle_, bias_;
  std::vector<std::array<int, 2>> row_index_;
  std::vector<std::array<double, 2>> row_weights_;
  int offset_;
  bool shared_;
  EnergyModulation modulation_;
  RestAngles rest_;
  CurvatureFactor curvature_;
  double curvature_log_span_ = 0;  // ln(full / start) of curvature_, the ramp's length in log curvature
  // Adds scale * value to the curvature factor's parameters (value: a q-derivative, ad.dq[n] times a product).
  void add_curvature_gradient(double value, double scale, Eigen::VectorXd& gp) const {
    for (int i : curvature_.indices) gp[i] += scale * value;
  }
  // Multiplies ad (E, phi) by M(d) and fills ad.dq.
  void apply_curvature_factor(int e, double d, const Eigen::VectorXd& p, AngleDerivatives& ad) const;
};

}  // namespace drapelab
