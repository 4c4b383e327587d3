#include "physics/stretch.hpp"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>

#include "util/error.hpp"
#include "util/psd_projection.hpp"

namespace drapelab {

std::array<double, 6> StretchWeightGrid::polar_weights(double guu, double gvv, double guv) {
  // Principal stretches: eigenvalues of C = 2G + I = F^T F.
  const double a = 2 * guu + 1, b = 2 * guv, d = 2 * gvv + 1;
  const double mean = 0.5 * (a + d), dev = std::sqrt(0.25 * (a - d) * (a - d) + b * b);
  const double lmax = mean + dev;
  const double lambda_max = std::sqrt(std::max(lmax, 0.0)) - 1.0;
  double s = lambda_max / kStretchSampleStrain;
  s = std::min(std::max(s, 0.0), 1.0);
  std::array<double, 6> w{};
  w[0] = 1.0 - s;
  if (dev < 1e-12) {  // isotropic: the direction is undefined, average the five directions
    for (int k = 0; k < 5; ++k) w[1 + k] = s / 5.0;
    return w;
  }
  // Eigenvector of lmax: (b, lmax - a) or (lmax - d, b); fold its angle to [0, pi/2].
  double vx = lmax - d, vy = b;
  if (std::abs(vx) + std::abs(vy) < 1e-14) {
    vx = b;
    vy = lmax - a;
  }
  const double phi = std::atan2(std::abs(vy), std::abs(vx));  // in [0, pi/2]
  double t = phi / (M_PI / 8.0);                               // 0..4
  int k = static_cast<int>(t);
  if (k > 3) k = 3;
  const double f = t - k;
  w[1 + k] += s * (1 - f);
  w[2 + k] += s * f;
  return w;
}

StretchWeightGrid::StretchWeightGrid() {
  node_weights.resize(static_cast<size_t>(kNormal) * kNormal * kShear);
  for (int i = 0; i < kNormal; ++i)
    for (int j = 0; j < kNormal; ++j)
      for (int k = 0; k < kShear; ++k)
        node_weights[(i * kNormal + j) * kShear + k] = polar_weights(kMin + i * kStep, kMin + j * kStep, k * kStep);
}

const StretchWeightGrid& stretch_weight_grid() {
  static const StretchWeightGrid grid;
  return grid;
}

namespace {
// Fraction along one grid axis and its derivatives in y (the axis coordinate is (y - kMin) / kStep, or
// |y| / kStep for the shear axis), as StretchTerm::cell: clamped outside the grid (constant).
struct AxisBlend {
  int i0;
  double f, f1, f2;
};
inline AxisBlend axis_blend(double g, int n, double dgdy) {
  AxisBlend b{0, 0.0, 0.0, 0.0};
  if (g <= 0) return b;
  if (g >= n - 1) {
    b.i0 = n - 2;
    b.f = 1.0;
    return b;
  }
  b.i0 = static_cast<int>(g);
  if (b.i0 > n - 2) b.i0 = n - 2;
  const double u = g - static_cast<double>(b.i0);
  b.f = u * u * (3.0 - 2.0 * u);
  b.f1 = 6.0 * u * (1.0 - u) * dgdy;
  b.f2 = (6.0 - 12.0 * u) * dgdy * dgdy;
  return b;
}
}  // namespace

const double* StretchTerm::node_stiffness(const double* p) {
  struct Cache {
    bool valid = false;
    double key[24];
    std::vector<double> nodes;
  };
  thread_local Cache cache;
  if (cache.valid && std::equal(p, p + 24, cache.key)) return cache.nodes.data();
  const StretchWeightGrid& grid = stretch_weight_grid();
  cache.nodes.assign(grid.node_weights.size() * 4, 0.0);
  for (size_t i = 0; i < grid.node_weights.size(); ++i) {
    const auto& nw = grid.node_weights[i];
    for (int r = 0; r < 6; ++r)
      if (nw[r] != 0.0)
        for (int col = 0; col < 4; ++col) cache.nodes[4 * i + col] += nw[r] * p[4 * r + col];
  }
  std::copy(p, p + 24, cache.key);
  cache.valid = true;
  return cache.nodes.data();
}

void StretchTerm::table_weight_derivatives(const double* y, double w[6], double dw[6][3]) {
  using G = StretchWeightGrid;
  const StretchWeightGrid& grid = stretch_weight_grid();
  const double sgn = y[2] >= 0 ? 1.0 : -1.0;
  const AxisBlend ba = axis_blend((y[0] - G::kMin) / G::kStep, G::kNormal, 1.0 / G::kStep);
  const AxisBlend bb = axis_blend((y[1] - G::kMin) / G::kStep, G::kNormal, 1.0 / G::kStep);
  const AxisBlend bc = axis_blend((y[2] >= 0 ? y[2] : -y[2]) / G::kStep, G::kShear, 1.0 / G::kStep);
  const double Na[2][2] = {{1.0 - ba.f, -ba.f1}, {ba.f, ba.f1}};
  const double Nb[2][2] = {{1.0 - bb.f, -bb.f1}, {bb.f, bb.f1}};
  const double Nc[2][2] = {{1.0 - bc.f, -sgn * bc.f1}, {bc.f, sgn * bc.f1}};
  for (int r = 0; r < 6; ++r) w[r] = dw[r][0] = dw[r][1] = dw[r][2] = 0.0;
  for (int di = 0; di < 2; ++di)
    for (int dj = 0; dj < 2; ++dj)
      for (int dk = 0; dk < 2; ++dk) {
        const auto& nw = grid.node_weights[((ba.i0 + di) * G::kNormal + (bb.i0 + dj)) * G::kShear + bc.i0 + dk];
        const double* a = Na[di];
        const double* b = Nb[dj];
        const double* g = Nc[dk];
        const double t = a[0] * b[0] * g[0], t0 = a[1] * b[0] * g[0], t1 = a[0] * b[1] * g[0], t2 = a[0] * b[0] * g[1];
        for (int r = 0; r < 6; ++r)
          if (nw[r] != 0.0) {
            w[r] += t * nw[r];
            dw[r][0] += t0 * nw[r];
            dw[r][1] += t1 * nw[r];
            dw[r][2] += t2 * nw[r];
          }
      }
}

namespace {
// C(y) and its y-derivatives in closed form: the blend is a tensor product of 1-D smoothstep fractions, so it
// is evaluated axis by axis (shear, then G_vv, then G_uu) on the 8 surrounding nodes' stiffness.
// kOrder 0: C; 1: and dC/dy; 2: and d2C/dy2 (kl = 00, 11, 22, 01, 02, 12).
template <int kOrder>
void blend_separable(const AxisBlend& ba, const AxisBlend& bb, const AxisBlend& bc, double sgn, const double* nodes,
                     const double* p, double c[4], double dc[4][3], double d2c[4][6]) {
  constexpr bool kGrad = kOrder >= 1;
  using G = StretchWeightGrid;
  const StretchWeightGrid& grid = stretch_weight_grid();
  // along the shear axis (k) for the 4 (i, j) corners
  double v[2][2][4], vk[2][2][4], vkk[2][2][4];
  const double n0 = 1.0 - bc.f, n1 = bc.f, d1 = sgn * bc.f1, d2 = bc.f2;
  for (int di = 0; di < 2; ++di)
    for (int dj = 0; dj < 2; ++dj) {
      const int node = ((ba.i0 + di) * G::kNormal + (bb.i0 + dj)) * G::kShear + bc.i0;
      double c0[4], c1[4];
      if (nodes) {
        for (int col = 0; col < 4; ++col) {
          c0[col] = nodes[4 * node + col];
          c1[col] = nodes[4 * (node + 1) + col];
        }
      } else {
        for (int col = 0; col < 4; ++col) c0[col] = c1[col] = 0.0;
        const auto& w0 = grid.node_weights[node];
        const auto& w1 = grid.node_weights[node + 1];
        for (int r = 0; r < 6; ++r)
          for (int col = 0; col < 4; ++col) {
            if (w0[r] != 0.0) c0[col] += w0[r] * p[4 * r + col];
            if (w1[r] != 0.0) c1[col] += w1[r] * p[4 * r + col];
          }
      }
      for (int col = 0; col < 4; ++col) {
        v[di][dj][col] = n0 * c0[col] + n1 * c1[col];
        if (kGrad) vk[di][dj][col] = d1 * (c1[col] - c0[col]);
        if (kOrder >= 2) vkk[di][dj][col] = d2 * (c1[col] - c0[col]);
      }
    }
  // along j, then i
  const double m0 = 1.0 - bb.f, m1 = bb.f, e1 = bb.f1;
  const double l0 = 1.0 - ba.f, l1 = ba.f, g1 = ba.f1;
  for (int col = 0; col < 4; ++col) {
    const double u0 = m0 * v[0][0][col] + m1 * v[0][1][col], u1 = m0 * v[1][0][col] + m1 * v[1][1][col];
    c[col] = l0 * u0 + l1 * u1;
    if (kGrad) {
      const double uj0 = e1 * (v[0][1][col] - v[0][0][col]), uj1 = e1 * (v[1][1][col] - v[1][0][col]);
      const double uk0 = m0 * vk[0][0][col] + m1 * vk[0][1][col], uk1 = m0 * vk[1][0][col] + m1 * vk[1][1][col];
      dc[col][0] = g1 * (u1 - u0);
      dc[col][1] = l0 * uj0 + l1 * uj1;
      dc[col][2] = l0 * uk0 + l1 * uk1;
      if (kOrder >= 2) {
        const double e2 = bb.f2, g2 = ba.f2;
        const double ujj0 = e2 * (v[0][1][col] - v[0][0][col]), ujj1 = e2 * (v[1][1][col] - v[1][0][col]);
        const double ukk0 = m0 * vkk[0][0][col] + m1 * vkk[0][1][col], ukk1 = m0 * vkk[1][0][col] + m1 * vkk[1][1][col];
        const double ujk0 = e1 * (vk[0][1][col] - vk[0][0][col]), ujk1 = e1 * (vk[1][1][col] - vk[1][0][col]);
        d2c[col][0] = g2 * (u1 - u0);
        d2c[col][1] = l0 * ujj0 + l1 * ujj1;
        d2c[col][2] = l0 * ukk0 + l1 * ukk1;
        d2c[col][3] = g1 * (uj1 - uj0);
        d2c[col][4] = g1 * (uk1 - uk0);
        d2c[col][5] = l0 * ujk0 + l1 * ujk1;
      }
    }
  }
}
}  // namespace

void StretchTerm::strain_energy_derivatives(const double* eps, const double* p, const double* nodes, int order,
                                            double& W, double dW[3], double d2W[3][3]) {
  // W = sum_q k_q sum_col C_col(t_q eps) Q_col(eps), Q = (e0^2, 2 e0 e1, e1^2, e2^2)
  const double Q[4] = {eps[0] * eps[0], 2.0 * eps[0] * eps[1], eps[1] * eps[1], eps[2] * eps[2]};
  const double dQ[4][3] = {{2.0 * eps[0], 0.0, 0.0}, {2.0 * eps[1], 2.0 * eps[0], 0.0}, {0.0, 2.0 * eps[1], 0.0},
                           {0.0, 0.0, 2.0 * eps[2]}};
  W = 0.0;
  if (order >= 1) dW[0] = dW[1] = dW[2] = 0.0;
  if (order >= 2)
    for (int k = 0; k < 3; ++k) d2W[k][0] = d2W[k][1] = d2W[k][2] = 0.0;
  static const int kl[3][3] = {{0, 3, 4}, {3, 1, 5}, {4, 5, 2}};
  for (int q = 0; q < 3; ++q) {
    const double t = kQuadT[q], kq = kQuadW[q] * (1.0 - kQuadT[q]);
    const double y[3] = {t * eps[0], t * eps[1], t * eps[2]};
    double c[4], dc[4][3], d2c[4][6];
    {
      using G = StretchWeightGrid;
      const double sgn = y[2] >= 0 ? 1.0 : -1.0;
      const AxisBlend ba = axis_blend((y[0] - G::kMin) / G::kStep, G::kNormal, 1.0 / G::kStep);
      const AxisBlend bb = axis_blend((y[1] - G::kMin) / G::kStep, G::kNormal, 1.0 / G::kStep);
      const AxisBlend bc = axis_blend((y[2] >= 0 ? y[2] : -y[2]) / G::kStep, G::kShear, 1.0 / G::kStep);
      if (order >= 2) blend_separable<2>(ba, bb, bc, sgn, nodes, p, c, dc, d2c);
      else if (order == 1) blend_separable<1>(ba, bb, bc, sgn, nodes, p, c, dc, d2c);
      else blend_separable<0>(ba, bb, bc, sgn, nodes, p, c, dc, d2c);
    }
    W += kq * (c[0] * Q[0] + c[1] * Q[1] + c[2] * Q[2] + c[3] * Q[3]);
    if (order >= 1)
      for (int k = 0; k < 3; ++k) {
        double s = 0;
        for (int col = 0; col < 4; ++col) s += t * dc[col][k] * Q[col] + c[col] * dQ[col][k];
        dW[k] += kq * s;
      }
    if (order >= 2)
      for (int k = 0; k < 3; ++k)
        for (int l = 0; l < 3; ++l) {
          double s = 0;
          for (int col = 0; col < 4; ++col)
            s += t * t * d2c[col][kl[k][l]] * Q[col] + t * dc[col][k] * dQ[col][l] + t * dc[col][l] * dQ[col][k];
          // second derivatives of Q: d2Q0/de0^2 = 2, d2Q1/de0de1 = 2, d2Q2/de1^2 = 2, d2Q3/de2^2 = 2
          if (k == 0 && l == 0) s += 2.0 * c[0];
          if ((k == 0 && l == 1) || (k == 1 && l == 0)) s += 2.0 * c[1];
          if (k == 1 && l == 1) s += 2.0 * c[2];
          if (k == 2 && l == 2) s += 2.0 * c[3];
          d2W[k][l] += kq * s;
        }
  }
}

StretchTerm::StretchTerm(const TriangleMesh& mesh, int parameter_offset, bool shared, RestScaling rest)
    : offset_(parameter_offset), shared_(shared), rest_(std::move(rest)) {
  const int nf = mesh.num_faces();
  faces_.resize(nf);
  dm_inv_.resize(nf);
  area_.resize(nf);
  for (int f = 0; f < nf; ++f) {
    faces_[f] = {mesh.faces(f, 0), mesh.faces(f, 1), mesh.faces(f, 2)};
    const Eigen::Vector2d u0 = mesh.face_uv(f, 0);
    Eigen::Matrix2d Dm;
    Dm.col(0) = mesh.face_uv(f, 1) - u0;
    Dm.col(1) = mesh.face_uv(f, 2) - u0;
    const double det = Dm.determinant();
    if (!(std::abs(det) > 0)) throw InputError("stretch: face " + std::to_string(f) + " has zero rest area");
    const Eigen::Matrix2d Di = Dm.inverse();
    dm_inv_[f] = {Di(0, 0), Di(0, 1), Di(1, 0), Di(1, 1)};
    area_[f] = 0.5 * std::abs(det);
  }
}

}  // namespace drapelab

// ---------------------------------------------------------------------------------------------------------
// Hand-written kernels. Per face: F = sum_v x_v B_v^T (B_v: row v of the 3x2 shape matrix below), the strains
// eps = (G_uu, G_vv, G_uv) with columns f_a of F:  d eps_0 = f_0 . dF_0,  d eps_1 = f_1 . dF_1,
// d eps_2 = (f_0 . dF_1 + f_1 . dF_0) / 2, and second derivatives (sum_ab Y_ab B_a B_b^T) (x) I3 for a
// symmetric 2x2 Y = [[y_0, y_2 / 2], [y_2 / 2, y_1]] of strain weights y.
// ---------------------------------------------------------------------------------------------------------

namespace drapelab {

struct StretchTerm::Local {
  int v[3];
  double B[3][2];   // dF[c][a] / dx[3 v + c]
  double f[3][2];   // F
  double eps[3];    // strains
  double Je[3][9];  // d eps / dx
  double A;
  const double* p;
};

namespace {
using J3 = Jet<double, 3>;

// out[3v+c] += scale * sum_a (sum_b f[c][b] Y[b][a]) B[v][a]  (the strain-gradient map J_eps^T y)
inline void strain_transpose(const double f[3][2], const double B[3][2], const double y[3], double* out) {
  const double Y[2][2] = {{y[0], 0.5 * y[2]}, {0.5 * y[2], y[1]}};
  for (int c = 0; c < 3; ++c) {
    const double P0 = f[c][0] * Y[0][0] + f[c][1] * Y[1][0];
    const double P1 = f[c][0] * Y[0][1] + f[c][1] * Y[1][1];
    for (int v = 0; v < 3; ++v) out[3 * v + c] += P0 * B[v][0] + P1 * B[v][1];
  }
}

// K[(3v+c)(3w+c)] += sum_ab Y[a][b] B[v][a] B[w][b] for every c (the strain-Hessian / geometric block).
inline void add_shape_block(const double B[3][2], const double Y[2][2], double* K) {
  for (int v = 0; v < 3; ++v)
    for (int w = 0; w < 3; ++w) {
      const double s = B[v][0] * (Y[0][0] * B[w][0] + Y[0][1] * B[w][1]) + B[v][1] * (Y[1][0] * B[w][0] + Y[1][1] * B[w][1]);
      for (int c = 0; c < 3; ++c) K[(3 * v + c) * 9 + 3 * w + c] += s;
    }
}
}  // namespace

StretchTerm::RestScale StretchTerm::rest_scale(const Eigen::VectorXd& p) const {
  RestScale rs;
  if (!rest_.active()) return rs;
  double su, sv;
  rest_.strains(p, su, sv);
  const double au = 1.0 - su, av = 1.0 - sv;
  if (!(au > 0 && av > 0)) throw InputError("stretch: a rest-length scaling of 1 - strain <= 0");
  rs.su = 1.0 / au;
  rs.sv = 1.0 / av;
  rs.area = au * av;
  return rs;
}

void StretchTerm::local_state(int e, const Eigen::VectorXd& x, const RestScale& rs, Local& s) const {
  const auto& vv = faces_[e];
  double xe[9];
  for (int k = 0; k < 3; ++k) {
    s.v[k] = vv[k];
    for (int c = 0; c < 3; ++c) xe[3 * k + c] = x[3 * vv[k] + c];
  }
  const auto& D = dm_inv_[e];
  const double Di[4] = {D[0] * rs.su, D[1] * rs.sv, D[2] * rs.su, D[3] * rs.sv};  // exact copies when unscaled
  for (int a = 0; a < 2; ++a) {
    s.B[1][a] = Di[a];
    s.B[2][a] = Di[2 + a];
    s.B[0][a] = -(Di[a] + Di[2 + a]);
  }
  deformation_gradient_of(xe, Di, s.f);
  strain_of(s.f, s.eps);
  for (int v = 0; v < 3; ++v)
    for (int c = 0; c < 3; ++c) {
      const int j = 3 * v + c;
      s.Je[0][j] = s.f[c][0] * s.B[v][0];
      s.Je[1][j] = s.f[c][1] * s.B[v][1];
      s.Je[2][j] = 0.5 * (s.f[c][0] * s.B[v][1] + s.f[c][1] * s.B[v][0]);
    }
  s.A = area_[e] * rs.area;
}

double StretchTerm::energy(const Eigen::VectorXd& x, const Eigen::VectorXd& p) const {
  const double* nodes = shared_nodes(p);
  const RestScale rs = rest_scale(p);
  double E = 0, xe[9], eps[3], f[3][2];
  for (int e = 0; e < num_elements(); ++e) {
    gather(e, x, xe);
    const auto& D = dm_inv_[e];
    const double Di[4] = {D[0] * rs.su, D[1] * rs.sv, D[2] * rs.su, D[3] * rs.sv};
    deformation_gradient_of(xe, Di, f);
    strain_of(f, eps);
    double W, dW[3], d2W[3][3];
    strain_energy_derivatives(eps, p.data() + parameter_offset(e), nodes, 0, W, dW, d2W);
    E += (area_[e] * rs.area) * W;
  }
  return E;
}

void StretchTerm::add_gradient(const Eigen::VectorXd& x, const Eigen::VectorXd& p, Eigen::VectorXd& g) const {
  const double* nodes = shared_nodes(p);
  const RestScale rs = rest_scale(p);
  Local s;
  for (int e = 0; e < num_elements(); ++e) {
    local_state(e, x, rs, s);
    double W, dW[3], d2W[3][3];
    strain_energy_derivatives(s.eps, p.data() + parameter_offset(e), nodes, 1, W, dW, d2W);
    const double y[3] = {s.A * dW[0], s.A * dW[1], s.A * dW[2]};
    double ge[9] = {0};
    strain_transpose(s.f, s.B, y, ge);
    scatter_vector(e, ge, 1.0, g);
  }
}

// K_e = J_eps^T (A C) J_eps (material part) + A S+ (x) I3 on F (geometric part), 9 x 9 row-major.
void StretchTerm::element_step_matrix(const Local& s, const double* pe, double* K) {
  double c[4];
  stiffness(s.eps, pe, c);
  // material part J_eps^T (A C) J_eps
  const double Cm[3][3] = {{s.A * c[0], s.A * c[1], 0.0}, {s.A * c[1], s.A * c[2], 0.0}, {0.0, 0.0, s.A * c[3]}};
  double M[3][9];
  for (int a = 0; a < 3; ++a)
    for (int j = 0; j < 9; ++j) M[a][j] = Cm[a][0] * s.Je[0][j] + Cm[a][1] * s.Je[1][j] + Cm[a][2] * s.Je[2][j];
  for (int i = 0; i < 9; ++i)
    for (int j = i; j < 9; ++j) K[i * 9 + j] = s.Je[0][i] * M[0][j] + s.Je[1][i] * M[1][j] + s.Je[2][i] * M[2][j];
  for (int i = 0; i < 9; ++i)
    for (int j = 0; j < i; ++j) K[i * 9 + j] = K[j * 9 + i];
  // geometric part A S+ (x) I3 on F
  const double s00 = c[0] * s.eps[0] + c[1] * s.eps[1], s11 = c[1] * s.eps[0] + c[2] * s.eps[1],
               s01 = 0.5 * c[3] * s.eps[2];
  double P[2][2];
  positive_part(s00, s01, s11, P);
  const double Y[2][2] = {{s.A * P[0][0], s.A * P[0][1]}, {s.A * P[1][0], s.A * P[1][1]}};
  add_shape_block(s.B, Y, K);
}

void StretchTerm::add_step_matrix(const Eigen::VectorXd& x, const Eigen::VectorXd& p, double scale,
                                  Eigen::VectorXd& values) const {
  const RestScale rs = rest_scale(p);
  Local s;
  double K[81];
  for (int e = 0; e < num_elements(); ++e) {
    local_state(e, x, rs, s);
    element_step_matrix(s, p.data() + parameter_offset(e), K);
    scatter_matrix(e, K, scale, values);
  }
}

void StretchTerm::add_hessian(const Eigen::VectorXd& x, const Eigen::VectorXd& p, double scale,
                              Eigen::VectorXd& values) const {
  add_element_hessians(x, p, scale, values, false);
}

void StretchTerm::add_projected_hessian(const Eigen::VectorXd& x, const Eigen::VectorXd& p, double scale,
                                        Eigen::VectorXd& values) const {
  add_element_hessians(x, p, scale, values, true);
}

void StretchTerm::add_element_hessians(const Eigen::VectorXd& x, const Eigen::VectorXd& p, double scale,
                                       Eigen::VectorXd& values, bool project) const {
  const double* nodes = shared_nodes(p);
  const RestScale rs = rest_scale(p);
  Local s;
  double H[81];
  for (int e = 0; e < num_elements(); ++e) {
    local_state(e, x, rs, s);
    double W, dW[3], d2W[3][3];
    strain_energy_derivatives(s.eps, p.data() + parameter_offset(e), nodes, 2, W, dW, d2W);
    double M[3][9];
    for (int a = 0; a < 3; ++a)
      for (int j = 0; j < 9; ++j)
        M[a][j] = s.A * (d2W[a][0] * s.Je[0][j] + d2W[a][1] * s.Je[1][j] + d2W[a][2] * s.Je[2][j]);
    for (int i = 0; i < 9; ++i)
      for (int j = i; j < 9; ++j) H[i * 9 + j] = s.Je[0][i] * M[0][j] + s.Je[1][i] * M[1][j] + s.Je[2][i] * M[2][j];
    for (int i = 0; i < 9; ++i)
      for (int j = 0; j < i; ++j) H[i * 9 + j] = H[j * 9 + i];
    const double Y[2][2] = {{s.A * dW[0], 0.5 * s.A * dW[2]}, {0.5 * s.A * dW[2], s.A * dW[1]}};
    add_shape_block(s.B, Y, H);
    if (project) project_psd<9>(H);
    scatter_matrix(e, H, scale, values);
  }
}

void StretchTerm::add_hessian_product(const Eigen::VectorXd& x, const Eigen::VectorXd& p, const Eigen::VectorXd& dir,
                                      Eigen::VectorXd& out) const {
  const double* nodes = shared_nodes(p);
  const RestScale rs = rest_scale(p);
  Local s;
  for (int e = 0; e < num_elements(); ++e) {
    local_state(e, x, rs, s);
    double d[9];
    for (int k = 0; k < 3; ++k)
      for (int c = 0; c < 3; ++c) d[3 * k + c] = dir[3 * s.v[k] + c];
    double de[3];
    for (int k = 0; k < 3; ++k) {
      de[k] = 0;
      for (int j = 0; j < 9; ++j) de[k] += s.Je[k][j] * d[j];
    }
    double W, dW[3], d2W[3][3];
    strain_energy_derivatives(s.eps, p.data() + parameter_offset(e), nodes, 2, W, dW, d2W);
    double Hd[9] = {0};
    double hy[3];
    for (int k = 0; k < 3; ++k) hy[k] = s.A * (d2W[k][0] * de[0] + d2W[k][1] * de[1] + d2W[k][2] * de[2]);
    strain_transpose(s.f, s.B, hy, Hd);
    // (sum_ab Y_ab B_a B_b^T) (x) I3 d with Y from grad W
    const double Y[2][2] = {{s.A * dW[0], 0.5 * s.A * dW[2]}, {0.5 * s.A * dW[2], s.A * dW[1]}};
    for (int c = 0; c < 3; ++c) {
      double dF[2] = {0, 0};
      for (int w = 0; w < 3; ++w)
        for (int b = 0; b < 2; ++b) dF[b] += s.B[w][b] * d[3 * w + c];
      const double t0 = Y[0][0] * dF[0] + Y[0][1] * dF[1], t1 = Y[1][0] * dF[0] + Y[1][1] * dF[1];
      for (int v = 0; v < 3; ++v) Hd[3 * v + c] += s.B[v][0] * t0 + s.B[v][1] * t1;
    }
    scatter_vector(e, Hd, 1.0, out);
  }
}

void StretchTerm::add_energy_parameter_gradient(const Eigen::VectorXd& x, const Eigen::VectorXd& p,
                                                Eigen::VectorXd& gp) const {
  const RestScale rs = rest_scale(p);
  Local s;
  double dW[24];
  for (int e = 0; e < num_elements(); ++e) {
    local_state(e, x, rs, s);
    strain_energy_table_gradient(s.eps, dW);
    const int off = parameter_offset(e);
    for (int k = 0; k < 24; ++k) gp[off + k] += s.A * dW[k];
  }
  if (rest_.active()) add_rest_scaling_derivatives(x, p, nullptr, nullptr, 1.0, 0.0, 0.0, gp);
}

void StretchTerm::add_gradient_parameter_product(const Eigen::VectorXd& x, const Eigen::VectorXd& p,
                                                 const Eigen::VectorXd& lambda, double scale,
                                                 Eigen::VectorXd& gp) const {
  using D1 = Jet<double, 1>;
  const RestScale rs = rest_scale(p);
  Local s;
  D1 dW[24];
  for (int e = 0; e < num_elements(); ++e) {
    local_state(e, x, rs, s);
    D1 ej[3];
    for (int k = 0; k < 3; ++k) {
      double de = 0;
      for (int vv = 0; vv < 3; ++vv)
        for (int c = 0; c < 3; ++c) de += s.Je[k][3 * vv + c] * lambda[3 * s.v[vv] + c];
      ej[k] = D1(s.eps[k]);
      ej[k].v[0] = de;
    }
    strain_energy_table_gradient(ej, dW);
    const int off = parameter_offset(e);
    for (int k = 0; k < 24; ++k) gp[off + k] += scale * s.A * dW[k].v[0];
  }
  if (rest_.active()) add_rest_scaling_derivatives(x, p, &lambda, nullptr, 0.0, scale, 0.0, gp);
}

namespace {
// Directional data of one face along a vector u (lambda, w, a direction): dF = sum_v B_v u_v^T and the
// strain derivative J_eps u.
struct Directional {
  double dF[3][2];
  double de[3];
};
}  // namespace

void StretchTerm::add_step_matrix_derivatives(const Eigen::VectorXd& x, const Eigen::VectorXd& p,
                                              const Eigen::VectorXd& lambda, const Eigen::VectorXd& w, double scale,
                                              Eigen::VectorXd& gx, Eigen::VectorXd& gp) const {
  const RestScale rs = rest_scale(p);
  Local s;
  for (int e = 0; e < num_elements(); ++e) {
    local_state(e, x, rs, s);
    const int off = parameter_offset(e);
    Directional L, Wd;
    directional(s, lambda, L.dF, L.de);
    directional(s, w, Wd.dF, Wd.de);
    double ge[9] = {0};
    step_matrix_derivative_element(s, p.data() + off, L.dF, L.de, Wd.dF, Wd.de, scale, ge, gp.data() + off, 0.0, nullptr);
    scatter_vector(e, ge, 1.0, gx);
  }
  if (rest_.active()) add_rest_scaling_derivatives(x, p, &lambda, &w, 0.0, 0.0, scale, gp);
}

bool StretchTerm::add_step_matrix_product(const Eigen::VectorXd& x, const Eigen::VectorXd& p, const Eigen::VectorXd& dir,
                                          double scale, Eigen::VectorXd& out) const {
  const RestScale rs = rest_scale(p);
  Local s;
  for (int e = 0; e < num_elements(); ++e) {
    local_state(e, x, rs, s);
    Directional D;
    directional(s, dir, D.dF, D.de);
    double c[4];
    stiffness(s.eps, p.data() + parameter_offset(e), c);
    const double s00 = c[0] * s.eps[0] + c[1] * s.eps[1], s11 = c[1] * s.eps[0] + c[2] * s.eps[1],
                 s01 = 0.5 * c[3] * s.eps[2];
    double P[2][2];
    positive_part(s00, s01, s11, P);
    double Kd[9] = {0};
    const double y[3] = {s.A * (c[0] * D.de[0] + c[1] * D.de[1]), s.A * (c[1] * D.de[0] + c[2] * D.de[1]),
                         s.A * c[3] * D.de[2]};
    // J_eps^T y, with y the weights of the three strain gradients
    for (int j = 0; j < 9; ++j) Kd[j] = s.Je[0][j] * y[0] + s.Je[1][j] * y[1] + s.Je[2][j] * y[2];
    for (int cc = 0; cc < 3; ++cc) {
      const double t0 = s.A * (P[0][0] * D.dF[cc][0] + P[0][1] * D.dF[cc][1]);
      const double t1 = s.A * (P[1][0] * D.dF[cc][0] + P[1][1] * D.dF[cc][1]);
      for (int v = 0; v < 3; ++v) Kd[3 * v + cc] += s.B[v][0] * t0 + s.B[v][1] * t1;
    }
    scatter_vector(e, Kd, scale, out);
  }
  return true;
}

bool StretchTerm::add_step_adjoint(const Eigen::VectorXd& x, const Eigen::VectorXd& p, const Eigen::VectorXd& lambda,
                                   const Eigen::VectorXd& w, double h, Eigen::VectorXd& gx, Eigen::VectorXd& gv,
                                   Eigen::VectorXd& gp) const {
  const double* nodes = shared_nodes(p);
  const RestScale rs = rest_scale(p);
  Local s;
  for (int e = 0; e < num_elements(); ++e) {
    local_state(e, x, rs, s);
    const int off = parameter_offset(e);
    const double* pe = p.data() + off;
    Directional L, Wd;
    directional(s, lambda, L.dF, L.de);
    directional(s, w, Wd.dF, Wd.de);
    // Hessian-vector product: J_eps^T W_epseps (J_eps lambda) + (sum_ab Y_ab B_a B_b^T) (x) I3 lambda
    double Wv, dW[3], d2W[3][3];
    strain_energy_derivatives(s.eps, pe, nodes, 2, Wv, dW, d2W);
    double ge[9] = {0};
    double hy[3];
    for (int k = 0; k < 3; ++k) hy[k] = -h * s.A * (d2W[k][0] * L.de[0] + d2W[k][1] * L.de[1] + d2W[k][2] * L.de[2]);
    strain_transpose(s.f, s.B, hy, ge);
    const double Y[2][2] = {{s.A * dW[0], 0.5 * s.A * dW[2]}, {0.5 * s.A * dW[2], s.A * dW[1]}};
    for (int cc = 0; cc < 3; ++cc) {
      const double t0 = -h * (Y[0][0] * L.dF[cc][0] + Y[0][1] * L.dF[cc][1]);
      const double t1 = -h * (Y[1][0] * L.dF[cc][0] + Y[1][1] * L.dF[cc][1]);
      for (int v = 0; v < 3; ++v) ge[3 * v + cc] += s.B[v][0] * t0 + s.B[v][1] * t1;
    }
    // d(lambda . grad E)/dp: d/ds dW/dp(eps + s el), dW/dp[4r+col] = sum_q k_q w_r(t_q eps) Q_col(eps)
    {
      const double* e0 = s.eps;
      const double* el = L.de;
      const double Q[4] = {e0[0] * e0[0], 2.0 * e0[0] * e0[1], e0[1] * e0[1], e0[2] * e0[2]};
      const double dQ[4] = {2.0 * e0[0] * el[0], 2.0 * (el[0] * e0[1] + e0[0] * el[1]), 2.0 * e0[1] * el[1],
                            2.0 * e0[2] * el[2]};
      double acc[24] = {0};
      for (int q = 0; q < 3; ++q) {
        const double t = kQuadT[q], kq = kQuadW[q] * (1.0 - kQuadT[q]);
        const double y[3] = {t * e0[0], t * e0[1], t * e0[2]};
        double w[6], dw[6][3];
        table_weight_derivatives(y, w, dw);
        for (int r = 0; r < 6; ++r) {
          const double wdir = t * (dw[r][0] * el[0] + dw[r][1] * el[1] + dw[r][2] * el[2]);
          for (int col = 0; col < 4; ++col) acc[4 * r + col] += kq * (wdir * Q[col] + w[r] * dQ[col]);
        }
      }
      for (int k = 0; k < 24; ++k) gp[off + k] += -h * s.A * acc[k];
    }
    // d(lambda^T K w)/d(x, p) and K lambda
    double Kl[9] = {0};
    step_matrix_derivative_element(s, pe, L.dF, L.de, Wd.dF, Wd.de, -h * h, ge, gp.data() + off, -h * h, Kl);
    scatter_vector(e, ge, 1.0, gx);
    scatter_vector(e, Kl, 1.0, gv);
  }
  if (rest_.active()) add_rest_scaling_derivatives(x, p, &lambda, &w, 0.0, -h, -h * h, gp);
  return true;
}

void StretchTerm::directional(const Local& s, const Eigen::VectorXd& u, double dF[3][2], double de[3]) const {
  for (int c = 0; c < 3; ++c) dF[c][0] = dF[c][1] = 0.0;
  for (int vv = 0; vv < 3; ++vv)
    for (int c = 0; c < 3; ++c) {
      const double l = u[3 * s.v[vv] + c];
      for (int a = 0; a < 2; ++a) dF[c][a] += s.B[vv][a] * l;
    }
  de[0] = de[1] = de[2] = 0.0;
  for (int c = 0; c < 3; ++c) {
    de[0] += s.f[c][0] * dF[c][0];
    de[1] += s.f[c][1] * dF[c][1];
    de[2] += 0.5 * (s.f[c][0] * dF[c][1] + s.f[c][1] * dF[c][0]);
  }
}

void StretchTerm::step_matrix_derivative_element(const Local& s, const double* p, const double dFl[3][2],
                                                 const double el[3], const double dFw[3][2], const double ew[3],
                                                 double scale, double* ge, double* gp, double kscale, double* Kl) {
  using J7 = Jet<double, 7>;
  // table weights at eps with their strain derivatives; C = sum_r w_r row_r
  double wr[6], dwr[6][3];
  table_weight_derivatives(s.eps, wr, dwr);
  J3 c3[4];
  for (int col = 0; col < 4; ++col) {
    c3[col] = J3(0.0);
    for (int r = 0; r < 6; ++r) {
      c3[col].a += wr[r] * p[4 * r + col];
      for (int k = 0; k < 3; ++k) c3[col].v[k] += dwr[r][k] * p[4 * r + col];
    }
  }
  // C(eps) with d/deps (slots 0..2) and d/dc (slots 3..6); S+ through s = C eps
  J7 c[4], ej[3];
  for (int k = 0; k < 4; ++k) {
    c[k] = J7(c3[k].a);
    for (int i = 0; i < 3; ++i) c[k].v[i] = c3[k].v[i];
    c[k].v[3 + k] = 1.0;
  }
  for (int k = 0; k < 3; ++k) ej[k] = J7(s.eps[k], k);
  const J7 s00 = c[0] * ej[0] + c[1] * ej[1], s11 = c[1] * ej[0] + c[2] * ej[1], s01 = 0.5 * c[3] * ej[2];
  J7 P[2][2];
  positive_part(s00, s01, s11, P);
  // q = A [ el^T C ew + sum_c sum_ab P_ab dFl[c][a] dFw[c][b] ]
  double G[2][2] = {{0, 0}, {0, 0}};
  for (int cc = 0; cc < 3; ++cc)
    for (int a = 0; a < 2; ++a)
      for (int b = 0; b < 2; ++b) G[a][b] += dFl[cc][a] * dFw[cc][b];
  const J7 q = s.A * (c[0] * (el[0] * ew[0]) + c[1] * (el[0] * ew[1] + el[1] * ew[0]) + c[2] * (el[1] * ew[1]) +
                      c[3] * (el[2] * ew[2]) + P[0][0] * G[0][0] + P[0][1] * G[0][1] + P[1][0] * G[1][0] +
                      P[1][1] * G[1][1]);
  // through C(eps) and S+(eps)
  const double qe[3] = {scale * q.v[0], scale * q.v[1], scale * q.v[2]};
  strain_transpose(s.f, s.B, qe, ge);
  // through the strain derivatives el(x), ew(x) with C frozen: u = A C ew, t = A C el
  const double cv[4] = {c3[0].a, c3[1].a, c3[2].a, c3[3].a};
  const double u[3] = {s.A * (cv[0] * ew[0] + cv[1] * ew[1]), s.A * (cv[1] * ew[0] + cv[2] * ew[1]), s.A * cv[3] * ew[2]};
  const double t[3] = {s.A * (cv[0] * el[0] + cv[1] * el[1]), s.A * (cv[1] * el[0] + cv[2] * el[1]), s.A * cv[3] * el[2]};
  for (int cc = 0; cc < 3; ++cc) {
    const double d0 = u[0] * dFl[cc][0] + 0.5 * u[2] * dFl[cc][1] + t[0] * dFw[cc][0] + 0.5 * t[2] * dFw[cc][1];
    const double d1 = u[1] * dFl[cc][1] + 0.5 * u[2] * dFl[cc][0] + t[1] * dFw[cc][1] + 0.5 * t[2] * dFw[cc][0];
    for (int vv = 0; vv < 3; ++vv) ge[3 * vv + cc] += scale * (d0 * s.B[vv][0] + d1 * s.B[vv][1]);
  }
  // parameters: dq/dp[4r+col] = dq/dc_col w_r(eps)
  for (int r = 0; r < 6; ++r)
    for (int col = 0; col < 4; ++col) gp[4 * r + col] += scale * q.v[3 + col] * wr[r];
  if (Kl) {  // K lambda = J_eps^T (A C el) + A (S+ (x) I3) dF_lambda
    const double y[3] = {kscale * t[0], kscale * t[1], kscale * t[2]};
    for (int j = 0; j < 9; ++j) Kl[j] += s.Je[0][j] * y[0] + s.Je[1][j] * y[1] + s.Je[2][j] * y[2];
    for (int cc = 0; cc < 3; ++cc) {
      const double t0 = kscale * s.A * (P[0][0].a * dFl[cc][0] + P[0][1].a * dFl[cc][1]);
      const double t1 = kscale * s.A * (P[1][0].a * dFl[cc][0] + P[1][1].a * dFl[cc][1]);
      for (int vv = 0; vv < 3; ++vv) Kl[3 * vv + cc] += s.B[vv][0] * t0 + s.B[vv][1] * t1;
    }
  }
}

bool StretchTerm::add_step_system(const Eigen::VectorXd& x, const Eigen::VectorXd& p, const Eigen::VectorXd& v,
                                  double scale, Eigen::VectorXd& values, Eigen::VectorXd& Kv,
                                  Eigen::VectorXd& g) const {
  const double* nodes = shared_nodes(p);
  const RestScale rs = rest_scale(p);
  Local s;
  double K[81], ve[9], kv[9];
  for (int e = 0; e < num_elements(); ++e) {
    local_state(e, x, rs, s);
    const double* pe = p.data() + parameter_offset(e);
    // gradient
    double W, dW[3], d2W[3][3];
    strain_energy_derivatives(s.eps, pe, nodes, 1, W, dW, d2W);
    const double y[3] = {s.A * dW[0], s.A * dW[1], s.A * dW[2]};
    double ge[9] = {0};
    strain_transpose(s.f, s.B, y, ge);
    scatter_vector(e, ge, 1.0, g);
    // step matrix (as add_step_matrix) and K v
    element_step_matrix(s, pe, K);
    scatter_matrix(e, K, scale, values);
    gather(e, v, ve);
    for (int i = 0; i < 9; ++i) {
      double t = 0;
      for (int j = 0; j < 9; ++j) t += K[i * 9 + j] * ve[j];
      kv[i] = t;
    }
    scatter_vector(e, kv, scale, Kv);
  }
  return true;
}

// The rest scaling's parameter derivatives. The scaling enters a face only through F' = F diag(1 / a_u, 1 / a_v)
// (F, and the directional dF along lambda and w, unscaled and fixed) and A' = a_u a_v A, so jets in (a_u, a_v)
// through the same expressions as the kernels above give them exactly: the strains and their directional
// derivatives, with W's closed-form derivatives for E and lambda . grad E, and q = lambda^T K w in its closed form A' [el^T C ew + S+ : sum_c dFl_c dFw_c^T]
// (as step_matrix_derivative_element). Then the chain rule to the parameters, a_u = 1 - sum_k weft_k q_k,
// a_v = 1 - sum_k warp_k q_k. Only models with a rest scaling pay for it.
void StretchTerm::add_rest_scaling_derivatives(const Eigen::VectorXd& x, const Eigen::VectorXd& p,
                                               const Eigen::VectorXd* lambda, const Eigen::VectorXd* w, double cE,
                                               double cG, double cK, Eigen::VectorXd& gp) const {
  using A2 = Jet<double, 2>;  // d/d(a_u, a_v)
  const double* nodes = shared_nodes(p);
  double su, sv;
  rest_.strains(p, su, sv);
  const A2 au(1.0 - su, 0), av(1.0 - sv, 1);
  const A2 inv[2] = {1.0 / au, 1.0 / av};
  const A2 area_factor = au * av;
  double acc[2] = {0, 0};  // d/da_u, d/da_v of cE E + cG lambda . grad E + cK lambda^T K w
  double xe[9], le[9] = {0}, we[9] = {0}, f[3][2], dFl[3][2], dFw[3][2];
  for (int e = 0; e < num_elements(); ++e) {
    gather(e, x, xe);
    if (lambda) gather(e, *lambda, le);
    if (w) gather(e, *w, we);
    const double* Di = dm_inv_[e].data();
    deformation_gradient_of(xe, Di, f);
    deformation_gradient_of(le, Di, dFl);  // linear: Ds(lambda) Dm^-1
    deformation_gradient_of(we, Di, dFw);
    A2 fs[3][2], dl[3][2], dw[3][2];
    for (int c = 0; c < 3; ++c)
      for (int a = 0; a < 2; ++a) {
        fs[c][a] = f[c][a] * inv[a];
        dl[c][a] = dFl[c][a] * inv[a];
        dw[c][a] = dFw[c][a] * inv[a];
      }
    A2 eps[3], el[3] = {A2(0.0), A2(0.0), A2(0.0)}, ew[3] = {A2(0.0), A2(0.0), A2(0.0)};
    strain_of(fs, eps);
    for (int c = 0; c < 3; ++c) {
      el[0] += fs[c][0] * dl[c][0];
      el[1] += fs[c][1] * dl[c][1];
      el[2] += 0.5 * (fs[c][0] * dl[c][1] + fs[c][1] * dl[c][0]);
      ew[0] += fs[c][0] * dw[c][0];
      ew[1] += fs[c][1] * dw[c][1];
      ew[2] += 0.5 * (fs[c][0] * dw[c][1] + fs[c][1] * dw[c][0]);
    }
    const A2 A = area_[e] * area_factor;
    const double* pe = p.data() + parameter_offset(e);
    if (cE != 0.0 || cG != 0.0) {
      // E = A' W(eps'), lambda . grad E = A' dW(eps') . el': their a-derivatives from W's closed-form derivatives
      const double ev[3] = {eps[0].a, eps[1].a, eps[2].a};
      double W, dW[3], d2W[3][3];
      strain_energy_derivatives(ev, pe, nodes, 2, W, dW, d2W);
      for (int k = 0; k < 2; ++k) {
        double dE = A.v[k] * W, dG = 0;
        for (int i = 0; i < 3; ++i) {
          dE += A.a * dW[i] * eps[i].v[k];
          double h = 0;
          for (int j = 0; j < 3; ++j) h += d2W[i][j] * eps[j].v[k];
          dG += A.v[k] * dW[i] * el[i].a + A.a * (h * el[i].a + dW[i] * el[i].v[k]);
        }
        acc[k] += cE * dE + cG * dG;
      }
    }
    if (cK != 0.0) {
      A2 c[4];
      stiffness(eps, pe, c);
      const A2 s00 = c[0] * eps[0] + c[1] * eps[1], s11 = c[1] * eps[0] + c[2] * eps[1], s01 = 0.5 * c[3] * eps[2];
      A2 P[2][2];
      positive_part(s00, s01, s11, P);
      A2 geometric(0.0);
      for (int cc = 0; cc < 3; ++cc)
        for (int a = 0; a < 2; ++a)
          for (int b = 0; b < 2; ++b) geometric += P[a][b] * (dl[cc][a] * dw[cc][b]);
      const A2 q = A * (c[0] * (el[0] * ew[0]) + c[1] * (el[0] * ew[1] + el[1] * ew[0]) + c[2] * (el[1] * ew[1]) +
                        c[3] * (el[2] * ew[2]) + geometric);
      for (int k = 0; k < 2; ++k) acc[k] += cK * q.v[k];
    }
  }
  for (size_t k = 0; k < rest_.indices.size(); ++k)
    gp[rest_.indices[k]] -= rest_.weft[k] * acc[0] + rest_.warp[k] * acc[1];
}

}  // namespace drapelab
