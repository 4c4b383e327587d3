// Additive CCD (contact/ccd.hpp): crafted head-on, grazing, parallel and tunnelling motions, and random motions
// checked against a fine sampling of the distance along the motion.
#include <gtest/gtest.h>

#include <random>

#include "contact/ccd.hpp"

namespace drapelab {
namespace {

using V = Eigen::Vector3d;
const V a(0, 0, 0), b(1, 0, 0), c(0, 1, 0), zero(0, 0, 0);

TEST(Ccd, HeadOnPointTriangleStopsBeforeImpact) {
  // point at z = 1 moving to z = -1 through the triangle's interior: impact at t = 0.5
  const double t = point_triangle_ccd(V(0.2, 0.2, 1), a, b, c, V(0, 0, -2), zero, zero, zero);
  EXPECT_GT(t, 0.4);
  EXPECT_LT(t, 0.5);
  // at t the point is still at least s d(0) = 0.1 away
  EXPECT_GE(1 - 2 * t, kDefaultCcdSeparation * 1.0 - 1e-12);
}

TEST(Ccd, FastTunnellingIsCaught) {
  // a point crossing a thin triangle in one step with a huge displacement
  const double t = point_triangle_ccd(V(0.2, 0.2, 1e-3), a, b, c, V(0, 0, -100), zero, zero, zero);
  EXPECT_LT(t, 1e-5);
  EXPECT_GT(t, 0.0);
  // the triangle moving through a static point
  const double t2 = point_triangle_ccd(V(0.2, 0.2, 0), a + V(0, 0, 1), b + V(0, 0, 1), c + V(0, 0, 1), zero,
                                       V(0, 0, -5), V(0, 0, -5), V(0, 0, -5));
  EXPECT_LT(t2, 0.2);
}

TEST(Ccd, GrazingAndParallelMotionsAreNotImpacts) {
  // a point sliding parallel to the face 1 cm above: no impact
  EXPECT_EQ(point_triangle_ccd(V(0.2, 0.2, 0.01), a, b, c, V(0.5, 0.1, 0), zero, zero, zero), 1.0);
  // passing beside the triangle (outside its edge) across its plane: grazing, closest 0.1 from edge bc
  EXPECT_EQ(point_triangle_ccd(V(0.7, 0.7, 1), a, b, c, V(0, 0, -2), zero, zero, zero), 1.0);
  // two parallel edges translating together
  EXPECT_EQ(edge_edge_ccd(a, b, V(0, 0, 0.01), V(1, 0, 0.01), V(1, 1, 1), V(1, 1, 1), V(1, 1, 1), V(1, 1, 1)), 1.0);
  // parallel edges approaching each other head-on stop before meeting
  const double t = edge_edge_ccd(a, b, V(0, 0, 0.1), V(1, 0, 0.1), zero, zero, V(0, 0, -0.2), V(0, 0, -0.2));
  EXPECT_GT(t, 0.4);
  EXPECT_LT(t, 0.5);
}

TEST(Ccd, CrossingEdgesAreCaught) {
  // edge along x at z = 0, edge along y moving down through it: impact at t = 0.5
  const double t = edge_edge_ccd(V(-1, 0, 0), V(1, 0, 0), V(0, -1, 1), V(0, 1, 1), zero, zero, V(0, 0, -2), V(0, 0, -2));
  EXPECT_GT(t, 0.4);
  EXPECT_LT(t, 0.5);
  // already touching: 0
  EXPECT_EQ(edge_edge_ccd(V(-1, 0, 0), V(1, 0, 0), V(0, -1, 0), V(0, 1, 0), zero, zero, V(0, 0, 1), V(0, 0, 1)), 0.0);
}

TEST(Ccd, RandomMotionsAreConservativeAgainstFineSampling) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-1, 1);
  auto rv = [&] { return V(u(rng), u(rng), u(rng)); };
  int impacts = 0;
  for (int trial = 0; trial < 400; ++trial) {
    V q[4], d[4];
    for (int k = 0; k < 4; ++k) {
      q[k] = rv();
      d[k] = 2 * rv();
    }
    const bool pt = trial % 2 == 0;
    auto dist = [&](double t) {
      V y[4];
      for (int k = 0; k < 4; ++k) y[k] = q[k] + t * d[k];
      return pt ? point_triangle_unsigned_distance(y[0], y[1], y[2], y[3]) : edge_edge_unsigned_distance(y[0], y[1], y[2], y[3]);
    };
    const double d0 = dist(0);
    const double t = pt ? point_triangle_ccd(q[0], q[1], q[2], q[3], d[0], d[1], d[2], d[3])
                        : edge_edge_ccd(q[0], q[1], q[2], q[3], d[0], d[1], d[2], d[3]);
    ASSERT_GT(t, 0.0);
    ASSERT_LE(t, 1.0);
    // Sampled: no sample before t comes closer than (a bit less than) s d0 (the advancement's guarantee), and
    // the first sampled near-touch (distance below 1e-3 d0) is never before t.
    double first_touch = 2;
    for (int k = 0; k <= 4000; ++k) {
      const double tk = k / 4000.0;
      const double dk = dist(tk);
      if (tk <= t) {
        EXPECT_GT(dk, 0.0) << "trial " << trial << " t " << tk;
      }
      if (dk < 1e-3 * d0 && first_touch > 1) first_touch = tk;
    }
    if (first_touch <= 1) {
      ++impacts;
      EXPECT_LE(t, first_touch) << "trial " << trial;
    }
    EXPECT_GE(dist(t), 0.0999 * d0 * (t < 1 ? 1.0 : 0.0)) << "trial " << trial;
  }
  EXPECT_GT(impacts, 5);  // the random set contains real impacts
}

}  // namespace
}  // namespace drapelab
