// The disk_contact effect in whole drapes: the specimen ends on the disk, never below it, and drapes
// differently from the base model (rigid 9 cm handle); the static solve reaches the same kind of state.
#include <gtest/gtest.h>

#include <chrono>

#include "../test_support.hpp"
#include "contact/distance.hpp"
#include "physics/effect.hpp"
#include "solver/implicit_euler.hpp"
#include "solver/static_solve.hpp"
#include "util/error.hpp"
#include "geometry/cusick.hpp"

namespace drapelab {
namespace {


using testing::template_dir;

// Signed clearance of every vertex that may touch the disk (rest radius between the clamp and the edge) above
// the disk's surface (disk_contact.cpp places its top face 0.5 mm below the rest plane).
double min_clearance(const Model& model, const Eigen::VectorXd& x, double clamp, double rim) {
  SupportDisk disk;
  disk.radius = model.options().support_radius;
  disk.rim_radius = rim;
  disk.top = -5e-4;
  double worst = INFINITY;
  for (int i = 0; i < model.num_vertices(); ++i) {
    const double r = model.mesh().uv.row(i).norm();
    if (r < clamp || r >= disk.radius) continue;
    worst = std::min(worst, support_disk_distance(disk, x.data() + 3 * i));
  }
  return worst;
}

double drape_coefficient_proxy(const Model& model, const Eigen::VectorXd& x) {
  // mean horizontal radius of the outermost ring, over the specimen radius (a silhouette-free proxy)
  double rmax = 0, sum = 0;
  int count = 0;
  for (int i = 0; i < model.num_vertices(); ++i) rmax = std::max(rmax, model.mesh().uv.row(i).norm());
  for (int i = 0; i < model.num_vertices(); ++i)
    if (model.mesh().uv.row(i).norm() > rmax - 1e-6) {
      sum += std::hypot(x[3 * i], x[3 * i + 1]);
      ++count;
    }
  return sum / count / rmax;
}

TEST(DiskContactDrape, RolloutStaysAboveTheDiskAndDiffersFromTheRigidHandle) {
  const TriangleMesh mesh = load_cusick_template(1, template_dir());
  ModelOptions base_options, contact_options;
  contact_options.effects["disk_contact"] = {{"clamp_radius_m", 0.02}, {"friction", 0.3}};
  Model base(mesh, base_options), contact(mesh, contact_options);
  RolloutOptions ro;
  ro.steps = 40;
  ro.record = false;
  ImplicitEuler sb(base), sc(contact);
  const Eigen::VectorXd xb = sb.forward(base.default_parameters(), ro);
  const Eigen::VectorXd xc = sc.forward(contact.default_parameters(), ro);
  const double clearance = min_clearance(contact, xc, 0.02, 0.002);
  EXPECT_GT(clearance, 0.0) << "a vertex reached the disk";
  EXPECT_LT(clearance, 5e-4) << "the free part should rest on the disk (within the barrier's reach)";
  // The free annulus lies on the disk: it carries its weight by the barrier, not by the handle.
  const double rb = drape_coefficient_proxy(base, xb), rc = drape_coefficient_proxy(contact, xc);
  EXPECT_TRUE(std::isfinite(rc));
  EXPECT_NE(rb, rc);
  std::printf("disk contact drape (circle1, 40 steps): clearance %.3g mm, outer radius ratio %.4f (rigid handle %.4f), "
              "%d Newton iterations\n",
              1e3 * clearance, rc, rb, sc.timing().newton_iterations);
}

TEST(DiskContactDrape, StaticSolveConvergesAboveTheDisk) {
  const TriangleMesh mesh = load_cusick_template(1, template_dir());
  ModelOptions o;
  o.effects["disk_contact"] = {{"clamp_radius_m", 0.03}};
  Model model(mesh, o);
  StaticSolver solver(model);
  const StaticResult r = solver.solve(model.default_parameters());
  EXPECT_GT(min_clearance(model, r.positions, 0.03, 0.002), 0.0);
  EXPECT_LT(r.residual, 1e-6);
}

TEST(DiskContactDrape, ModelRejectsAClampThatHoldsNothingAndAStructuralMismatch) {
  const TriangleMesh mesh = load_cusick_template(1, template_dir());
  ModelOptions o;
  o.effects["disk_contact"] = {{"clamp_radius_m", 0.005}};
  EXPECT_THROW(Model(mesh, o), InputError);  // no vertex inside a 5 mm clamp on circle1
  o.effects["disk_contact"] = {{"clamp_radius_m", 0.03}};
  Model model(mesh, o);
  Eigen::VectorXd p = model.default_parameters();
  p[model.layout().block("disk_contact.clamp_radius_m").offset] = 0.04;
  EXPECT_THROW(model.validate_parameters(p), InputError);
}

// disk_friction's step-start adjoint (Term::add_step_start_adjoint): the x_t-derivative of
// lambda . grad E(x) + c lambda^T K(x) w at fixed x, where the term began its step at x_t (the slip's start, the
// lagged normal force and tangent plane), against central differences of begin_step's x_t.
TEST(DiskContactDrape, FrictionStepStartAdjointMatchesCentralDifferences) {
  const TriangleMesh mesh = load_cusick_template(1, template_dir());
  ModelOptions o;
  o.effects["disk_contact"] = {{"clamp_radius_m", 0.02}, {"friction", 0.3}};
  Model model(mesh, o);
  const Eigen::VectorXd p = model.default_parameters();
  const int n = model.num_dofs();
  Term* term = nullptr;
  for (const auto& t : model.terms())
    if (t->name() == "disk_friction") term = t.get();
  ASSERT_NE(term, nullptr);
  Eigen::VectorXd xt = model.rest_positions();
  const Eigen::VectorXd jitter = testing::random_vector(n, 31);
  for (int i = 0; i < model.num_vertices(); ++i) xt[3 * i + 2] -= 2e-4 + 1e-4 * jitter[3 * i + 2];
  const double h = 0.01;
  for (double slip : {2e-6, 1e-4}) {  // within the stick zone (eps_v h = 1e-5 m) and sliding
    const Eigen::VectorXd x = xt + slip * testing::random_vector(n, 32);
    const Eigen::VectorXd lambda = testing::random_vector(n, 33), w = testing::random_vector(n, 34);
    const double c = 0.7;
    auto phi = [&](const Eigen::VectorXd& start) {
      term->begin_step(start, p, h);
      Eigen::VectorXd g = Eigen::VectorXd::Zero(n), Kw = Eigen::VectorXd::Zero(n);
      term->add_gradient(x, p, g);
      EXPECT_TRUE(term->add_step_matrix_product(x, p, w, 1.0, Kw));
      return lambda.dot(g) + c * lambda.dot(Kw);
    };
    const Eigen::VectorXd d = testing::random_vector(n, 35);
    const double e = 1e-9;
    const double fd = (phi(xt + e * d) - phi(xt - e * d)) / (2 * e);
    term->begin_step(xt, p, h);
    Eigen::VectorXd gxt = Eigen::VectorXd::Zero(n);
    term->add_step_start_adjoint(x, p, lambda, w, c, gxt);
    std::printf("disk friction start adjoint (slip %g m): %.9g, central difference %.9g\n", slip, gxt.dot(d), fd);
    EXPECT_NEAR(gxt.dot(d), fd, 1e-5 * std::abs(fd)) << "slip " << slip;
  }
}

}  // namespace
}  // namespace drapelab
