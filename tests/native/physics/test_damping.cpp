// damping with contact: its step-start state enters the contact steps' incremental potential (Newton) and the
// linearised contact iterations, and their adjoints take its x_t-derivative (Term::add_step_start_adjoint). The
// registry's suite checks each effect alone (damping's rollouts there are contact-free); here damping rides on
// disk_contact, and the rollout adjoint in mass_per_s matches central differences in both contact step modes.
#include <gtest/gtest.h>

#include "../test_support.hpp"
#include "physics/effect.hpp"
#include "solver/implicit_euler.hpp"

using namespace drapelab;
using namespace drapelab::testing;

TEST(Damping, RolloutAdjointWithDiskContactMatchesCentralDifferences) {
  ModelOptions o;
  // Frictionless: the disk's lagged friction holds its normal forces, taken at each step start, constant in the
  // adjoint (IPC's lagging, docs/physics.md), which is not the derivative of the forward once friction acts at
  // step starts (with damping and friction 0.3 here: 1-2 % off in mass_per_s and density, in both step modes).
  o.effects["disk_contact"] = {{"clamp_radius_m", 0.02}, {"friction", 0.0}};
  o.effects["damping"] = {{"mass_per_s", 6.0}};
  Model model(load_cusick_template(1, template_dir()), o);
  const Eigen::VectorXd p = model.default_parameters();
  const int k = model.layout().block(effect_block_name("damping", "mass_per_s")).offset;
  const Eigen::VectorXd w = random_vector(model.num_dofs(), 21);
  ImplicitEuler sim(model);
  for (const auto mode : {RolloutOptions::ContactStep::kLinearised, RolloutOptions::ContactStep::kNewton}) {
    SCOPED_TRACE(mode == RolloutOptions::ContactStep::kLinearised ? "linearised" : "newton");
    RolloutOptions ro;
    ro.steps = 12;
    ro.contact_step = mode;
    ro.contact_force_tolerance = 1e-10;  // Newton steps to the minimiser (at 1e-6: 1e-3 relative noise here)
    // Newton steps must reach the minimiser for the implicit-function adjoint: the landing steps take up to ~80
    // iterations with the edge term's relative dip weight and collision detection's tighter bound (43 before).
    ro.contact_max_iterations = 200;
    const Eigen::VectorXd x_damped = sim.forward(p, ro);
    const RolloutGradient g = sim.backward(w);
    RolloutOptions fo = ro;
    fo.record = false;
    Eigen::VectorXd p0 = p;
    p0[k] = 0.0;
    EXPECT_GT((sim.forward(p0, fo) - x_damped).norm(), 1e-4);  // damping moves this rollout
    const double h = 1e-5;
    Eigen::VectorXd pp = p, pm = p;
    pp[k] += h;
    pm[k] -= h;
    const double fd = (w.dot(sim.forward(pp, fo)) - w.dot(sim.forward(pm, fo))) / (2 * h);
    EXPECT_NEAR(g.parameters[k], fd, 1e-4 * std::abs(fd) + 1e-9);
    // and the density, which the damping term's masses read too
    const int d = model.layout().block("density").offset;
    const double hd = 1e-6 * p[d];
    pp = p;
    pm = p;
    pp[d] += hd;
    pm[d] -= hd;
    const double fdd = (w.dot(sim.forward(pp, fo)) - w.dot(sim.forward(pm, fo))) / (2 * hd);
    EXPECT_NEAR(g.parameters[d], fdd, 1e-4 * std::abs(fdd) + 1e-9);
  }
}
