// The garment body moving within a step (garment/revolved_body.hpp): pose interpolation, the carry field, the
// collision bound on the relative motion, and the barrier's derivatives at an intermediate pose.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <random>

#include "garment/revolved_body.hpp"

namespace drapelab {
namespace {

RevolvedPart leg(double x) {  // a leg of radius 6 cm with conical ends, 56 cm long, hanging from (x, 0, 1)
  return RevolvedPart{Eigen::Vector3d(x, 0, 1), {0.0, 0.06, 0.5, 0.56}, {0.0, 0.06, 0.06, 0.0}};
}

RigidPose pose(double angle, const Eigen::Vector3d& axis, const Eigen::Vector3d& c) {
  RigidPose p;
  p.R = Eigen::AngleAxisd(angle, axis.normalized()).toRotationMatrix();
  p.c = c;
  return p;
}

// Two legs; the second swings forward about its hip (0.1, 0, 1) by 0.08 rad and the whole body shifts 1 cm.
struct Walk {
  RevolvedBodyContact body{{leg(-0.1), leg(0.1)}, Eigen::VectorXd::Constant(4, 1e-4), 2e-3};
  std::vector<RigidPose> start{RigidPose{}, RigidPose{}}, end;
  Walk() {
    const Eigen::Vector3d hip(0.1, 0, 1), shift(0, 0.01, 0);
    RigidPose swing = pose(0.08, Eigen::Vector3d::UnitX(), Eigen::Vector3d::Zero());
    swing.c = hip - swing.R * hip + shift;
    end = {pose(0, Eigen::Vector3d::UnitZ(), shift), swing};
    body.set_poses(start, end);
  }
};

TEST(RevolvedBodyMotion, InterpolationFollowsOneGeodesic) {
  const RigidPose a = pose(0.3, Eigen::Vector3d(1, 2, 3), Eigen::Vector3d(0.1, 0.2, 0.3));
  const RigidPose b = pose(-0.2, Eigen::Vector3d(-1, 0.5, 2), Eigen::Vector3d(-0.1, 0.0, 0.4));
  const RigidPose a0 = RevolvedBodyContact::interpolate(a, b, 0.0), b1 = RevolvedBodyContact::interpolate(a, b, 1.0);
  EXPECT_LT((a0.R - a.R).norm(), 1e-12);
  EXPECT_LT((b1.R - b.R).norm(), 1e-12);
  EXPECT_LT((b1.c - b.c).norm(), 1e-12);
  // From 0.3 of the way, 0.5 of the rest: 0.65 of the way.
  const RigidPose m = RevolvedBodyContact::interpolate(RevolvedBodyContact::interpolate(a, b, 0.3), b, 0.5);
  const RigidPose d = RevolvedBodyContact::interpolate(a, b, 0.65);
  EXPECT_LT((m.R - d.R).norm(), 1e-12);
  EXPECT_LT((m.c - d.c).norm(), 1e-12);
}

TEST(RevolvedBodyMotion, CarryMovesNearClothRigidlyAndLeavesFarClothAlone) {
  Walk w;
  EXPECT_EQ(w.body.obstacle_progress(), 0.0);
  // On the swinging leg (1 mm off its surface, and 8 mm), beside the still leg, and 54 cm off the swinging leg.
  Eigen::VectorXd x(12);
  x << 0.1, -0.061, 0.7, 0.1, -0.068, 0.7, -0.1, 0.061, 0.7, 0.1, -0.6, 0.7;
  Eigen::VectorXd u = Eigen::VectorXd::Zero(12);
  w.body.obstacle_carry(x, u);
  for (int i : {0, 1}) {  // exactly the swinging leg's motion
    const Eigen::Vector3d q = x.segment<3>(3 * i);
    const Eigen::Vector3d rigid = w.end[1].R * q + w.end[1].c - q;
    EXPECT_LT((u.segment<3>(3 * i) - rigid).norm(), 1e-9) << i;
  }
  EXPECT_LT((u.segment<3>(6) - Eigen::Vector3d(0, 0.01, 0)).norm(), 1e-9);  // the still leg only shifts
  EXPECT_EQ(u.segment<3>(9).norm(), 0.0);
  // Stacked layers move together: 0.5 mm apart anywhere near the legs (falloff and blend between the parts
  // included), their displacements differ by well under their distance (the carried map stays injective).
  std::mt19937 rng(1);
  std::uniform_real_distribution<double> box(-0.25, 0.25), unit(-1, 1);
  double worst = 0;
  Eigen::Vector3d where;
  for (int trial = 0; trial < 2000; ++trial) {
    Eigen::VectorXd ab(6);
    ab.head<3>() = Eigen::Vector3d(box(rng), 0.5 * box(rng), 0.75 + box(rng));
    ab.tail<3>() = ab.head<3>() + 5e-4 * Eigen::Vector3d(unit(rng), unit(rng), unit(rng)).normalized();
    if (w.body.clearance(ab).minCoeff() <= 0) continue;
    Eigen::VectorXd uab = Eigen::VectorXd::Zero(6);
    w.body.obstacle_carry(ab, uab);
    const double lip = (uab.head<3>() - uab.tail<3>()).norm() / 5e-4;
    if (lip > worst) worst = lip, where = ab.head<3>();
  }
  EXPECT_LT(worst, 0.9) << where.transpose();  // below 1: x -> x + u is one to one
  EXPECT_GT(worst, 0.0);
  // Carried rigidly, the cloth keeps its clearance to the moving leg.
  const double c0 = w.body.part_clearance(1, x.segment<3>(0));
  w.body.advance_obstacle(1.0);
  EXPECT_EQ(w.body.obstacle_progress(), 1.0);
  EXPECT_NEAR(w.body.part_clearance(1, (x + u).segment<3>(0)), c0, 1e-9);
}

TEST(RevolvedBodyMotion, AdvanceBoundKeepsStillClothOutOfTheSwingingLeg) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> z(0.55, 0.9), gap(2e-4, 0.03), ang(-3.14159, 3.14159);
  int limited = 0;
  for (int trial = 0; trial < 200; ++trial) {
    Walk w;
    const double a = ang(rng), r = 0.06 + gap(rng);
    Eigen::VectorXd x(12);
    for (int i = 0; i < 4; ++i) x.segment<3>(3 * i) = Eigen::Vector3d(0.1 + r * std::cos(a + i), r * std::sin(a + i), z(rng));
    const Eigen::VectorXd u = Eigen::VectorXd::Zero(12);  // cloth held still: the leg moves toward part of it
    const double tau = w.body.obstacle_max_advance(x, u);
    ASSERT_GE(tau, 0.0);
    ASSERT_LE(tau, 1.0);
    limited += tau < 1.0;
    for (int s = 0; s <= 200; ++s) {  // no vertex inside any part along the allowed motion
      const double t = tau * s / 200.0;
      for (int k = 0; k < 2; ++k) {
        const RigidPose P = RevolvedBodyContact::interpolate(w.start[k], w.end[k], t);
        for (int i = 0; i < 4; ++i) ASSERT_GT(w.body.part_clearance_at(k, P, x.segment<3>(3 * i)), 0.0) << trial;
      }
    }
    // The bound is not vacuous: at 1.5 tau (when below 1) the leg would have come within the gap fraction.
    if (tau > 0 && tau < 0.6) {
      double closest = 1;
      for (int s = 0; s <= 400; ++s) {
        const RigidPose P = RevolvedBodyContact::interpolate(w.start[1], w.end[1], 1.5 * tau * s / 400.0);
        for (int i = 0; i < 4; ++i) closest = std::min(closest, w.body.part_clearance_at(1, P, x.segment<3>(3 * i)));
      }
      EXPECT_LT(closest, 0.5 * w.body.clearance(x).minCoeff() + 1e-3) << trial;
    }
  }
  EXPECT_GT(limited, 10);  // the swing does reach cloth
}

TEST(RevolvedBodyMotion, CarriedClothIsNotHeldBack) {
  Walk w;
  Eigen::VectorXd x(12);
  x << 0.1, -0.0605, 0.7, 0.1, 0.0605, 0.8, 0.1605, 0, 0.6, 0.1, -0.0612, 0.75;
  Eigen::VectorXd u = Eigen::VectorXd::Zero(12);
  w.body.obstacle_carry(x, u);
  EXPECT_GT(w.body.obstacle_max_advance(x, u), 0.2);  // without the carry the swing would stop at once
  EXPECT_LT(w.body.obstacle_max_advance(x, Eigen::VectorXd::Zero(12)), 0.05);
}

TEST(RevolvedBodyMotion, BarrierDerivativesAtAnIntermediatePoseMatchFiniteDifferences) {
  Walk w;
  w.body.advance_obstacle(0.4);
  EXPECT_NEAR(w.body.obstacle_progress(), 0.4, 1e-15);
  w.body.advance_obstacle(0.5);
  EXPECT_NEAR(w.body.obstacle_progress(), 0.7, 1e-15);
  // Points 0.3-1.5 mm off the legs at the current pose (inside the 2 mm reach).
  const RigidPose P = RevolvedBodyContact::interpolate(w.start[1], w.end[1], 0.7);
  Eigen::VectorXd x(12);
  const double gaps[4] = {3e-4, 8e-4, 1.2e-3, 1.5e-3};
  for (int i = 0; i < 4; ++i) {
    const double a = 0.7 * i + 0.2;
    const Eigen::Vector3d local(0.1 + (0.06 + gaps[i]) * std::cos(a), (0.06 + gaps[i]) * std::sin(a), 0.6 + 0.05 * i);
    x.segment<3>(3 * i) = i % 2 ? P.R * local + P.c : Eigen::Vector3d(local.x() - 0.2, local.y() + 0.007, local.z());
  }
  const Eigen::VectorXd p;
  Eigen::VectorXd g = Eigen::VectorXd::Zero(12);
  w.body.add_gradient(x, p, g);
  ASSERT_GT(g.norm(), 0.0);
  const double eps = 1e-8;
  for (int j = 0; j < 12; ++j) {
    Eigen::VectorXd xp = x, xm = x;
    xp[j] += eps;
    xm[j] -= eps;
    const double fd = (w.body.energy(xp, p) - w.body.energy(xm, p)) / (2 * eps);
    EXPECT_NEAR(g[j], fd, 1e-5 * g.lpNorm<Eigen::Infinity>()) << j;
    Eigen::VectorXd gp = Eigen::VectorXd::Zero(12), gm = Eigen::VectorXd::Zero(12), hcol = Eigen::VectorXd::Zero(12);
    w.body.add_gradient(xp, p, gp);
    w.body.add_gradient(xm, p, gm);
    Eigen::VectorXd e = Eigen::VectorXd::Zero(12);
    e[j] = 1;
    w.body.add_hessian_product(x, p, e, hcol);
    const Eigen::VectorXd fdcol = (gp - gm) / (2 * eps);
    EXPECT_LT((hcol - fdcol).norm(), 1e-4 * fdcol.norm() + 1e-6) << j;
  }
}

}  // namespace
}  // namespace drapelab
