// Nonlinear anisotropic membrane stretching (Volino et al. 2009; Wang, O'Brien, Ramamoorthi 2011).
//
// Per face j with rest pattern (u, v) (u = weft, v = warp) and rest area A_j:
//   F = Ds Dm^-1 (3x2 deformation gradient), G = (F^T F - I) / 2 (Green strain),
//   eps = (G_uu, G_vv, G_uv),  C = [[c11, c12, 0], [c12, c22, 0], [0, 0, c33]],
//   W(eps) = int_0^1 (1 - t) eps^T C(t eps) eps dt,   E_j = A_j W   [J];  table entries in N/m.
// The table is read as the tangent stiffness along proportional loading: W'' = C along every strain ray,
// W = 1/2 eps^T C eps when C is constant. (Reading it as a secant modulus, sigma = C(eps) eps as the
// paper's force does, is not a potential and, with the published tables whose stiffness falls with
// strain, makes 1/2 eps^T C(eps) eps lose convexity at ~14 % strain: the drape tears apart.)
// Each face carries a table (6 x 4, row-major, columns c11, c12, c22, c33): row 0 is the small-strain
// sample (lambda_max = 0, all directions); rows 1..5 are samples at lambda_max = kStretchSampleStrain
// in directions phi = 0, 22.5, 45, 67.5, 90 degrees from the weft (u) axis, where lambda_max + 1 is the
// largest principal stretch and phi its direction (folded to [0, 90] degrees by symmetry).
// The stiffness C(G) = sum_r W_r(G) row_r interpolates this table piecewise-linearly in
// (lambda_max, phi) at the nodes of a grid over (G_uu, G_vv, |G_uv|), and between nodes with the C1
// blend s(f) = 3 f^2 - 2 f^3 per axis (the paper's released code blends linearly; C1 makes the energy's
// gradient continuous, so static equilibria have a vanishing residual): well defined at isotropic strain
// (where phi is not), and linear in the table. At isotropic grid nodes the five directions are averaged.
// The energy includes the dependence of C on G, so forces are conservative and E is a potential;
// the integral is evaluated by 3-point Gauss-Legendre quadrature (the definition of W used here).
// Step matrix: Gauss-Newton A_j J_eps^T C J_eps (C frozen) plus the positive part of the geometric
// stiffness; PSD for valid tables.
// Optionally (an effect's change, physics/base_term_changes.hpp) the rest pattern is scaled per axis,
// u -> a_u u, v -> a_v v with a_u = 1 - s_u, a_v = 1 - s_v (rest lengths shrink by the strains s): then
// Dm^-1 -> Dm^-1 diag(1 / a_u, 1 / a_v) and A_j -> a_u a_v A_j, exact in x, the table and the strains' parameters
// (their derivatives by jets through the templated energy and Gauss-Newton form below). The jet-derived
// Reference (element_energy, element_gauss_newton) is the unscaled term.
#pragma once
#include <array>
#include <cmath>
#include <vector>

#include "geometry/mesh.hpp"
#include "physics/base_term_changes.hpp"
#include "physics/element_term.hpp"

namespace drapelab {

constexpr double kStretchSampleStrain = 1.0 / 6.0;  // lambda_max of rows 1..5 (ArcSim's convention)

// Interpolation weights of the 6 table rows at Green strain G (exposed for tests).
struct StretchWeightGrid {
  static constexpr double kMin = -0.225, kStep = 0.05;  // G_uu, G_vv nodes: kMin + i kStep; 0 is mid-cell
  static constexpr int kNormal = 21, kShear = 11;       // |G_uv| nodes: i kStep
  std::vector<std::array<double, 6>> node_weights;      // [(i * kNormal + j) * kShear + k]
  StretchWeightGrid();
  static std::array<double, 6> polar_weights(double guu, double gvv, double guv);
};
const StretchWeightGrid& stretch_weight_grid();

class StretchTerm : public ElementTerm<StretchTerm, 3, 24, 9> {
 public:
  // parameter_offset: offset of the "stretch" block; shared = one table for all faces; rest: an optional scaling
  // of the rest pattern.
  StretchTerm(const TriangleMesh& mesh, int parameter_offset, bool shared, RestScaling rest = {});
  std::string name() const override { return "stretch"; }

  int num_elements() const { return static_cast<int>(faces_.size()); }
  const std::array<int, 3>& element_vertices(int e) const { return faces_[e]; }
  int parameter_offset(int e) const { return offset_ + (shared_ ? 0 : 24 * e); }
  // The rest scaling's strains (prestrain) besides the table.
  std::vector<int> extra_parameter_indices() const { return rest_.indices; }

  // F = Ds Di for a row-major 2 x 2 rest inverse Di (the face's, or a scaled one).
  template <class T, class D>
  static void deformation_gradient_of(const T* x, const D* Di, T f[3][2]) {
    for (int c = 0; c < 3; ++c) {
      const T d1 = x[3 + c] - x[c], d2 = x[6 + c] - x[c];
      f[c][0] = d1 * Di[0] + d2 * Di[2];
      f[c][1] = d1 * Di[1] + d2 * Di[3];
    }
  }
  template <class T>
  void deformation_gradient(int e, const T* x, T f[3][2]) const {
    deformation_gradient_of(x, dm_inv_[e].data(), f);
  }

  template <class T>
  void green_strain(int e, const T* x, T* eps) const {
    T f[3][2];
    deformation_gradient(e, x, f);
    strain_of(f, eps);
  }
  // eps = (G_uu, G_vv, G_uv) of F.
  template <class T>
  static void strain_of(const T f[3][2], T* eps) {
    T g00 = f[0][0] * f[0][0] + f[1][0] * f[1][0] + f[2][0] * f[2][0];
    T g11 = f[0][1] * f[0][1] + f[1][1] * f[1][1] + f[2][1] * f[2][1];
    T g01 = f[0][0] * f[0][1] + f[1][0] * f[1][1] + f[2][0] * f[2][1];
    eps[0] = 0.5 * (g00 - 1.0);
    eps[1] = 0.5 * (g11 - 1.0);
    eps[2] = 0.5 * g01;
  }

  // Interpolation weights w_r(eps) of the 6 table rows at strain eps (C = sum_r w_r row_r).
  template <class T>
  static void table_weights(const T* eps, T* w) {
    const StretchWeightGrid& grid = stretch_weight_grid();
    const T ga = (eps[0] - StretchWeightGrid::kMin) / StretchWeightGrid::kStep;
    const T gb = (eps[1] - StretchWeightGrid::kMin) / StretchWeightGrid::kStep;
    const T gc = (value_of(eps[2]) >= 0 ? eps[2] : -eps[2]) / StretchWeightGrid::kStep;
    int i0, j0, k0;
    T fa, fb, fc;
    cell(ga, StretchWeightGrid::kNormal, i0, fa);
    cell(gb, StretchWeightGrid::kNormal, j0, fb);
    cell(gc, StretchWeightGrid::kShear, k0, fc);
    for (int r = 0; r < 6; ++r) w[r] = T(0.0);
    for (int di = 0; di < 2; ++di)
      for (int dj = 0; dj < 2; ++dj)
        for (int dk = 0; dk < 2; ++dk) {
          const T t = (di ? fa : 1.0 - fa) * (dj ? fb : 1.0 - fb) * (dk ? fc : 1.0 - fc);
          const auto& nw =
              grid.node_weights[((i0 + di) * StretchWeightGrid::kNormal + (j0 + dj)) * StretchWeightGrid::kShear + k0 + dk];
          for (int r = 0; r < 6; ++r)
            if (nw[r] != 0.0) w[r] += t * nw[r];
        }
  }

  // C entries (c11, c12, c22, c33) interpolated at strain eps from table p (24 entries).
  template <class T, class P>
  static void stiffness(const T* eps, const P* p, T* c) {
    T w[6];
    table_weights(eps, w);
    for (int col = 0; col < 4; ++col) {
      c[col] = T(0.0);
      for (int r = 0; r < 6; ++r) c[col] += w[r] * p[4 * r + col];
    }
  }

  // Row weights w_r(y) and their y-derivatives dw[r][k] in closed form (as table_weights).
  static void table_weight_derivatives(const double* y, double w[6], double dw[6][3]);
  // C at every grid node (4 per node) for table p: cached per thread, recomputed when p's values change.
  // For a table shared by all faces.
  static const double* node_stiffness(const double* p);
  // W(eps), grad W (order >= 1) and the Hessian of W (order 2) in strain space, in closed form (C(y) and its
  // derivatives by the tensor-product smoothstep blend); nodes: node_stiffness(p) for a shared table, or null.
  static void strain_energy_derivatives(const double* eps, const double* p, const double* nodes, int order, double& W,
                                        double dW[3], double d2W[3][3]);
  const double* shared_nodes(const Eigen::VectorXd& p) const { return shared_ ? node_stiffness(p.data() + offset_) : nullptr; }

  // Strain energy density W(eps) [J/m^2] (see the header comment).
  template <class T, class P>
  static T strain_energy(const T* eps, const P* p) {
    // W = int_0^1 (1 - t) eps^T C(t eps) eps dt by 3-point Gauss-Legendre (exact for constant C: 1/2 eps^T C eps).
    T W = T(0.0);
    for (int q = 0; q < 3; ++q) {
      T teps[3] = {kQuadT[q] * eps[0], kQuadT[q] * eps[1], kQuadT[q] * eps[2]};
      T c[4];
      stiffness(teps, p, c);
      W += (kQuadW[q] * (1.0 - kQuadT[q])) * (c[0] * eps[0] * eps[0] + 2.0 * c[1] * eps[0] * eps[1] +
                                              c[2] * eps[1] * eps[1] + c[3] * eps[2] * eps[2]);
    }
    return W;
  }

  // dW/dp (24 entries; W is linear in the table).
  template <class T>
  static void strain_energy_table_gradient(const T* eps, T* dW) {
    for (int k = 0; k < 24; ++k) dW[k] = T(0.0);
    const T Q[4] = {eps[0] * eps[0], 2.0 * eps[0] * eps[1], eps[1] * eps[1], eps[2] * eps[2]};
    for (int q = 0; q < 3; ++q) {
      T teps[3] = {kQuadT[q] * eps[0], kQuadT[q] * eps[1], kQuadT[q] * eps[2]};
      T w[6];
      table_weights(teps, w);
      const double coef = kQuadW[q] * (1.0 - kQuadT[q]);
      for (int r = 0; r < 6; ++r) {
        const T cw = coef * w[r];
        for (int col = 0; col < 4; ++col) dW[4 * r + col] += cw * Q[col];
      }
    }
  }

  template <class T>
  T element_energy(int e, const T* x, const T* p) const {
    T eps[3];
    green_strain(e, x, eps);
    return area_[e] * strain_energy(eps, p);
  }

  // Hand-derived kernels (the chain rule through the 3 strains: jets only on W(eps), C(eps) and S+(eps),
  // the strain map eps(x) and its derivatives written out). Equal to the jet-derived reference
  // (ElementTerm's versions, kept as Reference) to round-off; see tests/native/physics/test_kernels.cpp.
  using Reference = ElementTerm<StretchTerm, 3, 24, 9>;
  double energy(const Eigen::VectorXd& x, const Eigen::VectorXd& p) const override;
  void add_gradient(const Eigen::VectorXd& x, const Eigen::VectorXd& p, Eigen::VectorXd& g) const override;
  void add_step_matrix(const Eigen::VectorXd& x, const Eigen::VectorXd& p, double scale,
                       Eigen::VectorXd& values) const override;
  void add_hessian(const Eigen::VectorXd& x, const Eigen::VectorXd& p, double scale,
                   Eigen::VectorXd& values) const override;
  void add_projected_hessian(const Eigen::VectorXd& x, const Eigen::VectorXd& p, double scale,
                             Eigen::VectorXd& values) const override;
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

  // Residuals (eps, F) and weights: material part A C(eps) on eps, geometric part A S+ (x) I3 on F, where
  // S+ is the positive part of the secant stress [[s_uu, s_uv/2], [s_uv/2, s_vv]], s = C(eps) eps. The
  // geometric part gives a taut membrane its out-of-plane stiffness (without it the h = 0.05 s step diverges).
  template <class T>
  void element_gauss_newton(int e, const T* x, const T* p, T* r, T* S) const {
    T f[3][2];
    deformation_gradient(e, x, f);
    gauss_newton_of(f, p, area_[e], r, S);
  }
  // The Gauss-Newton residuals and weights of a face with deformation gradient f and rest area A.
  template <class T, class Table, class Area>
  static void gauss_newton_of(const T f[3][2], const Table* p, const Area& A, T* r, T* S) {
    strain_of(f, r);
    for (int c = 0; c < 3; ++c)
      for (int a = 0; a < 2; ++a) r[3 + 2 * c + a] = f[c][a];
    T c[4];
    stiffness(r, p, c);
    for (int k = 0; k < 81; ++k) S[k] = T(0.0);
    S[0] = A * c[0];
    S[1] = A * c[1];
    S[9] = A * c[1];
    S[10] = A * c[2];
    S[20] = A * c[3];
    // secant stress and its positive part (closed-form 2x2 eigen-split)
    const T s00 = c[0] * r[0] + c[1] * r[1], s11 = c[1] * r[0] + c[2] * r[1], s01 = 0.5 * c[3] * r[2];
    T P[2][2];
    positive_part(s00, s01, s11, P);
    for (int cc = 0; cc < 3; ++cc)
      for (int a = 0; a < 2; ++a)
        for (int b = 0; b < 2; ++b) S[(3 + 2 * cc + a) * 9 + 3 + 2 * cc + b] = A * P[a][b];
  }

  // Positive semidefinite part of the symmetric 2x2 matrix [[a, b], [b, d]].
  template <class T>
  static void positive_part(const T& a, const T& b, const T& d, T P[2][2]) {
    const double av = value_of(a), bv = value_of(b), dv = value_of(d);
    const double mv = 0.5 * (av + dv), rv = std::sqrt(0.25 * (av - dv) * (av - dv) + bv * bv);
    if (mv - rv >= 0) {  // both eigenvalues >= 0
      P[0][0] = a; P[0][1] = b; P[1][0] = b; P[1][1] = d;
    } else if (mv + rv <= 0) {  // both <= 0
      P[0][0] = P[0][1] = P[1][0] = P[1][1] = T(0.0);
    } else {  // mu1 > 0 > mu2: P = mu1 (S - mu2 I) / (mu1 - mu2)
      const T m = 0.5 * (a + d), rad = sqrt(0.25 * (a - d) * (a - d) + b * b);
      const T mu1 = m + rad, mu2 = m - rad;
      const T k = mu1 / (mu1 - mu2);
      P[0][0] = k * (a - mu2); P[0][1] = k * b; P[1][0] = k * b; P[1][1] = k * (d - mu2);
    }
  }

 private:
  // The exact element Hessians, each projected onto the PSD cone if `project` (add_projected_hessian).
  void add_element_hessians(const Eigen::VectorXd& x, const Eigen::VectorXd& p, double scale,
                            Eigen::VectorXd& values, bool project) const;
  // The rest pattern's scaling at p: the column factors of Dm^-1, 1 / a_u and 1 / a_v, and the rest-area factor
  // a_u a_v; all exactly 1 without a scaling or at zero strain.
  struct RestScale {
    double su = 1, sv = 1, area = 1;
  };
  RestScale rest_scale(const Eigen::VectorXd& p) const;
  // Adds, for the rest scaling's parameters, cE dE/dq + cG d(lambda . grad E)/dq + cK d(lambda^T K w)/dq to gp.
  void add_rest_scaling_derivatives(const Eigen::VectorXd& x, const Eigen::VectorXd& p, const Eigen::VectorXd* lambda,
                                    const Eigen::VectorXd* w, double cE, double cG, double cK,
                                    Eigen::VectorXd& gp) const;
  static constexpr double kQuadT[3] = {0.5 - 0.3872983346207417, 0.5, 0.5 + 0.3872983346207417};
  static constexpr double kQuadW[3] = {5.0 / 18.0, 8.0 / 18.0, 5.0 / 18.0};

  // Per-element state of the hand-written kernels.
  struct Local;
  void local_state(int e, const Eigen::VectorXd& x, const RestScale& rs, Local& s) const;
  static void element_step_matrix(const Local& s, const double* pe, double* K);
  void directional(const Local& s, const Eigen::VectorXd& u, double dF[3][2], double de[3]) const;
  // Per-face derivative of q = lambda^T K w: adds scale * dq/dx to ge and scale * dq/dp to gp; if Kl is given,
  // also Kl += kscale * K lambda.
  static void step_matrix_derivative_element(const Local& s, const double* p, const double dFl[3][2],
                                             const double el[3], const double dFw[3][2], const double ew[3],
                                             double scale, double* ge, double* gp, double kscale, double* Kl);
  // Cell index and fraction along one grid axis, clamped to the grid (constant extrapolation).
  template <class T>
  static void cell(const T& g, int n, int& i0, T& f) {
    const double gv = value_of(g);
    if (gv <= 0) {
      i0 = 0;
      f = T(0.0);
    } else if (gv >= n - 1) {
      i0 = n - 2;
      f = T(1.0);
    } else {
      i0 = static_cast<int>(gv);
      if (i0 > n - 2) i0 = n - 2;
      f = smoothstep(g - static_cast<double>(i0));
    }
  }

  std::vector<std::array<int, 3>> faces_;
  std::vector<std::array<double, 4>> dm_inv_;  // row-major 2x2 inverse of the rest edge matrix
  std::vector<double> area_;
  int offset_;
  bool shared_;
  RestScaling rest_;
};

}  // namespace drapelab
