#include "physics/bend.hpp"

#include <cmath>

#include "util/error.hpp"
#include "util/psd_projection.hpp"

namespace drapelab {

BendTerm::BendTerm(const TriangleMesh& mesh, const std::vector<BendingEdge>& edges, int parameter_offset, bool shared,
                   EnergyModulation modulation, RestAngles rest, CurvatureFactor curvature)
    : offset_(parameter_offset),
      shared_(shared),
      modulation_(std::move(modulation)),
      rest_(std::move(rest)),
      curvature_(std::move(curvature)) {
  if (curvature_.active() && !(curvature_.start > 0 && curvature_.full > curvature_.start))
    throw InputError("bend: a curvature factor needs 0 < start < full");
  if (curvature_.active()) curvature_log_span_ = std::log(curvature_.full / curvature_.start);
  for (const auto& c : modulation_.coefficients)
    if (c.size() != edges.size()) throw InputError("bend: a modulation needs one coefficient per bending edge");
  for (const auto& c : rest_.coefficients)
    if (c.size() != edges.size()) throw InputError("bend: a rest-angle change needs one coefficient per bending edge");
  const Eigen::VectorXd areas = rest_areas(mesh);
  for (size_t i = 0; i < edges.size(); ++i) {
    const BendingEdge& be = edges[i];
    verts_.push_back({be.a, be.b, be.c, be.d});
    const Eigen::Vector2d du = pattern_edge(mesh, be);
    const double L = du.norm();
    if (!(L > 0)) throw InputError("bend: edge " + std::to_string(i) + " has zero rest length");
    rest_length_.push_back(L);
    height_sum_.push_back(2.0 * (std::abs(areas[be.face0]) + std::abs(areas[be.face1])) / L);
    rest_angle_.push_back(0.0);  // flat rest shape; rest curvature is an optional effect
    const double beta = std::atan2(std::abs(du.y()), std::abs(du.x()));  // [0, pi/2] from weft
    bias_.push_back(beta);
    const double t = beta / (M_PI / 4.0);  // 0..2 over rows 0, 45, 90 degrees
    int r0 = static_cast<int>(t);
    if (r0 > 1) r0 = 1;
    const double f = t - r0;
    row_index_.push_back({r0, r0 + 1});
    row_weights_.push_back({1.0 - f, f});
  }
}

}  // namespace drapelab

// ---------------------------------------------------------------------------------------------------------
// Hand-written kernels (see bend.hpp). d = theta - theta_rest; E(d) and its d-derivatives by scalar jets.
// ---------------------------------------------------------------------------------------------------------

namespace drapelab {

namespace {
using D1 = Jet<double, 1>;

}  // namespace

void BendTerm::angle_derivatives(int e, double d, const double* p, AngleDerivatives& out) const {
  // G(d) = 2 (L / H) (1 - cos(d / 2)); t = |sin(d / 2)| / (H kBendSampleCurvature); f = smoothstep(t - k0)
  // (constant 1 beyond the table); k = K0 + f (K1 - K0); E = k G.
  const double h = 0.5 * d;
  const double s = std::sin(h), c = std::cos(h);
  const double LH = rest_length_[e] / height_sum_[e];
  const double G[4] = {2.0 * LH * (1.0 - c), LH * s, 0.5 * LH * c, -0.25 * LH * s};
  const double hsum = height_sum_[e];
  const double sg = s >= 0 ? 1.0 : -1.0;
  const double a = 1.0 / (hsum * kBendSampleCurvature);
  const double t = (s >= 0 ? s : -s) / hsum / kBendSampleCurvature;
  const double t1 = sg * a * 0.5 * c, t2 = -sg * a * 0.25 * s, t3 = -sg * a * 0.125 * c;
  int k0;
  double f[4] = {1.0, 0.0, 0.0, 0.0};
  if (!(t >= 4)) {
    k0 = static_cast<int>(t);
    if (k0 > 3) k0 = 3;
    const double u = t - static_cast<double>(k0);
    const double s1 = 6.0 * u * (1.0 - u), s2 = 6.0 - 12.0 * u;  // smoothstep' and '' in u
    f[0] = u * u * (3.0 - 2.0 * u);
    f[1] = s1 * t1;
    f[2] = s2 * t1 * t1 + s1 * t2;
    f[3] = -12.0 * t1 * t1 * t1 + 3.0 * s2 * t1 * t2 + s1 * t3;
  } else {
    k0 = 3;
  }
  const auto& rw = row_weights_[e];
  double K0 = 0, K1 = 0;
  out.count = 0;
  for (int r = 0; r < 2; ++r) {
    if (rw[r] == 0.0) continue;
    const int row = row_index_[e][r];
    K0 += rw[r] * p[5 * row + k0];
    K1 += rw[r] * p[5 * row + k0 + 1];
    // phi for (1 - f) G and f G
    const double fG[3] = {f[0] * G[0], f[1] * G[0] + f[0] * G[1], f[2] * G[0] + 2.0 * f[1] * G[1] + f[0] * G[2]};
    out.index[out.count] = 5 * row + k0;
    for (int n = 0; n < 3; ++n) out.phi[out.count][n] = rw[r] * (G[n] - fG[n]);
    ++out.count;
    out.index[out.count] = 5 * row + k0 + 1;
    for (int n = 0; n < 3; ++n) out.phi[out.count][n] = rw[r] * fG[n];
    ++out.count;
  }
  const double dK = K1 - K0;
  const double k[4] = {K0 + f[0] * dK, f[1] * dK, f[2] * dK, f[3] * dK};
  out.E[0] = k[0] * G[0];
  out.E[1] = k[1] * G[0] + k[0] * G[1];
  out.E[2] = k[2] * G[0] + 2.0 * k[1] * G[1] + k[0] * G[2];
  out.E[3] = k[3] * G[0] + 3.0 * k[2] * G[1] + 3.0 * k[1] * G[2] + k[0] * G[3];
}

void BendTerm::apply_curvature_factor(int e, double d, const Eigen::VectorXd& p, AngleDerivatives& ad) const {
  // s(alpha(d)) and its d-derivatives: alpha = |sin(d / 2)| / H, r = ln(alpha / start) / ln(full / start),
  // s = smoothstep(r) (a ramp in log curvature: alpha s'(alpha) <= 1.5 / ln(full / start), which bounds how fast
  // the factor can fall, physics/base_term_changes.hpp).
  const double q = curvature_.log_factor(p);
  const double h = 0.5 * d;
  const double sn = std::sin(h), cs = std::cos(h);
  const double H = height_sum_[e];
  const double sg = sn >= 0 ? 1.0 : -1.0;
  const double alpha = sg * sn / H;
  const double ell = curvature_log_span_;
  double S[4] = {0.0, 0.0, 0.0, 0.0};
  if (alpha >= curvature_.full) {
    S[0] = 1.0;
  } else if (alpha > curvature_.start) {
    const double r = std::log(alpha / curvature_.start) / ell;
    // alpha's d-derivatives over alpha, then r's
    const double a1 = sg * 0.5 * cs / H / alpha, a2 = -sg * 0.25 * sn / H / alpha, a3 = -sg * 0.125 * cs / H / alpha;
    const double t1 = a1 / ell, t2 = (a2 - a1 * a1) / ell, t3 = (a3 - 3.0 * a1 * a2 + 2.0 * a1 * a1 * a1) / ell;
    const double s1 = 6.0 * r * (1.0 - r), s2 = 6.0 - 12.0 * r;
    S[0] = r * r * (3.0 - 2.0 * r);
    S[1] = s1 * t1;
    S[2] = s2 * t1 * t1 + s1 * t2;
    S[3] = -12.0 * t1 * t1 * t1 + 3.0 * s2 * t1 * t2 + s1 * t3;
  }
  // M = exp(u), u = q S: M' = u' M, M'' = (u'' + u'^2) M, M''' = (u''' + 3 u' u'' + u'^3) M; d/dq of each with
  // du^(k)/dq = S^(k).
  const double M0 = std::exp(q * S[0]);
  const double u1 = q * S[1], u2 = q * S[2], u3 = q * S[3];
  const double M[4] = {M0, u1 * M0, (u2 + u1 * u1) * M0, (u3 + 3.0 * u1 * u2 + u1 * u1 * u1) * M0};
  const double Mq[3] = {S[0] * M0, (S[1] + u1 * S[0]) * M0, (S[2] + 2.0 * u1 * S[1] + (u2 + u1 * u1) * S[0]) * M0};
  const double* E = ad.E;
  ad.dq[0] = Mq[0] * E[0];
  ad.dq[1] = Mq[1] * E[0] + Mq[0] * E[1];
  ad.dq[2] = Mq[2] * E[0] + 2.0 * Mq[1] * E[1] + Mq[0] * E[2];
  const double En[4] = {M[0] * E[0], M[1] * E[0] + M[0] * E[1], M[2] * E[0] + 2.0 * M[1] * E[1] + M[0] * E[2],
                        M[3] * E[0] + 3.0 * M[2] * E[1] + 3.0 * M[1] * E[2] + M[0] * E[3]};
  for (int n = 0; n < 4; ++n) ad.E[n] = En[n];
  for (int j = 0; j < ad.count; ++j) {
    const double* f = ad.phi[j];
    const double fn[3] = {M[0] * f[0], M[1] * f[0] + M[0] * f[1], M[2] * f[0] + 2.0 * M[1] * f[1] + M[0] * f[2]};
    for (int n = 0; n < 3; ++n) ad.phi[j][n] = fn[n];
  }
}

void BendTerm::modulated_angle_derivatives(int e, double d, const Eigen::VectorXd& p, AngleDerivatives& out,
                                           double& m) const {
  angle_derivatives(e, d, p.data() + parameter_offset(e), out);
  if (curvature_.active()) apply_curvature_factor(e, d, p, out);
  m = 1.0;
  if (!modulation_.active()) return;
  m = std::exp(modulation_.log_multiplier(e, p));
  for (int n = 0; n < 4; ++n) out.E[n] *= m;
  for (int j = 0; j < out.count; ++j)
    for (int n = 0; n < 3; ++n) out.phi[j][n] *= m;
  if (curvature_.active())
    for (int n = 0; n < 3; ++n) out.dq[n] *= m;
}

double BendTerm::energy(const Eigen::VectorXd& x, const Eigen::VectorXd& p) const {
  if (!modulation_.active() && !rest_.active() && !curvature_.active()) return Reference::energy(x, p);
  double E = 0, xe[12];
  for (int e = 0; e < num_elements(); ++e) {
    gather_local(e, x, xe);
    if (curvature_.active()) {
      AngleDerivatives ad;
      double m;
      modulated_angle_derivatives(e, dihedral_angle(xe) - rest_angle(e, p), p, ad, m);
      E += ad.E[0];
      continue;
    }
    const double Ee = energy_of_angle(e, dihedral_angle(xe) - rest_angle(e, p), p.data() + parameter_offset(e));
    E += modulation_.active() ? std::exp(modulation_.log_multiplier(e, p)) * Ee : Ee;
  }
  return E;
}

void BendTerm::add_gradient(const Eigen::VectorXd& x, const Eigen::VectorXd& p, Eigen::VectorXd& g) const {
  double xe[12], gt[12];
  for (int e = 0; e < num_elements(); ++e) {
    gather_local(e, x, xe);
    const double d = dihedral_angle(xe) - rest_angle(e, p);
    AngleDerivatives ad;
    double m;
    modulated_angle_derivatives(e, d, p, ad, m);
    dihedral_gradient(xe, gt);
    for (int i = 0; i < 12; ++i) gt[i] *= ad.E[1];
    scatter_vector(e, gt, 1.0, g);
  }
}

void BendTerm::add_step_matrix(const Eigen::VectorXd& x, const Eigen::VectorXd& p, double scale,
                               Eigen::VectorXd& values) const {
  double xe[12], gt[12], K[144];
  for (int e = 0; e < num_elements(); ++e) {
    gather_local(e, x, xe);
    AngleDerivatives ad;
    double m;
    modulated_angle_derivatives(e, dihedral_angle(xe) - rest_angle(e, p), p, ad, m);
    const double S = ad.E[2] > 0 ? ad.E[2] : 0.0;  // as element_gauss_newton
    dihedral_gradient(xe, gt);
    for (int i = 0; i < 12; ++i) {
      const double si = S * gt[i];
      for (int j = 0; j < 12; ++j) K[i * 12 + j] = si * gt[j];
    }
    scatter_matrix(e, K, scale, values);
  }
}

void BendTerm::add_hessian(const Eigen::VectorXd& x, const Eigen::VectorXd& p, double scale,
                           Eigen::VectorXd& values) const {
  add_element_hessians(x, p, scale, values, false);
}

void BendTerm::add_projected_hessian(const Eigen::VectorXd& x, const Eigen::VectorXd& p, double scale,
                                     Eigen::VectorXd& values) const {
  add_element_hessians(x, p, scale, values, true);
}

void BendTerm::add_element_hessians(const Eigen::VectorXd& x, const Eigen::VectorXd& p, double scale,
                                    Eigen::VectorXd& values, bool project) const {
  using G = Jet<double, 12>;
  double xe[12], H[144];
  G xj[12], gj[12];
  for (int e = 0; e < num_elements(); ++e) {
    gather_local(e, x, xe);
    const double d = dihedral_angle(xe) - rest_angle(e, p);
    AngleDerivatives ad;
    double m;
    modulated_angle_derivatives(e, d, p, ad, m);
    const double E1 = ad.E[1], E2 = ad.E[2];
    for (int i = 0; i < 12; ++i) xj[i] = G(xe[i], i);
    dihedral_gradient(xj, gj);
    for (int i = 0; i < 12; ++i)
      for (int j = 0; j < 12; ++j) H[i * 12 + j] = E2 * gj[i].a * gj[j].a + E1 * gj[i].v[j];
    if (project) project_psd<12>(H);
    scatter_matrix(e, H, scale, values);
  }
}

void BendTerm::add_hessian_product(const Eigen::VectorXd& x, const Eigen::VectorXd& p, const Eigen::VectorXd& dir,
                                   Eigen::VectorXd& out) const {
  double xe[12], Hd[12];
  D1 xj[12], gj[12];
  for (int e = 0; e < num_elements(); ++e) {
    gather_local(e, x, xe);
    const auto& v = verts_[e];
    for (int i = 0; i < 12; ++i) {
      xj[i] = D1(xe[i]);
      xj[i].v[0] = dir[3 * v[i / 3] + i % 3];
    }
    const double d = dihedral_angle(xe) - rest_angle(e, p);
    AngleDerivatives ad;
    double m;
    modulated_angle_derivatives(e, d, p, ad, m);
    const double E1 = ad.E[1], E2 = ad.E[2];
    dihedral_gradient(xj, gj);
    double gd = 0;
    for (int i = 0; i < 12; ++i) gd += gj[i].a * xj[i].v[0];
    for (int i = 0; i < 12; ++i) Hd[i] = E2 * gj[i].a * gd + E1 * gj[i].v[0];
    scatter_vector(e, Hd, 1.0, out);
  }
}

void BendTerm::add_energy_parameter_gradient(const Eigen::VectorXd& x, const Eigen::VectorXd& p,
                                             Eigen::VectorXd& gp) const {
  double xe[12], phi[4];
  int index[4];
  for (int e = 0; e < num_elements(); ++e) {
    gather_local(e, x, xe);
    const int off = parameter_offset(e);
    const double d = dihedral_angle(xe) - rest_angle(e, p);
    if (curvature_.active()) {  // everything from the angle derivatives, which carry M(d) and m
      AngleDerivatives ad;
      double m;
      modulated_angle_derivatives(e, d, p, ad, m);
      for (int j = 0; j < ad.count; ++j) gp[off + ad.index[j]] += ad.phi[j][0];
      if (rest_.active()) add_rest_gradient(e, ad.E[1], 1.0, gp);
      if (modulation_.active()) add_modulation_gradient(e, ad.E[0], 1.0, gp);
      add_curvature_gradient(ad.dq[0], 1.0, gp);
      continue;
    }
    const int n = table_coefficients(e, d, index, phi);
    if (rest_.active()) {  // dE/dq = -a E'(d) (times m)
      AngleDerivatives ad;
      double m;
      modulated_angle_derivatives(e, d, p, ad, m);
      add_rest_gradient(e, ad.E[1], 1.0, gp);
    }
    if (!modulation_.active()) {
      for (int j = 0; j < n; ++j) gp[off + index[j]] += phi[j];
      continue;
    }
    const double m = std::exp(modulation_.log_multiplier(e, p));
    for (int j = 0; j < n; ++j) gp[off + index[j]] += m * phi[j];
    add_modulation_gradient(e, m * energy_of_angle(e, d, p.data() + off), 1.0, gp);
  }
}

void BendTerm::add_gradient_parameter_product(const Eigen::VectorXd& x, const Eigen::VectorXd& p,
                                              const Eigen::VectorXd& lambda, double scale, Eigen::VectorXd& gp) const {
  double xe[12], gt[12];
  D1 phi[4];
  int index[4];
  for (int e = 0; e < num_elements(); ++e) {
    gather_local(e, x, xe);
    const auto& v = verts_[e];
    const int off = parameter_offset(e);
    const double d = dihedral_angle(xe) - rest_angle(e, p);
    dihedral_gradient(xe, gt);
    double gl = 0;
    for (int i = 0; i < 12; ++i) gl += gt[i] * lambda[3 * v[i / 3] + i % 3];
    if (curvature_.active()) {  // lambda . grad E = E'(d) gl, E' from the angle derivatives (M(d) and m in them)
      AngleDerivatives ad;
      double m;
      modulated_angle_derivatives(e, d, p, ad, m);
      for (int j = 0; j < ad.count; ++j) gp[off + ad.index[j]] += scale * gl * ad.phi[j][1];
      if (rest_.active()) add_rest_gradient(e, ad.E[2] * gl, scale, gp);
      if (modulation_.active()) add_modulation_gradient(e, ad.E[1] * gl, scale, gp);
      add_curvature_gradient(ad.dq[1] * gl, scale, gp);
      continue;
    }
    const int n = table_coefficients(e, D1(d, 0), index, phi);
    if (rest_.active()) {  // lambda . grad E = E'(d) gl: its q-derivative -a E''(d) gl (times m)
      AngleDerivatives ad;
      double m;
      modulated_angle_derivatives(e, d, p, ad, m);
      add_rest_gradient(e, ad.E[2] * gl, scale, gp);
    }
    if (!modulation_.active()) {
      for (int j = 0; j < n; ++j) gp[off + index[j]] += scale * gl * phi[j].v[0];
      continue;
    }
    // E = m sum_j phi_j p_j: the table part times m, and dm/dq E'(d) (lambda . grad theta)
    const double m = std::exp(modulation_.log_multiplier(e, p));
    double dE = 0;
    for (int j = 0; j < n; ++j) {
      gp[off + index[j]] += scale * gl * m * phi[j].v[0];
      dE += phi[j].v[0] * p[off + index[j]];
    }
    add_modulation_gradient(e, m * dE * gl, scale, gp);
  }
}

// Element state along two directions: local positions xe, jets xj seeded with (lambda, w), gj = d theta/dx
// as jets (.a: grad theta, .v[0]: Hess theta lambda, .v[1]: Hess theta w), gl = grad theta . lambda,
// gw = grad theta . w.
void BendTerm::seed_directions(int e, const Eigen::VectorXd& x, const Eigen::VectorXd& lambda,
                               const Eigen::VectorXd& w, double* xe, Jet<double, 2>* xj, Jet<double, 2>* gj,
                               double& gl, double& gw) const {
  gather_local(e, x, xe);
  const auto& v = verts_[e];
  for (int i = 0; i < 12; ++i) {
    const int dof = 3 * v[i / 3] + i % 3;
    xj[i] = Jet<double, 2>(xe[i]);
    xj[i].v[0] = lambda[dof];
    xj[i].v[1] = w[dof];
  }
  dihedral_gradient(xj, gj);
  gl = 0;
  gw = 0;
  for (int i = 0; i < 12; ++i) {
    gl += gj[i].a * xj[i].v[0];
    gw += gj[i].a * xj[i].v[1];
  }
}

void BendTerm::add_step_matrix_derivatives(const Eigen::VectorXd& x, const Eigen::VectorXd& p,
                                           const Eigen::VectorXd& lambda, const Eigen::VectorXd& w, double scale,
                                           Eigen::VectorXd& gx, Eigen::VectorXd& gp) const {
  using T2 = Jet<double, 2>;
  double xe[12], ge[12];
  T2 xj[12], gj[12];
  for (int e = 0; e < num_elements(); ++e) {
    const int off = parameter_offset(e);
    double gl, gw;
    seed_directions(e, x, lambda, w, xe, xj, gj, gl, gw);
    const double d = dihedral_angle(xe) - rest_angle(e, p);
    // S = max(E'', 0): its angle derivative E''' and its table derivatives dE''/dp where E'' > 0.
    AngleDerivatives ad;
    double m;
    modulated_angle_derivatives(e, d, p, ad, m);
    const double E2 = ad.E[2];
    if (!(E2 > 0)) continue;  // S = 0 with zero derivatives
    const double E3v = ad.E[3];
    for (int i = 0; i < 12; ++i) ge[i] = E3v * gj[i].a * gl * gw + E2 * (gj[i].v[0] * gw + gl * gj[i].v[1]);
    scatter_vector(e, ge, scale, gx);
    for (int j = 0; j < ad.count; ++j) gp[off + ad.index[j]] += scale * gl * gw * ad.phi[j][2];
    if (modulation_.active()) add_modulation_gradient(e, gl * gw * E2, scale, gp);
    if (rest_.active()) add_rest_gradient(e, E3v * gl * gw, scale, gp);
    if (curvature_.active()) add_curvature_gradient(ad.dq[2] * gl * gw, scale, gp);
  }
}

bool BendTerm::add_step_matrix_product(const Eigen::VectorXd& x, const Eigen::VectorXd& p, const Eigen::VectorXd& dir,
                                       double scale, Eigen::VectorXd& out) const {
  double xe[12], gt[12];
  for (int e = 0; e < num_elements(); ++e) {
    gather_local(e, x, xe);
    AngleDerivatives ad;
    double m;
    modulated_angle_derivatives(e, dihedral_angle(xe) - rest_angle(e, p), p, ad, m);
    const double S = ad.E[2] > 0 ? ad.E[2] : 0.0;  // as element_gauss_newton
    if (!(S != 0.0)) continue;
    const auto& v = verts_[e];
    dihedral_gradient(xe, gt);
    double gd = 0;
    for (int i = 0; i < 12; ++i) gd += gt[i] * dir[3 * v[i / 3] + i % 3];
    const double sgd = S * gd;
    for (int i = 0; i < 12; ++i) gt[i] *= sgd;
    scatter_vector(e, gt, scale, out);
  }
  return true;
}

bool BendTerm::add_step_adjoint(const Eigen::VectorXd& x, const Eigen::VectorXd& p, const Eigen::VectorXd& lambda,
                                const Eigen::VectorXd& w, double h, Eigen::VectorXd& gx, Eigen::VectorXd& gv,
                                Eigen::VectorXd& gp) const {
  using T2 = Jet<double, 2>;
  double xe[12], ge[12], kl[12];
  T2 xj[12], gj[12];
  const double h2 = h * h;
  for (int e = 0; e < num_elements(); ++e) {
    const int off = parameter_offset(e);
    double gl, gw;
    seed_directions(e, x, lambda, w, xe, xj, gj, gl, gw);
    const double d = dihedral_angle(xe) - rest_angle(e, p);
    AngleDerivatives ad;
    double m;
    modulated_angle_derivatives(e, d, p, ad, m);
    const double E1 = ad.E[1], E2 = ad.E[2], E3 = ad.E[3];
    const int n = ad.count;
    // -h Hess E lambda
    for (int i = 0; i < 12; ++i) ge[i] = -h * (E2 * gj[i].a * gl + E1 * gj[i].v[0]);
    // -h d(lambda . grad E)/dp
    for (int j = 0; j < n; ++j) gp[off + ad.index[j]] += -h * gl * ad.phi[j][1];
    if (modulation_.active()) add_modulation_gradient(e, gl * E1, -h, gp);
    if (rest_.active()) add_rest_gradient(e, E2 * gl, -h, gp);
    if (curvature_.active()) add_curvature_gradient(ad.dq[1] * gl, -h, gp);
    if (E2 > 0) {  // S = E'' (else S = 0 with zero derivatives)
      for (int i = 0; i < 12; ++i) {
        ge[i] += -h2 * (E3 * gj[i].a * gl * gw + E2 * (gj[i].v[0] * gw + gl * gj[i].v[1]));
        kl[i] = -h2 * E2 * gl * gj[i].a;
      }
      for (int j = 0; j < n; ++j) gp[off + ad.index[j]] += -h2 * gl * gw * ad.phi[j][2];
      if (modulation_.active()) add_modulation_gradient(e, gl * gw * E2, -h2, gp);
      if (rest_.active()) add_rest_gradient(e, E3 * gl * gw, -h2, gp);
      if (curvature_.active()) add_curvature_gradient(ad.dq[2] * gl * gw, -h2, gp);
      scatter_vector(e, kl, 1.0, gv);
    }
    scatter_vector(e, ge, 1.0, gx);
  }
  return true;
}

bool BendTerm::add_step_system(const Eigen::VectorXd& x, const Eigen::VectorXd& p, const Eigen::VectorXd& v,
                               double scale, Eigen::VectorXd& values, Eigen::VectorXd& Kv, Eigen::VectorXd& g) const {
  double xe[12], gt[12], ge[12], K[144];
  for (int e = 0; e < num_elements(); ++e) {
    gather_local(e, x, xe);
    const auto& vv = verts_[e];
    const double d = dihedral_angle(xe) - rest_angle(e, p);
    AngleDerivatives ad;
    double m;
    modulated_angle_derivatives(e, d, p, ad, m);
    const double E1 = ad.E[1], E2 = ad.E[2];
    const double S = E2 > 0 ? E2 : 0.0;
    dihedral_gradient(xe, gt);
    for (int i = 0; i < 12; ++i) ge[i] = E1 * gt[i];
    scatter_vector(e, ge, 1.0, g);
    double gv = 0;
    for (int i = 0; i < 12; ++i) gv += gt[i] * v[3 * vv[i / 3] + i % 3];
    for (int i = 0; i < 12; ++i) {
      const double si = S * gt[i];
      for (int j = 0; j < 12; ++j) K[i * 12 + j] = si * gt[j];
      ge[i] = si * gv;
    }
    scatter_matrix(e, K, scale, values);
    scatter_vector(e, ge, scale, Kv);
  }
  return true;
}

}  // namespace drapelab
