// Friction between a garment and its body (garment/body_friction.hpp): the lagged potential's gradient, Hessian
// and step matrix against central differences on a moving two-part body (stick and slip zones), its lagged
// quantities (normal force, projector, the body's own slip), and a strip lying on a bar that slides along its own
// axis: frictionless the strip stays where its inertia keeps it, with friction the bar carries it along.
#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>
#include <cmath>
#include <random>

#include "contact/barrier.hpp"
#include "garment/body_friction.hpp"
#include "physics/model.hpp"
#include "physics/sparse_pattern.hpp"
#include "solver/implicit_euler.hpp"
#include "../test_support.hpp"

namespace drapelab {
namespace {

constexpr double kReach = 2e-3;

RevolvedPart leg(double x) {  // radius 6 cm, conical ends, 56 cm long, hanging from (x, 0, 1)
  return RevolvedPart{Eigen::Vector3d(x, 0, 1), {0.0, 0.06, 0.5, 0.56}, {0.0, 0.06, 0.06, 0.0}};
}

Eigen::MatrixXd dense(const SparsePattern& pattern, const Eigen::VectorXd& values) {
  return testing::dense_symmetric(pattern, values);
}

// Two legs; the second swings forward about its hip by 0.05 rad while the body shifts 5 mm sideways.
struct MovingBody {
  static constexpr int kVertices = 8;
  RevolvedBodyContact body{{leg(-0.1), leg(0.1)}, Eigen::VectorXd::LinSpaced(kVertices, 1e-5, 3e-5), kReach};
  std::vector<RigidPose> start{RigidPose{}, RigidPose{}}, end;
  MovingBody() {
    const Eigen::Vector3d hip(0.1, 0, 1), shift(0, 0.005, 0);
    RigidPose still, swing;
    still.c = shift;
    swing.R = Eigen::AngleAxisd(0.05, Eigen::Vector3d::UnitX()).toRotationMatrix();
    swing.c = hip - swing.R * hip + shift;
    end = {still, swing};
    body.set_poses(start, end);
  }
};

// Vertices within reach of the legs (clearance 0.2-1.8 mm) at random heights and angles; one far away.
Eigen::VectorXd near_legs(std::mt19937& rng) {
  std::uniform_real_distribution<double> angle(0, 2 * M_PI), height(0.6, 0.85), gap(2e-4, 1.8e-3);
  Eigen::VectorXd x(3 * MovingBody::kVertices);
  for (int i = 0; i < MovingBody::kVertices - 1; ++i) {
    const double cx = i % 2 ? 0.1 : -0.1, a = angle(rng), r = 0.06 + gap(rng);
    x.segment<3>(3 * i) = Eigen::Vector3d(cx + r * std::cos(a), r * std::sin(a), height(rng));
  }
  x.tail<3>() = Eigen::Vector3d(0, 0.5, 0.7);
  return x;
}

TEST(BodyFriction, LaggedNormalForceProjectorAndBodySlip) {
  MovingBody m;
  BodyFriction friction(m.body, MovingBody::kVertices, 0.4);
  std::mt19937 rng(3);
  const Eigen::VectorXd xt = near_legs(rng);
  const double h = 0.01;
  friction.begin_step(xt, Eigen::VectorXd(), h);
  EXPECT_EQ(friction.num_active(), MovingBody::kVertices - 1);  // the far vertex has none
  // At x = x_t the slip is minus the body's: on the still leg (shifted 5 mm sideways, tangent to a vertex at angle
  // a by |sin a| of it) the force opposes the tangential part of the relative motion, mu lambda f1(|u|)/|u| u.
  const Eigen::VectorXd p;
  const SparsePattern pattern(MovingBody::kVertices, friction.stencils());
  friction.bind_pattern(pattern);
  Eigen::VectorXd g = Eigen::VectorXd::Zero(xt.size());
  friction.add_gradient(xt, p, g);
  const double eps_u = 1e-3 * h;
  for (int i = 0; i < MovingBody::kVertices - 1; i += 2) {  // the still leg (part 0)
    const Eigen::Vector3d q = xt.segment<3>(3 * i);
    Eigen::Vector3d grad;
    const double gap = m.body.part_clearance_at(0, m.start[0], q, &grad);
    double b, db, d2b;
    barrier_derivatives(gap, kReach, b, db, d2b);
    const double lambda = m.body.kappa()[i] * std::abs(db) * grad.norm();
    const Eigen::Vector3d n = grad.normalized();
    const Eigen::Vector3d u = -(Eigen::Matrix3d::Identity() - n * n.transpose()) * Eigen::Vector3d(0, 0.005, 0);
    const Eigen::Vector3d expected = 0.4 * lambda * friction_f1_over_u(u.norm(), eps_u) * u;
    EXPECT_LT((g.segment<3>(3 * i) - expected).norm(), 1e-12 * expected.norm() + 1e-300) << i;
    EXPECT_NEAR(g.segment<3>(3 * i).norm(), 0.4 * lambda, 1e-12 * lambda) << "sliding: the full Coulomb force " << i;
  }
  EXPECT_EQ(g.tail<3>().norm(), 0.0);
  // Switched off (mu 0) or static (h 0): no energy.
  BodyFriction off(m.body, MovingBody::kVertices, 0.0);
  off.begin_step(xt, p, h);
  EXPECT_EQ(off.num_active(), 0);
  friction.begin_step(xt, p, 0.0);
  EXPECT_EQ(friction.num_active(), 0);
  EXPECT_EQ(friction.energy(xt, p), 0.0);
}

TEST(BodyFriction, DerivativesMatchCentralDifferencesInStickAndSlip) {
  MovingBody m;
  BodyFriction friction(m.body, MovingBody::kVertices, 0.3);
  const int n = 3 * MovingBody::kVertices;
  const SparsePattern pattern(MovingBody::kVertices, friction.stencils());
  friction.bind_pattern(pattern);
  const Eigen::VectorXd p;
  std::mt19937 rng(7);
  const double h = 0.01;  // eps_u = 1e-5 m
  for (const bool moving : {false, true}) {
    if (moving) m.body.set_poses(m.start, m.end);
    else m.body.set_poses(m.start, m.start);
    for (const double scale : {3e-6, 3e-5, 1e-3}) {  // the vertices' moves: within the stick zone, across, beyond
      const Eigen::VectorXd xt = near_legs(rng);
      friction.begin_step(xt, p, h);
      ASSERT_GT(friction.num_active(), 0);
      std::normal_distribution<double> normal(0, scale);
      Eigen::VectorXd x = xt;
      for (int j = 0; j < n; ++j) x[j] += normal(rng);
      // a body-following vertex: exactly the body's slip (u = 0, the smooth branch)
      if (!moving) x.segment<3>(0) = xt.segment<3>(0);
      Eigen::VectorXd g = Eigen::VectorXd::Zero(n), values = Eigen::VectorXd::Zero(pattern.nnz()),
                      step = Eigen::VectorXd::Zero(pattern.nnz());
      friction.add_gradient(x, p, g);
      friction.add_hessian(x, p, 1.0, values);
      friction.add_step_matrix(x, p, 1.0, step);
      const Eigen::MatrixXd H = dense(pattern, values), K = dense(pattern, step);
      for (int j = 0; j < n; ++j) {
        // At u = 0 (vertex 0 when the body stands still) f0's |u|^3 term makes central differences of the gradient
        // err by ~eps / eps_u, and x - x_t loses ~1e-16 / eps of eps: a small eps and a looser tolerance there.
        const bool at_zero_slip = !moving && j < 3;
        const double eps = at_zero_slip ? 3e-11 : std::min(1e-8, scale * 1e-3);
        const double tol = at_zero_slip ? 1e-4 : 1e-5;
        Eigen::VectorXd xp = x, xm = x;
        xp[j] += eps;
        xm[j] -= eps;
        const double fd = (friction.energy(xp, p) - friction.energy(xm, p)) / (2 * eps);
        EXPECT_NEAR(g[j], fd, 1e-6 * g.lpNorm<Eigen::Infinity>()) << "scale " << scale << " moving " << moving << " gradient " << j;
        Eigen::VectorXd gp = Eigen::VectorXd::Zero(n), gm = Eigen::VectorXd::Zero(n);
        friction.add_gradient(xp, p, gp);
        friction.add_gradient(xm, p, gm);
        EXPECT_LT((H.col(j) - (gp - gm) / (2 * eps)).norm(), tol * H.norm())
            << "scale " << scale << " moving " << moving << " Hessian column " << j;
        Eigen::VectorXd e = Eigen::VectorXd::Zero(n), hcol = Eigen::VectorXd::Zero(n), kcol = Eigen::VectorXd::Zero(n);
        e[j] = 1;
        friction.add_hessian_product(x, p, e, hcol);
        EXPECT_LT((H.col(j) - hcol).norm(), 1e-12 * H.norm());
        ASSERT_TRUE(friction.add_step_matrix_product(x, p, e, 1.0, kcol));
        EXPECT_LT((K.col(j) - kcol).norm(), 1e-12 * K.norm());
      }
      // The slip is linear in x: the step matrix is the exact Hessian, and PSD.
      EXPECT_LT((K - H).norm(), 1e-12 * H.norm()) << "scale " << scale;
      EXPECT_GT(Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd>(K).eigenvalues().minCoeff(), -1e-12 * K.norm());
    }
  }
}

// A 20 x 12 cm strip lying across a horizontal bar (a leg turned along +x), the bar sliding 0.2 m/s along its own
// axis for 0.5 s: returns the strip's mean x displacement and its least clearance.
void slide_bar_under_strip(double mu, double* moved, double* least) {
  TriangleMesh mesh;
  const int nx = 5, ny = 5;
  mesh.positions.resize(nx * ny, 3);
  mesh.uv.resize(nx * ny, 2);
  for (int i = 0; i < nx; ++i)
    for (int j = 0; j < ny; ++j) {
      const int v = i * ny + j;
      const double u = -0.1 + 0.2 * i / (nx - 1), w = -0.06 + 0.12 * j / (ny - 1);
      // draped over the bar's top (radius 6 cm about the x axis at z = 0.5): 1 mm above its surface near the top
      const double a = w / 0.061;
      mesh.positions.row(v) << u, 0.061 * std::sin(a), 0.5 + 0.061 * std::cos(a);
      mesh.uv.row(v) << u, w;
    }
  mesh.faces.resize(2 * (nx - 1) * (ny - 1), 3);
  int f = 0;
  for (int i = 0; i + 1 < nx; ++i)
    for (int j = 0; j + 1 < ny; ++j) {
      const int a = i * ny + j, b = a + ny;
      mesh.faces.row(f++) << a, b, a + 1;
      mesh.faces.row(f++) << a + 1, b, b + 1;
    }
  ModelOptions o;
  o.held_vertices = {0};
  o.handle_stiffness = 1e-6;  // N/m: negligible
  Model model(mesh, o);
  const Eigen::VectorXd p = model.default_parameters();
  const Eigen::VectorXd kappa = model.masses(p) * o.gravity * kReach;
  RigidPose bar;  // the leg's axis along +x, its middle (s = 0.28) at (0, 0, 0.5)
  bar.R = Eigen::AngleAxisd(-M_PI / 2, Eigen::Vector3d::UnitY()).toRotationMatrix();
  bar.c = Eigen::Vector3d(0, 0, 0.5) - bar.R * Eigen::Vector3d(0, 0, 1.0 - 0.28);
  auto* body = model.add_term(std::make_unique<RevolvedBodyContact>(std::vector<RevolvedPart>{leg(0.0)}, kappa, kReach));
  if (mu > 0) model.add_term(std::make_unique<BodyFriction>(*body, model.num_vertices(), mu));
  ImplicitEuler sim(model);
  RolloutOptions ro;
  ro.time_step = 1.0 / 96;
  ro.steps = 1;
  ro.record = false;
  Eigen::VectorXd x = Eigen::Map<const Eigen::VectorXd>(mesh.positions.data(), 3 * nx * ny);
  const Eigen::VectorXd x0 = x;
  Eigen::VectorXd v = Eigen::VectorXd::Zero(x.size());
  *least = INFINITY;
  RigidPose from = bar;
  for (int step = 0; step < 48; ++step) {
    RigidPose to = from;
    to.c.x() += 0.2 * ro.time_step;
    body->set_poses({from}, {to});
    const Eigen::VectorXd next = sim.forward(p, ro, nullptr, &x, &v);
    v = (next - x) / ro.time_step;
    x = next;
    from = to;
    *least = std::min(*least, body->clearance(x).minCoeff());
  }
  double sum = 0;
  for (int i = 0; i < nx * ny; ++i) sum += x[3 * i] - x0[3 * i];
  *moved = sum / (nx * ny);
}

TEST(BodyFriction, SlidingBarCarriesTheStripOnlyWithFriction) {
  double free_moved, free_least, moved, least;
  slide_bar_under_strip(0.0, &free_moved, &free_least);
  slide_bar_under_strip(0.5, &moved, &least);
  std::printf("bar sliding 0.1 m along its axis under a strip: mean strip displacement %.4f m frictionless, "
              "%.4f m with mu 0.5; least clearance %.3g / %.3g m\n", free_moved, moved, free_least, least);
  EXPECT_LT(std::abs(free_moved), 0.01) << "frictionless: nothing drags the strip along the bar";
  // mu g = 4.9 m/s^2 brings the strip to the bar's 0.2 m/s within ~0.04 s: it lags the bar by ~4 mm.
  EXPECT_GT(moved, 0.08);
  EXPECT_LT(moved, 0.1 + 1e-3);
  EXPECT_GT(free_least, 0.0);
  EXPECT_GT(least, 0.0);
}

}  // namespace
}  // namespace drapelab
