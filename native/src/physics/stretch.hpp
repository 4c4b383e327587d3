// Nonlinear anisotropic membrane stretching (Volino et al. 2009; Wang, O'Brien, Ramamoorthi 2011).
//
// Per face j with rest pattern (u, v) (u = weft, v = warp) and rest area A_j:
//   F = Ds Dm^-1 (3x2 deformation gradient), G = (F^T F - I) / 2 (Green strain),
//   eps = (G_uu, G_vv, G_uv),  W = 1/2 eps^T C eps,  C = [[c11, c12, 0], [c12, c22, 0], [0, 0, c33]],
//   E_j = A_j W   [J];  table entries in N/m.
// Each face carries a table (6 x 4, row-major, columns c11, c12, c22, c33): row 0 is the small-strain
// sample (lambda_max = 0, all directions); rows 1..5 are samples at lambda_max = kStretchSampleStrain
// in directions phi = 0, 22.5, 45, 67.5, 90 degrees from the weft (u) axis, where lambda_max + 1 is the
// largest principal stretch and phi its direction (folded to [0, 90] degrees by symmetry).
// The stiffness C(G) = sum_r W_r(G) row_r interpolates this table piecewise-linearly in
// (lambda_max, phi) at the nodes of a grid over (G_uu, G_vv, |G_uv|) and trilinearly between nodes
// (as the paper's released code does): continuous in G, well defined at isotropic strain (where phi is
// not), and linear in the table. At isotropic grid nodes the five directions are averaged.
// The energy includes the dependence of C on G, so forces are conservative and E is a potential.
// Step matrix: Gauss-Newton A_j J_eps^T C J_eps (C frozen), PSD for valid tables.
#pragma once
#include <array>
#include <vector>

#include "geometry/mesh.hpp"
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

class StretchTerm : public ElementTerm<StretchTerm, 3, 24, 3> {
 public:
  // parameter_offset: offset of the "stretch" block; shared = one table for all faces.
  StretchTerm(const TriangleMesh& mesh, int parameter_offset, bool shared);
  std::string name() const override { return "stretch"; }

  int num_elements() const { return static_cast<int>(faces_.size()); }
  const std::array<int, 3>& element_vertices(int e) const { return faces_[e]; }
  int parameter_offset(int e) const { return offset_ + (shared_ ? 0 : 24 * e); }

  template <class T>
  void green_strain(int e, const T* x, T* eps) const {
    const auto& Di = dm_inv_[e];
    T f[3][2];
    for (int c = 0; c < 3; ++c) {
      const T d1 = x[3 + c] - x[c], d2 = x[6 + c] - x[c];
      f[c][0] = d1 * Di[0] + d2 * Di[2];
      f[c][1] = d1 * Di[1] + d2 * Di[3];
    }
    T g00 = f[0][0] * f[0][0] + f[1][0] * f[1][0] + f[2][0] * f[2][0];
    T g11 = f[0][1] * f[0][1] + f[1][1] * f[1][1] + f[2][1] * f[2][1];
    T g01 = f[0][0] * f[0][1] + f[1][0] * f[1][1] + f[2][0] * f[2][1];
    eps[0] = 0.5 * (g00 - 1.0);
    eps[1] = 0.5 * (g11 - 1.0);
    eps[2] = 0.5 * g01;
  }

  // C entries (c11, c12, c22, c33) interpolated at strain eps from table p (24 entries).
  template <class T>
  void stiffness(const T* eps, const T* p, T* c) const {
    const StretchWeightGrid& grid = stretch_weight_grid();
    const T ga = (eps[0] - StretchWeightGrid::kMin) / StretchWeightGrid::kStep;
    const T gb = (eps[1] - StretchWeightGrid::kMin) / StretchWeightGrid::kStep;
    const T gc = (value_of(eps[2]) >= 0 ? eps[2] : -eps[2]) / StretchWeightGrid::kStep;
    int i0, j0, k0;
    T fa, fb, fc;
    cell(ga, StretchWeightGrid::kNormal, i0, fa);
    cell(gb, StretchWeightGrid::kNormal, j0, fb);
    cell(gc, StretchWeightGrid::kShear, k0, fc);
    T w[6];
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
    for (int col = 0; col < 4; ++col) {
      c[col] = T(0.0);
      for (int r = 0; r < 6; ++r) c[col] += w[r] * p[4 * r + col];
    }
  }

  template <class T>
  T element_energy(int e, const T* x, const T* p) const {
    T eps[3], c[4];
    green_strain(e, x, eps);
    stiffness(eps, p, c);
    const T W = 0.5 * (c[0] * eps[0] * eps[0] + 2.0 * c[1] * eps[0] * eps[1] + c[2] * eps[1] * eps[1] +
                       c[3] * eps[2] * eps[2]);
    return area_[e] * W;
  }

  template <class T>
  void element_gauss_newton(int e, const T* x, const T* p, T* r, T* S) const {
    green_strain(e, x, r);
    T c[4];
    stiffness(r, p, c);
    const double A = area_[e];
    S[0] = A * c[0];
    S[1] = A * c[1];
    S[2] = T(0.0);
    S[3] = A * c[1];
    S[4] = A * c[2];
    S[5] = T(0.0);
    S[6] = T(0.0);
    S[7] = T(0.0);
    S[8] = A * c[3];
  }

 private:
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
      f = g - static_cast<double>(i0);
    }
  }

  std::vector<std::array<int, 3>> faces_;
  std::vector<std::array<double, 4>> dm_inv_;  // row-major 2x2 inverse of the rest edge matrix
  std::vector<double> area_;
  int offset_;
  bool shared_;
};

}  // namespace drapelab
