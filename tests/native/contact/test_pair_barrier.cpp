// The pair barrier kernels (contact/pair_barrier.hpp) against central differences: gradient against energy,
// Hessian against gradient, the projected Hessian PSD, the activation-distance derivatives, and the Gauss-Newton
// step matrix's derivatives.
#include <gtest/gtest.h>

#include <Eigen/Geometry>

#include <Eigen/Eigenvalues>
#include <cmath>
#include <random>

#include "contact/barrier.hpp"
#include "contact/pair_barrier.hpp"

namespace drapelab {
namespace {

// A random pair of the kind at a distance in (0.3, 0.7) scale dhat: for point-triangle, the point over the face, beyond
// an edge or beyond a vertex (variant 0, 1, 2); for edge-edge, crossing edges offset along their common normal.
void put(double* x, int k, const Eigen::Vector3d& v) {
  for (int a = 0; a < 3; ++a) x[k + a] = v[a];
}

void random_pair(PairKind kind, int variant, std::mt19937& rng, double dhat, double* x, double scale = 1.0) {
  std::uniform_real_distribution<double> u(-1, 1);
  auto rv = [&] { return Eigen::Vector3d(u(rng), u(rng), u(rng)); };
  const double target = scale * (0.5 + 0.2 * u(rng)) * dhat;
  if (kind == PairKind::kPointTriangle) {
    const Eigen::Vector3d a = 0.01 * rv(), b = 0.01 * rv(), c = 0.01 * rv();
    const Eigen::Vector3d n = (b - a).cross(c - a).normalized(), g = (a + b + c) / 3;
    Eigen::Vector3d p;
    if (variant == 0) p = g + target * n;
    else if (variant == 1) p = 0.5 * (a + b) + target * ((a + b) / 2 - c).normalized();
    else p = a + target * (a - g).normalized();
    put(x, 0, p);
    put(x, 3, a);
    put(x, 6, b);
    put(x, 9, c);
  } else {
    const Eigen::Vector3d a0 = 0.01 * rv(), b0 = 0.01 * rv(), e1 = 0.01 * rv();
    const Eigen::Vector3d m = (a0 + b0) / 2, n = (b0 - a0).cross(e1).normalized();
    put(x, 0, a0);
    put(x, 3, b0);
    put(x, 6, m + target * n - 0.4 * e1);
    put(x, 9, m + target * n + 0.6 * e1);
  }
}

// phi = l^T K w for the Gauss-Newton matrix K = s r r^T at kappa = c dh (what ..._derivatives differentiates).
double gauss_newton_form(PairKind kind, int type, const double* x, double dh, double c, const double* l,
                         const double* w, double eps = 0) {
  double r[12], s, lr = 0, wr = 0;
  pair_barrier_gauss_newton(kind, type, x, dh, c * dh, r, s, eps);
  for (int i = 0; i < 12; ++i) {
    lr += l[i] * r[i];
    wr += w[i] * r[i];
  }
  return s * lr * wr;
}

TEST(PairBarrier, DerivativesMatchCentralDifferences) {
  std::mt19937 rng(3);
  std::normal_distribution<double> n01(0, 1);
  const double dhat = 1e-3, c = 0.7;
  int tested[2] = {0, 0};
  for (int trial = 0; trial < 60; ++trial) {
    const PairKind kind = trial % 2 ? PairKind::kEdgeEdge : PairKind::kPointTriangle;
    double x[12];
    random_pair(kind, (trial / 2) % 3, rng, dhat, x);
    const int type = pair_type(kind, x);
    double dir[12];
    for (double& v : dir) v = n01(rng);
    const double eps = 1e-9;
    double xp[12], xm[12];
    for (int i = 0; i < 12; ++i) {
      xp[i] = x[i] + eps * dir[i];
      xm[i] = x[i] - eps * dir[i];
    }
    // the type must not switch within the difference
    if (pair_type(kind, xp) != type || pair_type(kind, xm) != type) continue;
    ++tested[trial % 2];
    const double kappa = c * dhat;
    double g[12], gp[12], gm[12], H[144], P[144];
    pair_barrier_gradient(kind, type, x, dhat, kappa, g);
    const double fd = (pair_barrier_energy(kind, type, xp, dhat, kappa) - pair_barrier_energy(kind, type, xm, dhat, kappa)) /
                      (2 * eps);
    double gd = 0;
    for (int i = 0; i < 12; ++i) gd += g[i] * dir[i];
    EXPECT_NEAR(gd, fd, 1e-6 * std::max(std::abs(fd), 1e-12)) << "gradient, trial " << trial;
    pair_barrier_gradient(kind, type, xp, dhat, kappa, gp);
    pair_barrier_gradient(kind, type, xm, dhat, kappa, gm);
    pair_barrier_hessian(kind, type, x, dhat, kappa, false, H);
    Eigen::Map<Eigen::Matrix<double, 12, 12, Eigen::RowMajor>> Hm(H);
    Eigen::Map<Eigen::Matrix<double, 12, 1>> dv(dir);
    Eigen::Matrix<double, 12, 1> fdH;
    for (int i = 0; i < 12; ++i) fdH[i] = (gp[i] - gm[i]) / (2 * eps);
    EXPECT_LE((Hm * dv - fdH).norm(), 1e-5 * fdH.norm()) << "Hessian, trial " << trial;
    EXPECT_LE((Hm - Hm.transpose()).norm(), 1e-12 * Hm.norm());
    pair_barrier_hessian(kind, type, x, dhat, kappa, true, P);
    Eigen::Map<Eigen::Matrix<double, 12, 12, Eigen::RowMajor>> Pm(P);
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 12, 12>> eig(Pm);
    EXPECT_GE(eig.eigenvalues().minCoeff(), -1e-9 * Pm.norm()) << "projected Hessian PSD";
    // activation-distance derivatives (kappa = c dhat)
    const double hd = 1e-9;
    double dE, dg[12], g1[12], g2[12];
    pair_barrier_dhat_derivatives(kind, type, x, dhat, c, dE, dg);
    const double fdE = (pair_barrier_energy(kind, type, x, dhat + hd, c * (dhat + hd)) -
                        pair_barrier_energy(kind, type, x, dhat - hd, c * (dhat - hd))) / (2 * hd);
    EXPECT_NEAR(dE, fdE, 1e-6 * std::abs(fdE)) << "dE/ddhat";
    pair_barrier_gradient(kind, type, x, dhat + hd, c * (dhat + hd), g1);
    pair_barrier_gradient(kind, type, x, dhat - hd, c * (dhat - hd), g2);
    for (int i = 0; i < 12; ++i) EXPECT_NEAR(dg[i], (g1[i] - g2[i]) / (2 * hd), 1e-5 * std::abs(dg[i]) + 1e-9);
  }
  EXPECT_GT(tested[0], 10);
  EXPECT_GT(tested[1], 10);
}

TEST(PairBarrier, MollifiedNearlyParallelEdgesMatchCentralDifferences) {
  // Edges 1 cm long, 0.5 mm apart, at 0.5-1.5 degrees to each other: |e0 x e1|^2 below eps = 1e-3 |e0|^2 |e1|^2
  // (the mollifier acts), derivatives of m kappa b against central differences.
  std::mt19937 rng(11);
  std::normal_distribution<double> n01(0, 1);
  std::uniform_real_distribution<double> u(0.5, 1.5);
  const double dhat = 1e-3, c = 0.7, kappa = c * dhat;
  int tested = 0;
  for (int trial = 0; trial < 20; ++trial) {
    const double angle = u(rng) * M_PI / 180, shift = 0.003 * (u(rng) - 1);
    double x[12] = {0, 0, 0, 0.01, 0, 0,
                    shift, -0.005 * std::sin(angle), 5e-4, shift + 0.01 * std::cos(angle), 0.005 * std::sin(angle), 5e-4};
    const double eps = 1e-3 * 1e-4 * 1e-4;
    const double m = pair_mollifier(PairKind::kEdgeEdge, x, eps);
    ASSERT_LT(m, 1.0);
    ASSERT_GT(m, 0.0);
    const int type = pair_type(PairKind::kEdgeEdge, x);
    double dir[12], xp[12], xm[12];
    for (double& v : dir) v = n01(rng);
    const double h = 1e-9;
    for (int i = 0; i < 12; ++i) {
      xp[i] = x[i] + h * dir[i];
      xm[i] = x[i] - h * dir[i];
    }
    if (pair_type(PairKind::kEdgeEdge, xp) != type || pair_type(PairKind::kEdgeEdge, xm) != type) continue;
    ++tested;
    double g[12], gp[12], gm[12], H[144];
    pair_barrier_gradient(PairKind::kEdgeEdge, type, x, dhat, kappa, g, eps);
    const double fd = (pair_barrier_energy(PairKind::kEdgeEdge, type, xp, dhat, kappa, eps) -
                       pair_barrier_energy(PairKind::kEdgeEdge, type, xm, dhat, kappa, eps)) / (2 * h);
    double gd = 0;
    for (int i = 0; i < 12; ++i) gd += g[i] * dir[i];
    EXPECT_NEAR(gd, fd, 1e-6 * std::abs(fd)) << "gradient";
    pair_barrier_gradient(PairKind::kEdgeEdge, type, xp, dhat, kappa, gp, eps);
    pair_barrier_gradient(PairKind::kEdgeEdge, type, xm, dhat, kappa, gm, eps);
    pair_barrier_hessian(PairKind::kEdgeEdge, type, x, dhat, kappa, false, H, eps);
    Eigen::Map<Eigen::Matrix<double, 12, 12, Eigen::RowMajor>> Hm(H);
    Eigen::Map<Eigen::Matrix<double, 12, 1>> dv(dir);
    Eigen::Matrix<double, 12, 1> fdH;
    for (int i = 0; i < 12; ++i) fdH[i] = (gp[i] - gm[i]) / (2 * h);
    EXPECT_LE((Hm * dv - fdH).norm(), 1e-5 * fdH.norm()) << "Hessian";
    double dE, dg[12], g1[12], g2[12];
    pair_barrier_dhat_derivatives(PairKind::kEdgeEdge, type, x, dhat, c, dE, dg, eps);
    const double hd = 1e-9;
    EXPECT_NEAR(dE, (pair_barrier_energy(PairKind::kEdgeEdge, type, x, dhat + hd, c * (dhat + hd), eps) -
                     pair_barrier_energy(PairKind::kEdgeEdge, type, x, dhat - hd, c * (dhat - hd), eps)) / (2 * hd),
                1e-6 * std::abs(dE));
    pair_barrier_gradient(PairKind::kEdgeEdge, type, x, dhat + hd, c * (dhat + hd), g1, eps);
    pair_barrier_gradient(PairKind::kEdgeEdge, type, x, dhat - hd, c * (dhat - hd), g2, eps);
    for (int i = 0; i < 12; ++i) EXPECT_NEAR(dg[i], (g1[i] - g2[i]) / (2 * hd), 1e-5 * std::abs(dg[i]) + 1e-9);
    // the mollified energy is below the plain one, and vanishes for parallel edges
    EXPECT_LT(pair_barrier_energy(PairKind::kEdgeEdge, type, x, dhat, kappa, eps),
              pair_barrier_energy(PairKind::kEdgeEdge, type, x, dhat, kappa));
  }
  EXPECT_GT(tested, 10);
  const double parallel[12] = {0, 0, 0, 0.01, 0, 0, 0.002, 0, 5e-4, 0.012, 0, 5e-4};
  EXPECT_EQ(pair_mollifier(PairKind::kEdgeEdge, parallel, 1e-11), 0.0);
}

// The Gauss-Newton step matrix K = s r r^T (linearised contact steps): PSD (s >= 0), r the distance's gradient,
// and the derivatives of phi = l^T K w in x and dhat against central differences (random pairs of both kinds
// and, for edge-edge, with the mollifier acting on nearly parallel edges).
TEST(PairBarrier, GaussNewtonMatrixDerivativesMatchCentralDifferences) {
  std::mt19937 rng(5);
  std::normal_distribution<double> n01(0, 1);
  const double dhat = 1e-3, c = 0.7;
  auto phi = [&](PairKind kind, int type, const double* x, double dh, const double* l, const double* w, double eps) {
    return gauss_newton_form(kind, type, x, dh, c, l, w, eps);
  };
  int tested = 0;
  for (int trial = 0; trial < 80; ++trial) {
    const PairKind kind = trial % 2 ? PairKind::kEdgeEdge : PairKind::kPointTriangle;
    double x[12];
    double eps = 0;
    if (trial % 4 == 3) {  // nearly parallel edges 0.5 mm apart: the mollifier acts
      const double angle = (0.5 + (trial % 7) * 0.15) * M_PI / 180;
      const double y[12] = {0, 0, 0, 0.01, 0, 0, -0.002, -0.005 * std::sin(angle), 5e-4,
                            -0.002 + 0.01 * std::cos(angle), 0.005 * std::sin(angle), 5e-4};
      std::copy(y, y + 12, x);
      eps = 1e-3 * 1e-4 * 1e-4;
      ASSERT_LT(pair_mollifier(kind, x, eps), 1.0);
    } else {
      random_pair(kind, (trial / 2) % 3, rng, dhat, x);
    }
    const int type = pair_type(kind, x);
    double l[12], w[12], dir[12], xp[12], xm[12];
    for (int i = 0; i < 12; ++i) {
      l[i] = n01(rng);
      w[i] = n01(rng);
      dir[i] = n01(rng);
    }
    const double h = 1e-10;
    for (int i = 0; i < 12; ++i) {
      xp[i] = x[i] + h * dir[i];
      xm[i] = x[i] - h * dir[i];
    }
    if (pair_type(kind, xp) != type || pair_type(kind, xm) != type) continue;
    ++tested;
    double r[12], s;
    pair_barrier_gauss_newton(kind, type, x, dhat, c * dhat, r, s, eps);
    EXPECT_GT(s, 0.0);
    double dphi[12], dphi_ddhat, dd = 0;
    pair_barrier_gauss_newton_derivatives(kind, type, x, dhat, c, l, w, dphi, dphi_ddhat, eps);
    for (int i = 0; i < 12; ++i) dd += dphi[i] * dir[i];
    const double fd = (phi(kind, type, xp, dhat, l, w, eps) - phi(kind, type, xm, dhat, l, w, eps)) / (2 * h);
    const double scale = std::abs(phi(kind, type, x, dhat, l, w, eps)) / dhat;  // phi varies on the scale of d
    EXPECT_NEAR(dd, fd, 1e-5 * std::max(std::abs(fd), scale)) << "x, trial " << trial;
    const double hd = 1e-10;
    const double fdh = (phi(kind, type, x, dhat + hd, l, w, eps) - phi(kind, type, x, dhat - hd, l, w, eps)) / (2 * hd);
    EXPECT_NEAR(dphi_ddhat, fdh, 1e-5 * std::max(std::abs(fdh), scale)) << "dhat, trial " << trial;
  }
  EXPECT_GT(tested, 50);
  // beyond the activation distance: no matrix, no derivatives
  const double far[12] = {0.2, 0.2, 2e-3, 0, 0, 0, 1, 0, 0, 0, 1, 0};
  double r[12], s;
  pair_barrier_gauss_newton(PairKind::kPointTriangle, pair_type(PairKind::kPointTriangle, far), far, 1e-3, 1e-3, r, s);
  EXPECT_EQ(s, 0.0);
}

// Below the distance floor (pairs pinched to a tiny fraction of dhat) the Gauss-Newton curvature stays at the
// floor's, s = kappa b''(floor dhat) (finite and independent of d: the step matrix's condition is bounded), and its
// derivatives in x and dhat (the floor moves with dhat) still match central differences.
TEST(PairBarrier, GaussNewtonCurvatureFloorBelowTheFloorMatchesCentralDifferences) {
  std::mt19937 rng(11);
  std::normal_distribution<double> n01(0, 1);
  const double dhat = 1e-3, c = 0.7, floor_d = kGaussNewtonDistanceFloor * dhat;
  double b, db, d2b_floor;
  barrier_derivatives(floor_d, dhat, b, db, d2b_floor);
  auto phi = [&](PairKind kind, int type, const double* x, double dh, const double* l, const double* w) {
    return gauss_newton_form(kind, type, x, dh, c, l, w);
  };
  int tested = 0;
  for (int trial = 0; trial < 72; ++trial) {
    const PairKind kind = (trial / 6) % 2 ? PairKind::kEdgeEdge : PairKind::kPointTriangle;
    double x[12];
    // from half the floor down to 1e-11 m (a pinched garment fold reached 1e-13 m, docs/lab/garment-speed.md); the
    // central differences only down to about 1e-8 m (below, the coordinates' round-off is a visible part of d)
    const int decade = trial % 6;
    const double scale = 0.5 * kGaussNewtonDistanceFloor * std::pow(10.0, -decade);
    random_pair(kind, (trial / 12) % 3, rng, dhat, x, scale);
    const int type = pair_type(kind, x);
    const double d = std::sqrt(pair_distance2(kind, type, x));
    ASSERT_LT(d, floor_d);
    double r[12], s;
    pair_barrier_gauss_newton(kind, type, x, dhat, c * dhat, r, s);
    EXPECT_NEAR(s, c * dhat * d2b_floor, 1e-12 * c * dhat * d2b_floor) << "trial " << trial;
    if (decade > 2) continue;
    double l[12], w[12], dir[12], xp[12], xm[12];
    for (int i = 0; i < 12; ++i) {
      l[i] = n01(rng);
      w[i] = n01(rng);
      dir[i] = n01(rng);
    }
    const double h = 1e-3 * d;  // the distance's derivatives vary on the scale of d
    for (int i = 0; i < 12; ++i) {
      xp[i] = x[i] + h * dir[i];
      xm[i] = x[i] - h * dir[i];
    }
    if (pair_type(kind, xp) != type || pair_type(kind, xm) != type) continue;
    ++tested;
    double dphi[12], dphi_ddhat, dd = 0;
    pair_barrier_gauss_newton_derivatives(kind, type, x, dhat, c, l, w, dphi, dphi_ddhat);
    for (int i = 0; i < 12; ++i) dd += dphi[i] * (xp[i] - xm[i]) / (2 * h);  // the steps as rounded
    const double fd = (phi(kind, type, xp, dhat, l, w) - phi(kind, type, xm, dhat, l, w)) / (2 * h);
    const double scale_x = std::abs(phi(kind, type, x, dhat, l, w)) / d;
    // 1e-4: the truncation (h / d)^2 of a distance whose curvature is 1 / d, and the coordinates' round-off (d is
    // a difference of coordinates 1e8 times larger)
    EXPECT_NEAR(dd, fd, 1e-4 * std::max(std::abs(fd), scale_x)) << "x, trial " << trial;
    const double hd = 1e-9 * dhat;
    const double fdh = (phi(kind, type, x, dhat + hd, l, w) - phi(kind, type, x, dhat - hd, l, w)) / (2 * hd);
    EXPECT_NEAR(dphi_ddhat, fdh, 1e-6 * std::abs(fdh)) << "dhat, trial " << trial;
    EXPECT_NE(dphi_ddhat, 0.0);
  }
  EXPECT_GT(tested, 20);
}

TEST(PairBarrier, ZeroBeyondActivationInfiniteAtContact) {
  const double x[12] = {0.2, 0.2, 2e-3, 0, 0, 0, 1, 0, 0, 0, 1, 0};
  EXPECT_EQ(pair_barrier_energy(PairKind::kPointTriangle, pair_type(PairKind::kPointTriangle, x), x, 1e-3, 1.0), 0.0);
  const double y[12] = {0.2, 0.2, 0, 0, 0, 0, 1, 0, 0, 0, 1, 0};
  EXPECT_TRUE(std::isinf(pair_barrier_energy(PairKind::kPointTriangle, pair_type(PairKind::kPointTriangle, y), y, 1e-3, 1.0)));
}

}  // namespace
}  // namespace drapelab
