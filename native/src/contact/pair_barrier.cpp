#include "contact/pair_barrier.hpp"

#include <Eigen/Core>
#include <cmath>
#include <limits>

#include "contact/barrier.hpp"
#include "contact/distance.hpp"
#include "util/jet.hpp"
#include "util/psd_projection.hpp"

namespace drapelab {

namespace {
template <class T>
T distance2_of(PairKind kind, int type, const T* x) {
  return kind == PairKind::kPointTriangle ? point_triangle_distance2(static_cast<PointTriangleType>(type), x)
                                          : edge_edge_distance2(static_cast<EdgeEdgeType>(type), x);
}
// b(d; dhat) / dhat^2 and its d-derivative, templated in dhat (for the parameter derivatives).
template <class T>
T barrier_in(double d, const T& dhat) {
  const T e = d - dhat;
  return -(e * e) * log_of(d / dhat) / (dhat * dhat);
}
template <class T>
T barrier_slope_in(double d, const T& dhat) {
  const T e = d - dhat;
  return (-2.0 * e * log_of(d / dhat) - e * e / d) / (dhat * dhat);
}
// b''(d; dhat) / dhat^2, templated in d and dhat (the Gauss-Newton matrix's derivatives).
template <class T>
T barrier_curvature_in(const T& d, const T& dhat) {
  const T e = d - dhat;
  return (-2.0 * log_of(d / dhat) - 4.0 * e / d + e * e / (d * d)) / (dhat * dhat);
}
}  // namespace

int pair_type(PairKind kind, const double* x) {
  const Eigen::Map<const Eigen::Vector3d> q0(x), q1(x + 3), q2(x + 6), q3(x + 9);
  return kind == PairKind::kPointTriangle ? static_cast<int>(point_triangle_type(q0, q1, q2, q3))
                                          : static_cast<int>(edge_edge_type(q0, q1, q2, q3));
}

double pair_distance2(PairKind kind, int type, const double* x) { return distance2_of(kind, type, x); }

namespace {
double plain_energy(PairKind kind, int type, const double* x, double dhat, double kappa) {
  const double d2 = distance2_of(kind, type, x);
  if (!(d2 > 0)) return std::numeric_limits<double>::infinity();
  const double d = std::sqrt(d2);
  if (d >= dhat) return 0.0;
  return kappa * barrier(d, dhat);
}

void plain_gradient(PairKind kind, int type, const double* x, double dhat, double kappa, double* g) {
  using J = Jet<double, 12>;
  J xs[12];
  for (int i = 0; i < 12; ++i) xs[i] = J(x[i], i);
  const J d2 = distance2_of(kind, type, xs);
  for (int i = 0; i < 12; ++i) g[i] = 0;
  const double d = std::sqrt(d2.a);
  if (!(d > 0) || d >= dhat) return;
  double b, db, d2b;
  barrier_derivatives(d, dhat, b, db, d2b);
  // grad d = grad d2 / (2 d)
  for (int i = 0; i < 12; ++i) g[i] = kappa * db * d2.v[i] / (2 * d);
}

void plain_hessian(PairKind kind, int type, const double* x, double dhat, double kappa, bool project,
                          double* H) {
  double d2, g2[12], H2[144];
  distance_gradient_hessian<12>([&](const auto* y) { return distance2_of(kind, type, y); }, x, d2, g2, H2);
  for (int k = 0; k < 144; ++k) H[k] = 0;
  const double d = std::sqrt(d2);
  if (!(d > 0) || d >= dhat) return;
  double b, db, d2b;
  barrier_derivatives(d, dhat, b, db, d2b);
  // d = sqrt(d2): grad d = g2 / (2d), Hess d = H2 / (2d) - g2 g2^T / (4 d^3);
  // Hess E = kappa (b'' grad d grad d^T + b' Hess d).
  for (int i = 0; i < 12; ++i)
    for (int j = 0; j < 12; ++j) {
      const double gg = g2[i] * g2[j];
      H[12 * i + j] = kappa * (d2b * gg / (4 * d2) + db * (H2[12 * i + j] / (2 * d) - gg / (4 * d2 * d)));
    }
  if (project) project_psd<12>(H);
}

void plain_dhat_derivatives(PairKind kind, int type, const double* x, double dhat, double c, double& dE,
                                   double* dg) {
  using J = Jet<double, 12>;
  J xs[12];
  for (int i = 0; i < 12; ++i) xs[i] = J(x[i], i);
  const J d2 = distance2_of(kind, type, xs);
  dE = 0;
  for (int i = 0; i < 12; ++i) dg[i] = 0;
  const double d = std::sqrt(d2.a);
  if (!(d > 0) || d >= dhat) return;  // b, b' vanish at d = dhat for every dhat: no contribution beyond
  using S = Jet<double, 1>;
  const S h(dhat, 0);
  const S e = c * h * barrier_in(d, h);
  const S s = c * h * barrier_slope_in(d, h);
  dE = e.v[0];
  for (int i = 0; i < 12; ++i) dg[i] = s.v[0] * d2.v[i] / (2 * d);
}

template <class T>
T mollifier_of(const T* x, double eps) {
  const Vec3<T> e0{x[3] - x[0], x[4] - x[1], x[5] - x[2]}, e1{x[9] - x[6], x[10] - x[7], x[11] - x[8]};
  const Vec3<T> n = cross(e0, e1);
  const T c = dot(n, n);
  if (value_of(c) >= eps) return T(1.0);
  const T s = c / eps;
  return (2.0 - s) * s;
}
bool mollified(PairKind kind, const double* x, double eps) {
  return kind == PairKind::kEdgeEdge && eps > 0 && mollifier_of(x, eps) < 1.0;
}
}  // namespace

double pair_mollifier(PairKind kind, const double* x, double eps) {
  return kind == PairKind::kEdgeEdge && eps > 0 ? mollifier_of(x, eps) : 1.0;
}

double pair_barrier_energy(PairKind kind, int type, const double* x, double dhat, double kappa, double eps) {
  const double E = plain_energy(kind, type, x, dhat, kappa);
  return mollified(kind, x, eps) && E != 0 ? mollifier_of(x, eps) * E : E;
}

void pair_barrier_gradient(PairKind kind, int type, const double* x, double dhat, double kappa, double* g, double eps) {
  plain_gradient(kind, type, x, dhat, kappa, g);
  if (!mollified(kind, x, eps)) return;
  const double E = plain_energy(kind, type, x, dhat, kappa);
  if (E == 0) return;
  using J = Jet<double, 12>;
  J xs[12];
  for (int i = 0; i < 12; ++i) xs[i] = J(x[i], i);
  const J m = mollifier_of(xs, eps);
  for (int i = 0; i < 12; ++i) g[i] = m.a * g[i] + E * m.v[i];
}

void pair_barrier_hessian(PairKind kind, int type, const double* x, double dhat, double kappa, bool project, double* H,
                          double eps) {
  if (!mollified(kind, x, eps)) {
    plain_hessian(kind, type, x, dhat, kappa, project, H);
    return;
  }
  plain_hessian(kind, type, x, dhat, kappa, false, H);
  const double E = plain_energy(kind, type, x, dhat, kappa);
  if (E != 0) {
    double gb[12], m, gm[12], Hm[144];
    plain_gradient(kind, type, x, dhat, kappa, gb);
    distance_gradient_hessian<12>([&](const auto* y) { return mollifier_of(y, eps); }, x, m, gm, Hm);
    // Hess (m E) = m Hess E + grad m grad E^T + grad E grad m^T + E Hess m
    for (int i = 0; i < 12; ++i)
      for (int j = 0; j < 12; ++j)
        H[12 * i + j] = m * H[12 * i + j] + gm[i] * gb[j] + gb[i] * gm[j] + E * Hm[12 * i + j];
  }
  if (project) project_psd<12>(H);
}

void pair_barrier_dhat_derivatives(PairKind kind, int type, const double* x, double dhat, double c, double& dE,
                                   double* dg, double eps) {
  plain_dhat_derivatives(kind, type, x, dhat, c, dE, dg);
  if (!mollified(kind, x, eps) || (dE == 0)) return;
  using J = Jet<double, 12>;
  J xs[12];
  for (int i = 0; i < 12; ++i) xs[i] = J(x[i], i);
  const J m = mollifier_of(xs, eps);
  // d(m E)/ddhat = m dE; d(grad(m E))/ddhat = m dg + dE grad m
  for (int i = 0; i < 12; ++i) dg[i] = m.a * dg[i] + dE * m.v[i];
  dE *= m.a;
}

void pair_barrier_gauss_newton(PairKind kind, int type, const double* x, double dhat, double kappa, double* r,
                               double& s, double eps) {
  using J = Jet<double, 12>;
  J xs[12];
  for (int i = 0; i < 12; ++i) xs[i] = J(x[i], i);
  const J d2 = distance2_of(kind, type, xs);
  s = 0;
  for (int i = 0; i < 12; ++i) r[i] = 0;
  const double d = std::sqrt(d2.a);
  if (!(d > 0) || d >= dhat) return;
  s = kappa * barrier_step_curvature(d, dhat) * pair_mollifier(kind, x, eps);
  for (int i = 0; i < 12; ++i) r[i] = d2.v[i] / (2 * d);
}

void pair_barrier_gauss_newton_derivatives(PairKind kind, int type, const double* x, double dhat, double c,
                                           const double* l, const double* w, double* dphi, double& dphi_ddhat,
                                           double eps) {
  for (int i = 0; i < 12; ++i) dphi[i] = 0;
  dphi_ddhat = 0;
  double d2, g2[12], H2[144];
  distance_gradient_hessian<12>([&](const auto* y) { return distance2_of(kind, type, y); }, x, d2, g2, H2);
  const double d = std::sqrt(d2);
  if (!(d > 0) || d >= dhat) return;
  // phi = s (l.r)(w.r), s = m c dhat b''(max(d, floor dhat); dhat), r = grad d = g2 / (2d),
  // Hess d = H2 / (2d) - g2 g2^T / (4 d^3): dphi = ds (l.r)(w.r) + s ((w.r) Hess d l + (l.r) Hess d w),
  // ds = c dhat (b''(d) grad m + m b'''(d) r) (b''' = 0 below the floor).
  using J = Jet<double, 2>;
  // below the floor the curvature is b''(floor dhat; dhat): no d-dependence, its dhat-dependence through both
  const J curvature = d > kGaussNewtonDistanceFloor * dhat
                          ? barrier_curvature_in(J(d, 0), J(dhat, 1))
                          : barrier_curvature_in(kGaussNewtonDistanceFloor * J(dhat, 1), J(dhat, 1));
  double m = 1.0, gm[12] = {0};
  if (kind == PairKind::kEdgeEdge && eps > 0) {
    using M = Jet<double, 12>;
    M xs[12];
    for (int i = 0; i < 12; ++i) xs[i] = M(x[i], i);
    const M mj = mollifier_of(xs, eps);
    m = mj.a;
    for (int i = 0; i < 12; ++i) gm[i] = mj.v[i];
  }
  double r[12], lr = 0, wr = 0;
  for (int i = 0; i < 12; ++i) {
    r[i] = g2[i] / (2 * d);
    lr += l[i] * r[i];
    wr += w[i] * r[i];
  }
  const double s = m * c * dhat * curvature.a;
  double Hl[12], Hw[12];
  for (int i = 0; i < 12; ++i) {
    double a = 0, b = 0;
    for (int j = 0; j < 12; ++j) {
      const double Hd = H2[12 * i + j] / (2 * d) - g2[i] * g2[j] / (4 * d2 * d);
      a += Hd * l[j];
      b += Hd * w[j];
    }
    Hl[i] = a;
    Hw[i] = b;
  }
  for (int i = 0; i < 12; ++i)
    dphi[i] = c * dhat * (curvature.a * gm[i] + m * curvature.v[0] * r[i]) * lr * wr + s * (wr * Hl[i] + lr * Hw[i]);
  dphi_ddhat = m * c * (curvature.a + dhat * curvature.v[1]) * lr * wr;
}

}  // namespace drapelab
