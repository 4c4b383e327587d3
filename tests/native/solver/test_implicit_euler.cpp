// The rollout adjoint against central differences of the whole 100-step rollout.
#include <gtest/gtest.h>

#include "../test_support.hpp"
#include "solver/implicit_euler.hpp"

using namespace drapelab;
using namespace drapelab::testing;

namespace {
TriangleMesh circle1() { return load_cusick_template(1, template_dir()); }
}  // namespace

namespace {
// L = w . x_T after the paper's 100-step rollout; adjoint against central differences along random
// (relative) directions. Relative steps of 1e-7: the tables are piecewise linear, and a strongly
// heterogeneous drape bifurcates (folds), so at 1e-4..1e-5 differences disagree with each other.
void check_rollout_gradient(const Eigen::VectorXd& p, Model& model, const RolloutOptions& ro) {
  ImplicitEuler sim(model);
  const Eigen::VectorXd w = random_vector(model.num_dofs(), 1);
  sim.forward(p, ro);
  const RolloutGradient g = sim.backward(w);
  ASSERT_TRUE(g.parameters.allFinite());
  RolloutOptions fo = ro;
  fo.record = false;
  for (unsigned s = 0; s < 3; ++s) {
    const Eigen::VectorXd dp = random_vector(static_cast<int>(p.size()), 50 + s).cwiseProduct(p);
    const double eps = 1e-7;
    const double lp = w.dot(sim.forward(p + eps * dp, fo));
    const double lm = w.dot(sim.forward(p - eps * dp, fo));
    const double fd = (lp - lm) / (2 * eps);
    const double an = g.parameters.dot(dp);
    EXPECT_NEAR(an, fd, 1e-4 * std::abs(fd)) << "direction " << s;
  }
}
}  // namespace

TEST(ImplicitEuler, RolloutGradientMatchesCentralDifferences) {
  ModelOptions o;
  o.heterogeneous = true;
  Model model(circle1(), o);
  check_rollout_gradient(jittered_parameters(model, 3), model, RolloutOptions());
}

TEST(ImplicitEuler, RolloutGradientMatchesCentralDifferencesUnderStrongHeterogeneity) {
  // Per-element stiffness factors exp(N(0, 1)) (0.05-20x): the regime of BDP draws, where the drape folds.
  ModelOptions o;
  o.heterogeneous = true;
  Model model(circle1(), o);
  check_rollout_gradient(lognormal_element_parameters(model, 1.0, 4), model, RolloutOptions());
}

TEST(ImplicitEuler, FactorMemoryBudgetGivesTheSameGradient) {
  // Factors kept for every step, for some, or for none (the backward refactorises): the same gradient.
  ModelOptions o;
  o.heterogeneous = true;
  Model model(circle1(), o);
  ImplicitEuler sim(model);
  const Eigen::VectorXd p = jittered_parameters(model, 4);
  const Eigen::VectorXd w = random_vector(model.num_dofs(), 6);
  RolloutOptions ro;
  ro.steps = 12;
  sim.forward(p, ro);
  const RolloutGradient all = sim.backward(w);
  const double factor_mb = sim.linear_solver().kept_factor_bytes() / 1048576.0;
  for (double budget : {0.0, 4.5 * factor_mb}) {
    ro.factor_memory_mb = budget;
    sim.forward(p, ro);
    const RolloutGradient g = sim.backward(w);
    EXPECT_LT((g.parameters - all.parameters).norm(), 1e-13 * all.parameters.norm()) << "budget " << budget;
    EXPECT_LT((g.positions0 - all.positions0).norm(), 1e-13 * all.positions0.norm()) << "budget " << budget;
    EXPECT_LT((g.velocities0 - all.velocities0).norm(), 1e-13 * all.velocities0.norm()) << "budget " << budget;
  }
}

TEST(ImplicitEuler, RepeatedRolloutsReuseFactorBuffersExactly) {
  // The second and third rollouts write their kept factors into the buffers released by the earlier ones
  // (longer, then shorter): the gradients are identical to a fresh simulator's.
  Model model(circle1());
  const Eigen::VectorXd p = model.default_parameters();
  const Eigen::VectorXd w = random_vector(model.num_dofs(), 8);
  RolloutOptions ro;
  ro.steps = 9;
  ImplicitEuler fresh(model);
  fresh.forward(p, ro);
  const RolloutGradient expected = fresh.backward(w);
  ImplicitEuler sim(model);
  RolloutOptions longer = ro;
  longer.steps = 14;
  sim.forward(p, longer);
  sim.backward(w);
  for (int repeat = 0; repeat < 2; ++repeat) {
    sim.forward(p, ro);
    const RolloutGradient g = sim.backward(w);
    EXPECT_EQ(g.parameters, expected.parameters) << "repeat " << repeat;
    EXPECT_EQ(g.positions0, expected.positions0) << "repeat " << repeat;
    EXPECT_EQ(g.velocities0, expected.velocities0) << "repeat " << repeat;
  }
}
