// ObstacleContact (contact/obstacle_contact.hpp): a small free cloth dropped on a static icosphere ends
// intersection-free, outside the sphere and resting on it; the term's derivatives against central
// differences; a moving obstacle is swept against by CCD; bad obstacle input is refused.
#include <gtest/gtest.h>

#include <Eigen/Geometry>

#include "../test_support.hpp"
#include "contact/obstacle_contact.hpp"
#include "contact_support.hpp"
#include "solver/implicit_euler.hpp"
#include "util/error.hpp"

namespace drapelab {
namespace {

// Inside a convex closed mesh: behind every face's plane (faces wound outward).
bool inside_convex(const ObstacleMesh& m, const Eigen::Vector3d& q) {
  for (int f = 0; f < m.faces.rows(); ++f) {
    const Eigen::Vector3d a = m.positions.row(m.faces(f, 0)), b = m.positions.row(m.faces(f, 1)),
                          c = m.positions.row(m.faces(f, 2));
    if ((b - a).cross(c - a).dot(q - a) > 0) return false;
  }
  return true;
}

TEST(ObstacleContact, ClothDroppedOnSphereEndsOutsideAndIntersectionFree) {
  const TriangleMesh cloth = testing::grid_mesh(10, 0.12, 0.0);
  const ObstacleMesh sphere = testing::icosphere(2, 0.03, {0.0, 0.0, -0.035});
  ASSERT_FALSE(inside_convex(sphere, Eigen::Vector3d(0, 0, 0)));
  ASSERT_TRUE(inside_convex(sphere, Eigen::Vector3d(0.0, 0.0, -0.035)));  // faces wound outward
  ModelOptions o;
  o.handle_stiffness = 0.0;  // a free cloth (the handle term holds nothing)
  Model model(cloth, o);
  model.add_term(std::make_unique<ObstacleContact>(cloth, model.area_weights(), o.density, o.gravity, sphere, 1e-3));
  ImplicitEuler sim(model);
  RolloutOptions ro;
  // 0.3 s: the cloth lands (after ~30 ms) and drapes around the sphere. Without friction it would later slide
  // off the sphere's top (an unstable equilibrium), so the run stops while it rests there.
  ro.steps = 15;
  ro.time_step = 0.02;
  ro.record = false;
  const Eigen::VectorXd x = sim.forward(model.default_parameters(), ro);
  const ContactReport r = contact_report(cloth.faces, x, &sphere);
  EXPECT_EQ(r.intersecting_pairs, 0);
  EXPECT_GT(r.min_distance_m, 0.0);
  EXPECT_LT(r.min_distance_m, 1e-3) << "the cloth should rest on the sphere";
  int inside = 0;
  double worst_centre = 0;  // the central vertices rest on the sphere: their distance to its surface [m]
  for (int i = 0; i < model.num_vertices(); ++i) {
    inside += inside_convex(sphere, x.segment<3>(3 * i));
    if (cloth.positions.row(i).head<2>().norm() < 0.01)
      worst_centre = std::max(worst_centre, std::abs((x.segment<3>(3 * i) - Eigen::Vector3d(0, 0, -0.035)).norm() - 0.03));
  }
  EXPECT_EQ(inside, 0);
  // The centre is held up by the sphere (free fall over 0.3 s: 0.44 m): its vertices (rest radius 9.4 mm) lie
  // within 5 mm of the surface (the flat patch between them spans the sphere's top: 1.4 mm at least).
  EXPECT_LT(worst_centre, 5e-3) << "the centre rests on the sphere";
  // the free rim drapes down around it
  double lowest = INFINITY;
  for (int i = 0; i < model.num_vertices(); ++i) lowest = std::min(lowest, x[3 * i + 2]);
  EXPECT_LT(lowest, -0.02);
  std::printf("cloth on sphere: min distance %.3g mm, centre off the sphere by %.3g mm, lowest %.3g mm, %d Newton iterations\n",
              1e3 * r.min_distance_m, 1e3 * worst_centre, 1e3 * lowest, sim.timing().newton_iterations);
}

TEST(ObstacleContact, DropWithSelfContactTooStaysIntersectionFree) {
  // A finer cloth (14 x 14) on the sphere with self contact on as well (its rim folds around the sphere), with
  // friction on both: no cloth-cloth or cloth-sphere intersection, no vertex inside.
  const TriangleMesh cloth = testing::grid_mesh(14, 0.14, 0.0);
  const ObstacleMesh sphere = testing::icosphere(2, 0.03, {0.0, 0.0, -0.035});
  ModelOptions o;
  o.handle_stiffness = 0.0;
  o.effects["self_contact"] = {{"thickness_m", 1e-3}, {"friction", 0.3}};
  Model model(cloth, o);
  model.add_term(std::make_unique<ObstacleContact>(cloth, model.area_weights(), o.density, o.gravity, sphere, 1e-3, 0.3));
  ImplicitEuler sim(model);
  RolloutOptions ro;
  ro.steps = 15;
  ro.time_step = 0.02;
  ro.record = false;
  const Eigen::VectorXd x = sim.forward(model.default_parameters(), ro);
  const ContactReport r = contact_report(cloth.faces, x, &sphere);
  EXPECT_EQ(r.intersecting_pairs, 0);
  EXPECT_GT(r.min_distance_m, 0.0);
  int inside = 0;
  for (int i = 0; i < model.num_vertices(); ++i) inside += inside_convex(sphere, x.segment<3>(3 * i));
  EXPECT_EQ(inside, 0);
  std::printf("cloth (self contact) on sphere: min distance %.3g mm, %d Newton iterations\n", 1e3 * r.min_distance_m,
              sim.timing().newton_iterations);
}

TEST(ObstacleContact, DerivativesMatchCentralDifferences) {
  const TriangleMesh cloth = testing::grid_mesh(8, 0.06, 0.0);
  const ObstacleMesh sphere = testing::icosphere(2, 0.03, {0.0, 0.0, -0.0306});
  ModelOptions o;
  Model model(cloth, o);
  auto* term = model.add_term(
      std::make_unique<ObstacleContact>(cloth, model.area_weights(), o.density, o.gravity, sphere, 1e-3));
  const Eigen::VectorXd p = model.default_parameters();
  // off the grid's symmetric positions, where closest-feature types switch (the Hessian jumps there)
  const Eigen::VectorXd x = model.rest_positions() + 5e-5 * testing::random_vector(model.num_dofs(), 3);
  ASSERT_GT(term->active_pairs(x, 1e-3).size(), 5u);
  const int n = model.num_dofs();
  const Eigen::VectorXd d = testing::random_vector(n, 5);
  const double eps = 1e-9;
  Eigen::VectorXd g = Eigen::VectorXd::Zero(n), gp = g, gm = g, Hd = g;
  term->add_gradient(x, p, g);
  const double fd = (term->energy(x + eps * d, p) - term->energy(x - eps * d, p)) / (2 * eps);
  EXPECT_NEAR(g.dot(d), fd, 1e-6 * std::abs(fd));
  term->add_gradient(x + eps * d, p, gp);
  term->add_gradient(x - eps * d, p, gm);
  term->add_hessian_product(x, p, d, Hd);
  EXPECT_LE((Hd - (gp - gm) / (2 * eps)).norm(), 1e-5 * Hd.norm());
  EXPECT_GT(Hd.norm(), 0.0);
}

TEST(ObstacleContact, FrictionDragsTheClothWithAMovingBody) {
  // A free 5 cm cloth resting 0.6 mm over a 30 cm plate (two triangles) that slides along x at 2 cm/s for 0.5 s:
  // with friction 0.5 the cloth rides along; without friction the plate slides away under it.
  const TriangleMesh cloth = testing::grid_mesh(6, 0.05, 0.0);
  ObstacleMesh plate;
  plate.positions.resize(4, 3);
  plate.positions << -0.15, -0.15, -6e-4, 0.15, -0.15, -6e-4, 0.15, 0.15, -6e-4, -0.15, 0.15, -6e-4;
  plate.faces.resize(2, 3);
  plate.faces << 0, 1, 2, 0, 2, 3;
  auto ride = [&](double mu) {
    ModelOptions o;
    o.handle_stiffness = 0.0;
    Model model(cloth, o);
    auto* term = model.add_term(
        std::make_unique<ObstacleContact>(cloth, model.area_weights(), o.density, o.gravity, plate, 1e-3, mu));
    ImplicitEuler sim(model);
    RolloutOptions ro;
    ro.steps = 1;
    ro.record = false;
    Eigen::VectorXd x = model.rest_positions(), v = Eigen::VectorXd::Zero(model.num_dofs());
    MatrixX3d at = plate.positions;
    for (int step = 0; step < 10; ++step) {
      MatrixX3d next = at;
      next.col(0).array() += 0.02 * ro.time_step;
      term->set_obstacle(at, next);
      x = sim.forward(model.default_parameters(), ro, nullptr, &x, &v);
      v = sim.velocities();
      at = next;
    }
    ObstacleMesh now{at, plate.faces};
    EXPECT_EQ(contact_report(cloth.faces, x, &now).intersecting_pairs, 0);
    double dx = 0;
    for (int i = 0; i < model.num_vertices(); ++i) dx += x[3 * i] - cloth.positions(i, 0);
    return dx / model.num_vertices();
  };
  const double with = ride(0.5), without = ride(0.0);
  EXPECT_GT(with, 8e-3) << "the plate moved 10 mm";
  EXPECT_LT(std::abs(without), 1e-3);
  std::printf("cloth on a plate sliding 10 mm: rides %.3g mm with friction 0.5, %.3g mm without\n", 1e3 * with,
              1e3 * without);
}

TEST(ObstacleContact, MovingObstacleIsSweptAndBadInputRefused) {
  const TriangleMesh cloth = testing::grid_mesh(6, 0.06, 0.0);
  ObstacleMesh sphere = testing::icosphere(1, 0.02, {0.0, 0.0, -0.03});
  ModelOptions o;
  Model model(cloth, o);
  auto* term = model.add_term(
      std::make_unique<ObstacleContact>(cloth, model.area_weights(), o.density, o.gravity, sphere, 1e-3));
  const Eigen::VectorXd p = model.default_parameters(), x = model.rest_positions();
  // the cloth moving 5 cm down onto the sphere (top at -1 cm): CCD stops it before the top
  Eigen::VectorXd dx = Eigen::VectorXd::Zero(model.num_dofs());
  for (int i = 0; i < model.num_vertices(); ++i) dx[3 * i + 2] = -0.05;
  const double alpha = term->max_step(x, dx, p);
  EXPECT_GT(alpha, 0.1);
  EXPECT_LT(alpha, 0.2);
  // the obstacle raised to just under the cloth: a cloth step down is bounded by it
  MatrixX3d raised = sphere.positions;
  raised.col(2).array() += 0.0095;
  term->set_obstacle(sphere.positions, raised);
  EXPECT_LT(term->max_step(x, dx, p), alpha);
  EXPECT_THROW(term->set_obstacle(sphere.positions, raised.topRows(3)), InputError);
  // a body passing through the cloth within one step (from 1 cm below to 1 cm above): refused, naming a pair
  MatrixX3d through = sphere.positions;
  through.col(2).array() += 0.06;
  term->set_obstacle(sphere.positions, through);
  try {
    term->begin_step(x, p, 0.05);
    FAIL() << "no error";
  } catch (const SolverError& e) {
    EXPECT_NE(std::string(e.what()).find("moves through the cloth"), std::string::npos) << e.what();
  }
  term->set_obstacle(sphere.positions, raised);  // close, not through: accepted
  term->begin_step(x, p, 0.05);
  ObstacleMesh bad = sphere;
  bad.faces(0, 0) = 999;
  EXPECT_THROW(ObstacleContact(cloth, model.area_weights(), o.density, o.gravity, bad, 1e-3), InputError);
  EXPECT_THROW(ObstacleContact(cloth, model.area_weights(), o.density, o.gravity, sphere, 0.0), InputError);
}

}  // namespace
}  // namespace drapelab
