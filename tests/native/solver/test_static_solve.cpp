// Static equilibrium: convergence, rest at equilibrium, and the implicit-function adjoint vs central differences.
#include <gtest/gtest.h>

#include "../test_support.hpp"
#include "solver/implicit_euler.hpp"
#include "solver/static_solve.hpp"
#include "util/error.hpp"

using namespace drapelab;
using namespace drapelab::testing;

TEST(StaticSolve, AdjointMatchesCentralDifferences) {
  ModelOptions o;
  o.heterogeneous = true;
  Model model(load_cusick_template(1, template_dir()), o);
  StaticSolver solver(model);
  const Eigen::VectorXd p = jittered_parameters(model, 5);
  // The adjoint is exact at an exact equilibrium; at one converged to a residual r it is off by O(r) relative
  // (the default 1e-6 of a vertex's weight reached 1e-4 against the differences on some inputs). Solve the
  // point and the differences to 1e-10.
  StaticOptions tight;
  tight.force_tolerance = 1e-10;
  const StaticResult r = solver.solve(p, tight);
  EXPECT_LT(r.residual, 1e-10);
  const Eigen::VectorXd w = random_vector(model.num_dofs(), 2);
  const Eigen::VectorXd gp = solver.adjoint(w);
  ASSERT_TRUE(gp.allFinite());
  for (unsigned s = 0; s < 3; ++s) {
    const Eigen::VectorXd dp = random_vector(static_cast<int>(p.size()), 70 + s).cwiseProduct(p);
    const double eps = 1e-6;
    // Warm start from the equilibrium so that both sides land on the same branch of equilibria.
    const double lp = w.dot(solver.solve(p + eps * dp, tight, nullptr, &r.positions).positions);
    const double lm = w.dot(solver.solve(p - eps * dp, tight, nullptr, &r.positions).positions);
    const double fd = (lp - lm) / (2 * eps);
    EXPECT_NEAR(gp.dot(dp), fd, 1e-4 * std::abs(fd)) << "direction " << s;
  }
}

TEST(StaticSolve, EquilibriumIsAtRest) {
  Model model(load_cusick_template(1, template_dir()));
  StaticSolver solver(model);
  const Eigen::VectorXd p = model.default_parameters();
  const StaticResult r = solver.solve(p);
  // One dynamic step from the equilibrium at rest stays at rest.
  ImplicitEuler sim(model);
  RolloutOptions one;
  one.steps = 1;
  Eigen::VectorXd v0 = Eigen::VectorXd::Zero(model.num_dofs());
  sim.forward(p, one, nullptr, &r.positions, &v0);
  double max_speed = 0;
  for (int i = 0; i < model.num_vertices(); ++i) max_speed = std::max(max_speed, sim.velocities().segment<3>(3 * i).norm());
  EXPECT_LT(max_speed, 1e-3);
}

TEST(StaticSolve, ReportsNonConvergence) {
  Model model(load_cusick_template(1, template_dir()));
  StaticSolver solver(model);
  StaticOptions o;
  o.max_iterations = 2;
  try {
    solver.solve(model.default_parameters(), o);
    FAIL() << "expected SolverError";
  } catch (const SolverError& e) {
    EXPECT_NE(std::string(e.what()).find("not converged"), std::string::npos) << e.what();
  }
}
