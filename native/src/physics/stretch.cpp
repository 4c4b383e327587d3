#include "physics/stretch.hpp"

#include <Eigen/Eigenvalues>
#include <cmath>

#include "util/error.hpp"

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

StretchTerm::StretchTerm(const TriangleMesh& mesh, int parameter_offset, bool shared)
    : offset_(parameter_offset), shared_(shared) {
  const int nf = mesh.num_faces();
  faces_.resize(nf);
  dm_inv_.resize(nf);
  area_.resize(nf);
  for (int f = 0; f < nf; ++f) {
    faces_[f] = {mesh.faces(f, 0), mesh.faces(f, 1), mesh.faces(f, 2)};
    const Eigen::Vector2d u0 = mesh.uv.row(faces_[f][0]).transpose();
    Eigen::Matrix2d Dm;
    Dm.col(0) = mesh.uv.row(faces_[f][1]).transpose() - u0;
    Dm.col(1) = mesh.uv.row(faces_[f][2]).transpose() - u0;
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

void StretchTerm::local_state(int e, const Eigen::VectorXd& x, Local& s) const {
  const auto& vv = faces_[e];
  double xe[9];
  for (int k = 0; k < 3; ++k) {
    s.v[k] = vv[k];
    for (int c = 0; c < 3; ++c) xe[3 * k + c] = x[3 * vv[k] + c];
  }
  const auto& Di = dm_inv_[e];
  for (int a = 0; a < 2; ++a) {
    s.B[1][a] = Di[a];
    s.B[2][a] = Di[2 + a];
    s.B[0][a] = -(Di[a] + Di[2 + a]);
  }
  deformation_gradient(e, xe, s.f);
  green_strain(e, xe, s.eps);
  for (int v = 0; v < 3; ++v)
    for (int c = 0; c < 3; ++c) {
      const int j = 3 * v + c;
      s.Je[0][j] = s.f[c][0] * s.B[v][0];
      s.Je[1][j] = s.f[c][1] * s.B[v][1];
      s.Je[2][j] = 0.5 * (s.f[c][0] * s.B[v][1] + s.f[c][1] * s.B[v][0]);
    }
  s.A = area_[e];
}

void StretchTerm::add_gradient(const Eigen::VectorXd& x, const Eigen::VectorXd& p, Eigen::VectorXd& g) const {
  Local s;
  for (int e = 0; e < num_elements(); ++e) {
    local_state(e, x, s);
    const J3 ej[3] = {J3(s.eps[0], 0), J3(s.eps[1], 1), J3(s.eps[2], 2)};
    const J3 W = strain_energy(ej, p.data() + parameter_offset(e));
    const double y[3] = {s.A * W.v[0], s.A * W.v[1], s.A * W.v[2]};
    double ge[9] = {0};
    strain_transpose(s.f, s.B, y, ge);
    scatter_vector(e, ge, 1.0, g);
  }
}

void StretchTerm::add_step_matrix(const Eigen::VectorXd& x, const Eigen::VectorXd& p, double scale,
                                  Eigen::VectorXd& values) const {
  Local s;
  double K[81];
  for (int e = 0; e < num_elements(); ++e) {
    local_state(e, x, s);
    double c[4];
    stiffness(s.eps, p.data() + parameter_offset(e), c);
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
    scatter_matrix(e, K, scale, values);
  }
}

void StretchTerm::add_hessian(const Eigen::VectorXd& x, const Eigen::VectorXd& p, double scale,
                              Eigen::VectorXd& values) const {
  using H1 = Jet<double, 3>;
  using H2 = Jet<H1, 3>;
  Local s;
  double H[81];
  for (int e = 0; e < num_elements(); ++e) {
    local_state(e, x, s);
    H2 ej[3];
    for (int k = 0; k < 3; ++k) {
      ej[k] = H2(H1(s.eps[k], k));
      ej[k].v[k] = H1(1.0);
    }
    const H2 W = strain_energy(ej, p.data() + parameter_offset(e));
    double M[3][9];
    for (int a = 0; a < 3; ++a)
      for (int j = 0; j < 9; ++j)
        M[a][j] = s.A * (W.v[a].v[0] * s.Je[0][j] + W.v[a].v[1] * s.Je[1][j] + W.v[a].v[2] * s.Je[2][j]);
    for (int i = 0; i < 9; ++i)
      for (int j = i; j < 9; ++j) H[i * 9 + j] = s.Je[0][i] * M[0][j] + s.Je[1][i] * M[1][j] + s.Je[2][i] * M[2][j];
    for (int i = 0; i < 9; ++i)
      for (int j = 0; j < i; ++j) H[i * 9 + j] = H[j * 9 + i];
    const double Y[2][2] = {{s.A * W.v[0].a, 0.5 * s.A * W.v[2].a}, {0.5 * s.A * W.v[2].a, s.A * W.v[1].a}};
    add_shape_block(s.B, Y, H);
    scatter_matrix(e, H, scale, values);
  }
}

void StretchTerm::add_hessian_product(const Eigen::VectorXd& x, const Eigen::VectorXd& p, const Eigen::VectorXd& dir,
                                      Eigen::VectorXd& out) const {
  using H1 = Jet<double, 1>;
  using H2 = Jet<H1, 3>;
  Local s;
  for (int e = 0; e < num_elements(); ++e) {
    local_state(e, x, s);
    double d[9];
    for (int k = 0; k < 3; ++k)
      for (int c = 0; c < 3; ++c) d[3 * k + c] = dir[3 * s.v[k] + c];
    H2 ej[3];
    for (int k = 0; k < 3; ++k) {
      double de = 0;
      for (int j = 0; j < 9; ++j) de += s.Je[k][j] * d[j];
      H1 inner(s.eps[k]);
      inner.v[0] = de;
      ej[k] = H2(inner);
      ej[k].v[k] = H1(1.0);
    }
    const H2 W = strain_energy(ej, p.data() + parameter_offset(e));
    double Hd[9] = {0};
    const double hy[3] = {s.A * W.v[0].v[0], s.A * W.v[1].v[0], s.A * W.v[2].v[0]};
    strain_transpose(s.f, s.B, hy, Hd);
    // (sum_ab Y_ab B_a B_b^T) (x) I3 d with Y from grad W
    const double Y[2][2] = {{s.A * W.v[0].a, 0.5 * s.A * W.v[2].a}, {0.5 * s.A * W.v[2].a, s.A * W.v[1].a}};
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

void StretchTerm::add_energy_parameter_gradient(const Eigen::VectorXd& x, const Eigen::VectorXd& /*p*/,
                                                Eigen::VectorXd& gp) const {
  Local s;
  double dW[24];
  for (int e = 0; e < num_elements(); ++e) {
    local_state(e, x, s);
    strain_energy_table_gradient(s.eps, dW);
    const int off = parameter_offset(e);
    for (int k = 0; k < 24; ++k) gp[off + k] += s.A * dW[k];
  }
}

void StretchTerm::add_gradient_parameter_product(const Eigen::VectorXd& x, const Eigen::VectorXd& /*p*/,
                                                 const Eigen::VectorXd& lambda, double scale,
                                                 Eigen::VectorXd& gp) const {
  using D1 = Jet<double, 1>;
  Local s;
  D1 dW[24];
  for (int e = 0; e < num_elements(); ++e) {
    local_state(e, x, s);
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
  Local s;
  for (int e = 0; e < num_elements(); ++e) {
    local_state(e, x, s);
    const int off = parameter_offset(e);
    Directional L, Wd;
    directional(s, lambda, L.dF, L.de);
    directional(s, w, Wd.dF, Wd.de);
    double ge[9] = {0};
    step_matrix_derivative_element(s, p.data() + off, L.dF, L.de, Wd.dF, Wd.de, scale, ge, gp.data() + off, 0.0, nullptr);
    scatter_vector(e, ge, 1.0, gx);
  }
}

bool StretchTerm::add_step_matrix_product(const Eigen::VectorXd& x, const Eigen::VectorXd& p, const Eigen::VectorXd& dir,
                                          double scale, Eigen::VectorXd& out) const {
  Local s;
  for (int e = 0; e < num_elements(); ++e) {
    local_state(e, x, s);
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
  using H1 = Jet<double, 1>;
  using H2 = Jet<H1, 3>;
  Local s;
  H1 dW[24];
  for (int e = 0; e < num_elements(); ++e) {
    local_state(e, x, s);
    const int off = parameter_offset(e);
    const double* pe = p.data() + off;
    Directional L, Wd;
    directional(s, lambda, L.dF, L.de);
    directional(s, w, Wd.dF, Wd.de);
    // Hessian-vector product: J_eps^T W_epseps (J_eps lambda) + (sum_ab Y_ab B_a B_b^T) (x) I3 lambda
    H2 ej[3];
    for (int k = 0; k < 3; ++k) {
      H1 inner(s.eps[k]);
      inner.v[0] = L.de[k];
      ej[k] = H2(inner);
      ej[k].v[k] = H1(1.0);
    }
    const H2 W = strain_energy(ej, pe);
    double ge[9] = {0};
    const double hy[3] = {-h * s.A * W.v[0].v[0], -h * s.A * W.v[1].v[0], -h * s.A * W.v[2].v[0]};
    strain_transpose(s.f, s.B, hy, ge);
    const double Y[2][2] = {{s.A * W.v[0].a, 0.5 * s.A * W.v[2].a}, {0.5 * s.A * W.v[2].a, s.A * W.v[1].a}};
    for (int cc = 0; cc < 3; ++cc) {
      const double t0 = -h * (Y[0][0] * L.dF[cc][0] + Y[0][1] * L.dF[cc][1]);
      const double t1 = -h * (Y[1][0] * L.dF[cc][0] + Y[1][1] * L.dF[cc][1]);
      for (int v = 0; v < 3; ++v) ge[3 * v + cc] += s.B[v][0] * t0 + s.B[v][1] * t1;
    }
    // d(lambda . grad E)/dp
    H1 el[3];
    for (int k = 0; k < 3; ++k) {
      el[k] = H1(s.eps[k]);
      el[k].v[0] = L.de[k];
    }
    strain_energy_table_gradient(el, dW);
    for (int k = 0; k < 24; ++k) gp[off + k] += -h * s.A * dW[k].v[0];
    // d(lambda^T K w)/d(x, p) and K lambda
    double Kl[9] = {0};
    step_matrix_derivative_element(s, pe, L.dF, L.de, Wd.dF, Wd.de, -h * h, ge, gp.data() + off, -h * h, Kl);
    scatter_vector(e, ge, 1.0, gx);
    scatter_vector(e, Kl, 1.0, gv);
  }
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
  const J3 ej3[3] = {J3(s.eps[0], 0), J3(s.eps[1], 1), J3(s.eps[2], 2)};
  J3 w3[6];
  table_weights(ej3, w3);
  J3 c3[4];
  for (int col = 0; col < 4; ++col) {
    c3[col] = J3(0.0);
    for (int r = 0; r < 6; ++r) c3[col] += w3[r] * p[4 * r + col];
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
    for (int col = 0; col < 4; ++col) gp[4 * r + col] += scale * q.v[3 + col] * w3[r].a;
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

}  // namespace drapelab
