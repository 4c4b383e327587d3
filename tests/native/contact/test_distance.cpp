// Contact kernels (contact/distance.hpp, contact/barrier.hpp): distances against brute-force sampling of the
// primitives, every gradient and Hessian against central differences, the barrier's closed forms against
// its jet derivatives and differences.
#include <gtest/gtest.h>

#include <random>

#include "contact/barrier.hpp"
#include "contact/distance.hpp"

namespace drapelab {
namespace {

std::mt19937 rng(7);
double uniform(double a, double b) { return std::uniform_real_distribution<double>(a, b)(rng); }
Eigen::Vector3d random_point(double s = 1.0) { return {uniform(-s, s), uniform(-s, s), uniform(-s, s)}; }

// Brute force: the minimum over a fine barycentric grid of the triangle.
double sampled_point_triangle(const Eigen::Vector3d& p, const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                              const Eigen::Vector3d& c) {
  double best = INFINITY;
  const int n = 400;
  for (int i = 0; i <= n; ++i)
    for (int j = 0; i + j <= n; ++j) {
      const double u = double(i) / n, v = double(j) / n;
      best = std::min(best, (a + u * (b - a) + v * (c - a) - p).squaredNorm());
    }
  return best;
}
double sampled_edge_edge(const Eigen::Vector3d& a0, const Eigen::Vector3d& b0, const Eigen::Vector3d& a1,
                         const Eigen::Vector3d& b1) {
  double best = INFINITY;
  const int n = 600;
  for (int i = 0; i <= n; ++i)
    for (int j = 0; j <= n; ++j)
      best = std::min(best, (a0 + (double(i) / n) * (b0 - a0) - a1 - (double(j) / n) * (b1 - a1)).squaredNorm());
  return best;
}

template <class F>
void expect_derivatives_match_differences(const F& f, const double* x0, const char* what) {
  double v, g[12], H[144];
  distance_gradient_hessian<12>(f, x0, v, g, H);
  const double eps = 1e-6;
  for (int k = 0; k < 12; ++k) {
    double xp[12], xm[12];
    std::copy(x0, x0 + 12, xp);
    std::copy(x0, x0 + 12, xm);
    xp[k] += eps;
    xm[k] -= eps;
    double vp, vm, gp[12], gm[12], Hs[144];
    distance_gradient_hessian<12>(f, xp, vp, gp, Hs);
    distance_gradient_hessian<12>(f, xm, vm, gm, Hs);
    EXPECT_NEAR(g[k], (vp - vm) / (2 * eps), 1e-6 * (1 + std::abs(g[k]))) << what << " gradient " << k;
    for (int j = 0; j < 12; ++j)
      EXPECT_NEAR(H[j * 12 + k], (gp[j] - gm[j]) / (2 * eps), 1e-5 * (1 + std::abs(H[j * 12 + k])))
          << what << " Hessian " << j << "," << k;
  }
}

TEST(ContactDistance, PointTriangleMatchesBruteForceAndDifferences) {
  for (int trial = 0; trial < 40; ++trial) {
    const Eigen::Vector3d p = random_point(), a = random_point(0.5), b = random_point(0.5), c = random_point(0.5);
    const PointTriangleType type = point_triangle_type(p, a, b, c);
    double x[12];
    for (int k = 0; k < 3; ++k) x[k] = p[k], x[3 + k] = a[k], x[6 + k] = b[k], x[9 + k] = c[k];
    const double d2 = point_triangle_distance2(type, x);
    const double sampled = sampled_point_triangle(p, a, b, c);
    EXPECT_LE(d2, sampled + 1e-12) << "trial " << trial;
    EXPECT_NEAR(d2, sampled, 2e-4 * (1 + sampled)) << "trial " << trial << " type " << int(type);
    expect_derivatives_match_differences([&](const auto* y) { return point_triangle_distance2(type, y); }, x,
                                         "point-triangle");
  }
}

TEST(ContactDistance, EdgeEdgeMatchesBruteForceAndDifferences) {
  for (int trial = 0; trial < 40; ++trial) {
    const Eigen::Vector3d a0 = random_point(), b0 = random_point(), a1 = random_point(), b1 = random_point();
    const EdgeEdgeType type = edge_edge_type(a0, b0, a1, b1);
    double x[12];
    for (int k = 0; k < 3; ++k) x[k] = a0[k], x[3 + k] = b0[k], x[6 + k] = a1[k], x[9 + k] = b1[k];
    const double d2 = edge_edge_distance2(type, x);
    const double sampled = sampled_edge_edge(a0, b0, a1, b1);
    EXPECT_LE(d2, sampled + 1e-12) << "trial " << trial;
    EXPECT_NEAR(d2, sampled, 2e-4 * (1 + sampled)) << "trial " << trial << " type " << int(type);
    expect_derivatives_match_differences([&](const auto* y) { return edge_edge_distance2(type, y); }, x, "edge-edge");
  }
}

TEST(ContactDistance, ParallelEdgesFallBackToPointEdge) {
  const Eigen::Vector3d a0(0, 0, 0), b0(1, 0, 0), a1(0.2, 0.1, 0), b1(1.5, 0.1, 0);
  const EdgeEdgeType type = edge_edge_type(a0, b0, a1, b1);
  EXPECT_NE(type, EdgeEdgeType::kLineLine);
  double x[12];
  for (int k = 0; k < 3; ++k) x[k] = a0[k], x[3 + k] = b0[k], x[6 + k] = a1[k], x[9 + k] = b1[k];
  EXPECT_NEAR(edge_edge_distance2(type, x), 0.01, 1e-15);
}

TEST(ContactDistance, SupportDiskDistanceIsExactOnItsRegions) {
  SupportDisk disk;  // R 9 cm, rim 2 mm, top z = 0
  const double top[3] = {0.03, 0.02, 0.004};
  EXPECT_NEAR(support_disk_distance(disk, top), 0.004, 1e-15);
  const double below[3] = {0.0, 0.05, -0.01};  // under the plate (thickness 4 mm)
  EXPECT_NEAR(support_disk_distance(disk, below), 0.006, 1e-15);
  const double outside[3] = {0.095, 0.0, -0.002};  // level with the rim's centre circle, 7 mm beyond it
  EXPECT_NEAR(support_disk_distance(disk, outside), 0.095 - 0.088 - 0.002, 1e-15);
  // Gradient and Hessian by differences around the rim.
  for (int trial = 0; trial < 20; ++trial) {
    const double r = uniform(0.089, 0.1), t = uniform(0, 6.28), z = uniform(-0.01, 0.01);
    const double x0[3] = {r * std::cos(t), r * std::sin(t), z};
    double v, g[3], H[9];
    distance_gradient_hessian<3>([&](const auto* y) { return support_disk_distance(disk, y); }, x0, v, g, H);
    EXPECT_NEAR(Eigen::Vector3d(g[0], g[1], g[2]).norm(), 1.0, 1e-12) << "a distance's gradient is a unit vector";
    for (int k = 0; k < 3; ++k) {
      double xp[3] = {x0[0], x0[1], x0[2]}, xm[3] = {x0[0], x0[1], x0[2]};
      xp[k] += 1e-7;
      xm[k] -= 1e-7;
      EXPECT_NEAR(g[k], (support_disk_distance(disk, xp) - support_disk_distance(disk, xm)) / 2e-7, 1e-6);
    }
  }
}

TEST(ContactBarrier, ClosedFormsMatchJetsAndDifferences) {
  const double dhat = 1e-3;
  for (double d : {1e-6, 1e-5, 1e-4, 3e-4, 7e-4, 9.99e-4}) {
    double b, db, d2b;
    barrier_derivatives(d, dhat, b, db, d2b);
    using J = Jet<Jet<double, 1>, 1>;
    const J bj = barrier(J(Jet<double, 1>(d, 0), 0), dhat);
    EXPECT_NEAR(b, bj.a.a, 1e-12 * std::abs(b));
    EXPECT_NEAR(db, bj.v[0].a, 1e-10 * std::abs(db));
    EXPECT_NEAR(d2b, bj.v[0].v[0], 1e-10 * std::abs(d2b));
    const double e = 1e-9 * d;
    double bp, bm, dbp, dbm, tmp;
    barrier_derivatives(d + e, dhat, bp, dbp, tmp);
    barrier_derivatives(d - e, dhat, bm, dbm, tmp);
    EXPECT_NEAR(db, (bp - bm) / (2 * e), 1e-5 * std::abs(db));
    EXPECT_NEAR(d2b, (dbp - dbm) / (2 * e), 1e-5 * std::abs(d2b));
    EXPECT_GT(b, 0);
    EXPECT_LT(db, 0);
    EXPECT_GT(d2b, 0);
  }
  // C2 at dhat: value, slope and curvature vanish; infinite as d -> 0.
  double b, db, d2b;
  barrier_derivatives(dhat * (1 - 1e-9), dhat, b, db, d2b);
  EXPECT_LT(std::abs(b), 1e-15);
  EXPECT_LT(std::abs(db) * dhat, 1e-7);
  EXPECT_LT(std::abs(d2b) * dhat * dhat, 1e-7);
  EXPECT_GT(barrier(1e-300, dhat), 600.0);  // logarithmic, unbounded as d -> 0
}

TEST(ContactFriction, SmoothedF0IsC1AndMatchesItsDerivative) {
  const double eps = 1e-4;
  for (double u : {0.0, 1e-6, 5e-5, 9.9e-5, 1e-4, 2e-4}) {
    using J = Jet<double, 1>;
    const J f = friction_f0(J(u, 0), eps);
    if (u > 0) EXPECT_NEAR(f.v[0] / u, friction_f1_over_u(u, eps), 1e-9 / eps) << u;
    EXPECT_GE(f.v[0], 0.0);
    EXPECT_LE(f.v[0], 1.0 + 1e-12);
  }
  EXPECT_NEAR(friction_f0(eps * (1 - 1e-12), eps), eps, 1e-15);  // continuous at eps
}

}  // namespace
}  // namespace drapelab
