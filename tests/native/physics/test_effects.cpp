// The effect registry's automatic suite: every registered effect, without listing them, is a no-op at its
// off value (bit for bit), and switched on at a random moderate strength its term's derivatives and the
// drape adjoints (dynamic rollout and static solve) with respect to its parameters match central
// differences on a small mesh.
#include <gtest/gtest.h>

#include <algorithm>
#include <random>

#include "../test_support.hpp"
#include "physics/effect.hpp"
#include "physics/sparse_pattern.hpp"
#include "solver/cholmod_solver.hpp"
#include "solver/implicit_euler.hpp"
#include "solver/static_solve.hpp"
#include "util/error.hpp"

using namespace drapelab;
using namespace drapelab::testing;

namespace {

double rel_err(double a, double b) { return std::abs(a - b) / std::max(1e-300, std::max(std::abs(a), std::abs(b))); }

// Tolerance of a central difference fd of dL/dq_k against an adjoint g: 1e-4 relative to the larger of |fd| and
// the largest of the effect's derivatives, each taken per prior scale (so one near-zero component, e.g. of
// prestrain's strain where the drape's response is a kink away from changing sign, is judged against the
// effect's whole sensitivity, not against its own round-off).
double adjoint_tolerance(const EffectSpec& spec, const Eigen::VectorXd& g, const std::vector<int>& idx, size_t k,
                         double fd) {
  double sensitivity = 0;
  for (size_t j = 0; j < idx.size(); ++j)
    sensitivity = std::max(sensitivity, std::abs(g[idx[j]]) * spec.parameters[j].prior_scale);
  return 1e-4 * std::max(std::abs(fd), sensitivity / spec.parameters[k].prior_scale) + 1e-9;
}

// Indices of the effect's parameters in the model's vector.
std::vector<int> effect_indices(const Model& model, const EffectSpec& spec) {
  std::vector<int> idx;
  for (const auto& q : spec.parameters) idx.push_back(model.layout().block(effect_block_name(spec.name, q.name)).offset);
  return idx;
}

bool has_contact(const Model& model) {
  for (const auto& t : model.terms())
    if (t->is_contact()) return true;
  return false;
}

// The rest state with each vertex lowered by 0.1-0.3 mm into the contact barrier's reach (0.5 mm): no vertex
// touches the disk, every free one over it feels its barrier.
Eigen::VectorXd contact_positions(const Model& model, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  Eigen::VectorXd x = model.rest_positions();
  for (int i = 0; i < model.num_vertices(); ++i) {
    x[3 * i] += 1e-4 * (u(rng) - 0.5);
    x[3 * i + 1] += 1e-4 * (u(rng) - 0.5);
    x[3 * i + 2] -= 1e-4 + 2e-4 * u(rng);
  }
  return x;
}

}  // namespace

class EffectSuite : public ::testing::TestWithParam<std::string> {};

TEST_P(EffectSuite, OffValueIsTheBaseModelBitForBit) {
  const EffectSpec& spec = find_effect(GetParam());
  ModelOptions base_options, off_options;
  off_options.effects[spec.name] = {};  // active, every parameter at its off value
  const TriangleMesh mesh = make_cusick_specimen(60);
  Model base(mesh, base_options), off(mesh, off_options);
  ASSERT_EQ(off.active_effects(), std::vector<std::string>{spec.name});
  const Eigen::VectorXd pb = base.default_parameters();
  const Eigen::VectorXd po = off.default_parameters();
  ASSERT_EQ(po.head(pb.size()), pb);  // base blocks first, unchanged
  const std::vector<int> idx = effect_indices(off, spec);
  for (size_t k = 0; k < idx.size(); ++k) EXPECT_EQ(po[idx[k]], spec.parameters[k].off) << spec.parameters[k].name;
  const Eigen::VectorXd x = perturbed_positions(base, 2e-3, 3);
  EXPECT_EQ(base.energy(x, pb), off.energy(x, po));
  Eigen::VectorXd gb = Eigen::VectorXd::Zero(x.size()), go = gb;
  base.add_gradient(x, pb, gb);
  off.add_gradient(x, po, go);
  EXPECT_EQ(gb, go);
  EXPECT_EQ(base.observe(x, pb), off.observe(x, po)) << "observation (Model::observe) differs at the off value";
  RolloutOptions ro;
  ro.steps = 5;
  ImplicitEuler sb(base), so(off);
  EXPECT_EQ(sb.forward(pb, ro), so.forward(po, ro)) << "rollout differs at the off value";
}

TEST_P(EffectSuite, TermDerivativesMatchCentralDifferencesAtModerateStrength) {
  const EffectSpec& spec = find_effect(GetParam());
  ModelOptions o;
  o.effects = moderate_effect_values(spec, 17);
  Model model(make_cusick_specimen(60), o);
  const Eigen::VectorXd p = model.default_parameters();
  // Contact effects: a collision-free state with vertices inside the barrier's reach, and a lagged friction
  // state from a step start 1 mm away (so the friction forces are active). Every model gets that step start
  // (terms with step-start state: friction, damping; the others ignore it).
  const Eigen::VectorXd x = has_contact(model) ? contact_positions(model, 5) : perturbed_positions(model, 2e-3, 5);
  Eigen::VectorXd start = x;
  for (int i = 0; i < model.num_vertices(); ++i) start[3 * i] -= 1e-3 * std::sin(i);
  for (const auto& t : model.terms()) t->begin_step(start, p, 0.05);
  const int n = model.num_dofs(), np = static_cast<int>(p.size());
  const SparsePattern& pat = model.pattern();
  for (const auto& term : model.terms()) {
    if (term->name() == "stretch" || term->name() == "bend" || term->name() == "gravity" || term->name() == "handle")
      continue;  // the base terms have their own suite (test_terms.cpp)
    SCOPED_TRACE(term->name());
    for (unsigned s = 0; s < 3; ++s) {
      const Eigen::VectorXd d = random_vector(n, 200 + s);
      // Contact barriers curve on the scale of the distances (0.2 mm here): a smaller step keeps the central
      // differences' truncation error, (eps / d)^2, below the tolerance.
      const double eps = has_contact(model) ? 1e-8 : 1e-6;
      // gradient against energy
      Eigen::VectorXd g = Eigen::VectorXd::Zero(n);
      term->add_gradient(x, p, g);
      const double fd = (term->energy(x + eps * d, p) - term->energy(x - eps * d, p)) / (2 * eps);
      EXPECT_LT(rel_err(g.dot(d), fd), 1e-6) << "gradient";
      // Hessian (assembled and product) against the gradient
      Eigen::VectorXd gp = Eigen::VectorXd::Zero(n), gm = Eigen::VectorXd::Zero(n), Hd = Eigen::VectorXd::Zero(n);
      term->add_gradient(x + eps * d, p, gp);
      term->add_gradient(x - eps * d, p, gm);
      term->add_hessian_product(x, p, d, Hd);
      Eigen::VectorXd H = Eigen::VectorXd::Zero(pat.nnz());
      term->add_hessian(x, p, 1.0, H);
      const Eigen::VectorXd fdH = (gp - gm) / (2 * eps);
      EXPECT_LE((Hd - fdH).norm(), 1e-6 * std::max(1e-12, fdH.norm()) + 1e-12 * g.norm()) << "Hessian product";
      // A term with couplings outside the pattern (self contact) assembles part of its Hessian and gives the
      // rest as a product (Term::add_offpattern_hessian_product): together, the exact Hessian.
      Eigen::VectorXd rest = Eigen::VectorXd::Zero(n);
      term->add_offpattern_hessian_product(x, p, d, false, rest);
      EXPECT_LE((symmetric_multiply(pat, H, d) + rest - Hd).norm(), 1e-10 * std::max(1e-12, Hd.norm()) + 1e-14)
          << "assembled Hessian";
      // projected Hessian and step matrix are PSD
      Eigen::VectorXd P = Eigen::VectorXd::Zero(pat.nnz()), K = Eigen::VectorXd::Zero(pat.nnz());
      term->add_projected_hessian(x, p, 1.0, P);
      term->add_step_matrix(x, p, 1.0, K);
      Eigen::VectorXd prest = Eigen::VectorXd::Zero(n);
      term->add_offpattern_hessian_product(x, p, d, true, prest);
      EXPECT_GE(d.dot(symmetric_multiply(pat, P, d)), -1e-12 * std::max(1.0, H.norm())) << "projected Hessian";
      EXPECT_GE(d.dot(symmetric_multiply(pat, P, d) + prest), -1e-12 * std::max(1.0, H.norm()))
          << "projected Hessian with its off-pattern part";
      EXPECT_GE(d.dot(symmetric_multiply(pat, K, d)), -1e-12 * std::max(1.0, H.norm())) << "step matrix";
    }
    // parameter derivatives against central differences in every parameter the term reads
    Eigen::VectorXd dEdp = Eigen::VectorXd::Zero(np), dgdp = Eigen::VectorXd::Zero(np);
    const Eigen::VectorXd lambda = random_vector(n, 300);
    term->add_energy_parameter_gradient(x, p, dEdp);
    term->add_gradient_parameter_product(x, p, lambda, 1.0, dgdp);
    for (int k = 0; k < np; ++k) {
      const double h = 1e-6 * std::max(1.0, std::abs(p[k]));
      Eigen::VectorXd pp = p, pm = p;
      pp[k] += h;
      pm[k] -= h;
      const double fdE = (term->energy(x, pp) - term->energy(x, pm)) / (2 * h);
      Eigen::VectorXd gpp = Eigen::VectorXd::Zero(n), gpm = Eigen::VectorXd::Zero(n);
      term->add_gradient(x, pp, gpp);
      term->add_gradient(x, pm, gpm);
      const double fdG = lambda.dot(gpp - gpm) / (2 * h);
      const double scaleE = std::abs(term->energy(x, p)) / std::max(1e-3, std::abs(p[k])) + 1e-14;
      EXPECT_NEAR(dEdp[k], fdE, 1e-6 * std::max(std::abs(fdE), scaleE)) << "dE/dp[" << k << "]";
      EXPECT_NEAR(dgdp[k], fdG, 1e-6 * std::max(std::abs(fdG), 1e-12)) << "d(lambda.g)/dp[" << k << "]";
    }
    // Contact terms: the step matrix's derivatives (the adjoint of linearised contact steps), phi = lambda^T K w
    // with K the assembled part plus the off-pattern remainder, against central differences in x and p.
    if (term->is_contact() && term->provides_step_matrix_derivatives()) {
      const Eigen::VectorXd wv = random_vector(n, 301), dir = random_vector(n, 302);
      auto phi = [&](const Eigen::VectorXd& xx, const Eigen::VectorXd& pp) {
        Eigen::VectorXd K = Eigen::VectorXd::Zero(pat.nnz()), rest = Eigen::VectorXd::Zero(n);
        term->add_step_matrix(xx, pp, 1.0, K);
        term->add_offpattern_step_matrix_product(xx, pp, wv, rest);
        return lambda.dot(symmetric_multiply(pat, K, wv) + rest);
      };
      Eigen::VectorXd gx = Eigen::VectorXd::Zero(n), gK = Eigen::VectorXd::Zero(np);
      term->add_step_matrix_derivatives(x, p, lambda, wv, 1.0, gx, gK);
      const double eps = 1e-8;
      const double fdx = (phi(x + eps * dir, p) - phi(x - eps * dir, p)) / (2 * eps);
      EXPECT_NEAR(gx.dot(dir), fdx, 1e-5 * std::max(std::abs(fdx), 1e-12)) << "d(lambda^T K w)/dx";
      for (int k = 0; k < np; ++k) {
        const double h = 1e-6 * std::max(1e-3, std::abs(p[k]));
        Eigen::VectorXd pp = p, pm = p;
        pp[k] += h;
        pm[k] -= h;
        const double fdp = (phi(x, pp) - phi(x, pm)) / (2 * h);
        EXPECT_NEAR(gK[k], fdp, 1e-5 * std::max(std::abs(fdp), 1e-12)) << "d(lambda^T K w)/dp[" << k << "]";
      }
      // K with its remainder is symmetric positive semidefinite
      Eigen::VectorXd K = Eigen::VectorXd::Zero(pat.nnz()), rd = Eigen::VectorXd::Zero(n),
                      rw = Eigen::VectorXd::Zero(n);
      term->add_step_matrix(x, p, 1.0, K);
      term->add_offpattern_step_matrix_product(x, p, dir, rd);
      term->add_offpattern_step_matrix_product(x, p, wv, rw);
      const Eigen::VectorXd Kd = symmetric_multiply(pat, K, dir) + rd, Kw = symmetric_multiply(pat, K, wv) + rw;
      EXPECT_NEAR(wv.dot(Kd), dir.dot(Kw), 1e-10 * std::max(1e-12, Kd.norm() * wv.norm())) << "K symmetric";
      EXPECT_GE(dir.dot(Kd), -1e-12 * std::max(1.0, K.norm())) << "K with its remainder PSD";
    }
    // The step start's adjoint (Term::add_step_start_adjoint): the x_t-derivative of lambda . grad E(x) +
    // c lambda^T K(x) w at fixed x, against central differences in x_t (begin_step at x_t +- eps d). Contact
    // terms hold their lagged normal forces and tangent planes constant there (IPC's lagging), which a moved
    // begin_step does not: they are checked through the rollout adjoints instead.
    if (!term->is_contact()) {
      const Eigen::VectorXd wv = random_vector(n, 303), dir = random_vector(n, 304);
      const double c = 0.05 * 0.05;
      auto phi = [&](const Eigen::VectorXd& xt) {
        term->begin_step(xt, p, 0.05);
        Eigen::VectorXd g = Eigen::VectorXd::Zero(n), K = Eigen::VectorXd::Zero(pat.nnz());
        term->add_gradient(x, p, g);
        term->add_step_matrix(x, p, 1.0, K);
        return lambda.dot(g) + c * lambda.dot(symmetric_multiply(pat, K, wv));
      };
      const double eps = 1e-6;
      const double fd = (phi(start + eps * dir) - phi(start - eps * dir)) / (2 * eps);
      term->begin_step(start, p, 0.05);
      Eigen::VectorXd gxt = Eigen::VectorXd::Zero(n);
      term->add_step_start_adjoint(x, p, lambda, wv, c, gxt);
      EXPECT_NEAR(gxt.dot(dir), fd, 1e-6 * std::max(std::abs(fd), 1e-12)) << "step start adjoint";
    }
  }
}

// An effect's position transform before the render (EffectSpec::make_observation: camera, offset): its
// vector-Jacobian products in positions and in every parameter against central differences.
TEST_P(EffectSuite, ObservationDerivativesMatchCentralDifferences) {
  const EffectSpec& spec = find_effect(GetParam());
  if (!spec.make_observation) GTEST_SKIP() << "no observation";
  ModelOptions o;
  o.effects = moderate_effect_values(spec, 23);
  Model model(make_cusick_specimen(60), o);
  ASSERT_TRUE(model.has_observation());
  const Eigen::VectorXd p = model.default_parameters();
  Eigen::VectorXd x = perturbed_positions(model, 2e-3, 6);
  for (int i = 0; i < model.num_vertices(); ++i) x[3 * i + 2] -= 0.05 * model.mesh().uv.row(i).norm();  // a skirt
  const int n = model.num_dofs(), np = static_cast<int>(p.size());
  const Eigen::VectorXd gy = random_vector(n, 401), d = random_vector(n, 402);
  Eigen::VectorXd gx = Eigen::VectorXd::Zero(n), gp = Eigen::VectorXd::Zero(np);
  model.add_observe_vjp(x, p, gy, gx, gp);
  const Eigen::VectorXd y = model.observe(x, p);
  EXPECT_GT((y - x).norm(), 1e-6) << "the observation at a moderate strength changes the positions";
  const double eps = 1e-6;
  const double fdx = (gy.dot(model.observe(x + eps * d, p)) - gy.dot(model.observe(x - eps * d, p))) / (2 * eps);
  EXPECT_NEAR(gx.dot(d), fdx, 1e-7 * std::max(1.0, std::abs(fdx))) << "d/dx";
  for (int k = 0; k < np; ++k) {
    const double h = 1e-6 * std::max(1.0, std::abs(p[k]));
    Eigen::VectorXd pp = p, pm = p;
    pp[k] += h;
    pm[k] -= h;
    const double fd = (gy.dot(model.observe(x, pp)) - gy.dot(model.observe(x, pm))) / (2 * h);
    EXPECT_NEAR(gp[k], fd, 1e-6 * std::max(1.0, std::abs(fd))) << "d/dp[" << k << "]";
  }
}

TEST_P(EffectSuite, DrapeAdjointsMatchCentralDifferencesInTheEffectParameters) {
  const EffectSpec& spec = find_effect(GetParam());
  ModelOptions o;
  o.effects = moderate_effect_values(spec, 29);
  Model model(load_cusick_template(1, template_dir()), o);
  const Eigen::VectorXd p = model.default_parameters();
  const Eigen::VectorXd w = random_vector(model.num_dofs(), 8);
  const std::vector<int> idx = effect_indices(model, spec);
  // L = w . observe(x(p), p): the drape's adjoint of dL/dx plus the observation's direct dL/dp (identity and 0
  // for effects without one).
  auto loss = [&](const Eigen::VectorXd& x, const Eigen::VectorXd& pp) { return w.dot(model.observe(x, pp)); };
  auto chain = [&](const Eigen::VectorXd& x, const Eigen::VectorXd& pp, Eigen::VectorXd& direct) {
    Eigen::VectorXd gx = Eigen::VectorXd::Zero(model.num_dofs());
    direct = Eigen::VectorXd::Zero(pp.size());
    model.add_observe_vjp(x, pp, w, gx, direct);
    return gx;
  };
  // Dynamic rollout (20 steps of 0.05 s); with contact, in both step modes (linearised, Newton to the minimiser).
  ImplicitEuler sim(model);
  const bool contact = has_contact(model);
  for (const auto mode : {RolloutOptions::ContactStep::kLinearised, RolloutOptions::ContactStep::kNewton}) {
    if (!contact && mode != RolloutOptions::ContactStep::kLinearised) continue;
    const char* label = mode == RolloutOptions::ContactStep::kLinearised ? "rollout, " : "rollout (newton), ";
    RolloutOptions ro;
    ro.steps = 20;
    ro.contact_step = mode;
    const Eigen::VectorXd xf = sim.forward(p, ro);
    Eigen::VectorXd direct;
    RolloutGradient g = sim.backward(chain(xf, p, direct));
    g.parameters += direct;
    RolloutOptions fo = ro;
    fo.record = false;
    // Step 1e-6 in the parameter's own scale (its prior scale, when below 1): the rollout map is only piecewise
    // smooth (the step matrix's positive parts switch), and prestrain's compressed rest state (strain < 0) puts
    // kinks within 1e-6 of a strain of scale 0.02; at 2e-8 central differences agree with the adjoint to 1e-6.
    for (size_t k = 0; k < idx.size(); ++k) {
      if (spec.parameters[k].structural) continue;  // fixed by the model's structure: no gradient
      const double h = 1e-6 * std::min(1.0, spec.parameters[k].prior_scale) * std::max(1.0, std::abs(p[idx[k]]));
      Eigen::VectorXd pp = p, pm = p;
      pp[idx[k]] += h;
      pm[idx[k]] -= h;
      const double fd = (loss(sim.forward(pp, fo), pp) - loss(sim.forward(pm, fo), pm)) / (2 * h);
      EXPECT_NEAR(g.parameters[idx[k]], fd, adjoint_tolerance(spec, g.parameters, idx, k, fd))
          << label << spec.parameters[k].name;
    }
  }
  // Static equilibrium (implicit-function adjoint), warm-started so both sides stay on one branch.
  StaticSolver solver(model);
  StaticOptions tight;
  tight.force_tolerance = 1e-10;
  const StaticResult r = solver.solve(p, tight);
  Eigen::VectorXd direct;
  const Eigen::VectorXd gs = solver.adjoint(chain(r.positions, p, direct)) + direct;
  // Step 1e-4 in the parameter's own scale (its prior scale, when below 1): each solve stops at a residual of
  // 1e-10 vertex weights, so L carries noise of ~1e-10 relative, amplified by 1/h; the truncation error is
  // O(h^2). Both stay below 1e-5 relative here, against the 1e-4 tolerance (at h = 1e-7 the noise alone reached
  // 2e-4). A small-scale parameter needs the smaller step: the drape's response to prestrain's strain (scale
  // 0.02) bends within 1e-4, where a unit step left a 2.6 % truncation error.
  for (size_t k = 0; k < idx.size(); ++k) {
    if (spec.parameters[k].structural) continue;
    const double h = 1e-4 * std::min(1.0, spec.parameters[k].prior_scale) * std::max(1.0, std::abs(p[idx[k]]));
    Eigen::VectorXd pp = p, pm = p;
    pp[idx[k]] += h;
    pm[idx[k]] -= h;
    const double lp = loss(solver.solve(pp, tight, nullptr, &r.positions).positions, pp);
    const double lm = loss(solver.solve(pm, tight, nullptr, &r.positions).positions, pm);
    const double fd = (lp - lm) / (2 * h);
    EXPECT_NEAR(gs[idx[k]], fd, adjoint_tolerance(spec, gs, idx, k, fd)) << "static, " << spec.parameters[k].name;
  }
}

INSTANTIATE_TEST_SUITE_P(Registry, EffectSuite, ::testing::ValuesIn(registered_effect_names()),
                         [](const ::testing::TestParamInfo<std::string>& info) { return info.param; });

TEST(EffectRegistry, SpecsAreComplete) {
  ASSERT_FALSE(effect_registry().empty());
  for (const auto& e : effect_registry()) {
    SCOPED_TRACE(e.name);
    EXPECT_FALSE(e.explanation.empty());
    EXPECT_FALSE(e.signature.empty());
    ASSERT_FALSE(e.parameters.empty());
    EXPECT_TRUE(e.make_terms);
    for (const auto& q : e.parameters) {
      EXPECT_FALSE(q.unit.empty()) << q.name;
      EXPECT_TRUE(q.lower <= q.off && q.off <= q.upper) << q.name;
      EXPECT_TRUE(q.lower <= q.moderate && q.moderate <= q.upper && q.moderate != q.off) << q.name;
      EXPECT_GT(q.prior_scale, 0) << q.name;
    }
    for (const auto& [name, value] : e.second_direction) {  // a non-primary parameter, inside its bounds
      EXPECT_NE(name, e.parameters.front().name);
      EXPECT_NO_THROW(check_effect_value(e, name, value)) << name;
    }
    for (const auto& name : e.step_parameters) {  // the step test's parameters: the effect's own, with a moderate
      const auto it = std::find_if(e.parameters.begin(), e.parameters.end(),
                                   [&](const EffectParameter& q) { return q.name == name; });
      ASSERT_NE(it, e.parameters.end()) << name;
      EXPECT_NE(it->moderate, it->off) << name;
    }
    if (e.step_diagonals) EXPECT_EQ(e.step_parameters.size(), 2u) << e.name;  // the diagonals of their plane
    EXPECT_GE(e.search_grid_spacing, 0.0) << e.name;
    if (e.search_grid_spacing > 0) {  // a grid over the plane of two step parameters, at least one spacing wide
      EXPECT_EQ(e.step_parameters.size(), 2u) << e.name;
      EXPECT_GE(e.search_grid_reach, e.search_grid_spacing) << e.name;
    }
  }
}

TEST(EffectRegistry, BadNamesAndValuesAreErrorsNamingTheField) {
  const TriangleMesh mesh = make_cusick_specimen(40);
  ModelOptions o;
  o.effects["no_such_effect"] = {};
  try {
    Model m(mesh, o);
    FAIL();
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("no_such_effect"), std::string::npos);
    EXPECT_NE(std::string(e.what()).find(effect_registry().front().name), std::string::npos) << e.what();
  }
  const EffectSpec& first = effect_registry().front();
  o.effects.clear();
  o.effects[first.name]["no_such_parameter"] = 1.0;
  try {
    Model m(mesh, o);
    FAIL();
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("no_such_parameter"), std::string::npos) << e.what();
  }
  o.effects.clear();
  const EffectParameter& q = first.parameters.front();
  o.effects[first.name][q.name] = std::isfinite(q.upper) ? q.upper + 1.0 : std::nan("");
  try {
    Model m(mesh, o);
    FAIL();
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find(q.name), std::string::npos) << e.what();
  }
  // Out of range in a parameter vector: refused at validation, naming the block.
  o.effects.clear();
  o.effects[first.name] = {};
  Model m(mesh, o);
  Eigen::VectorXd p = m.default_parameters();
  p[m.layout().block(effect_block_name(first.name, q.name)).offset] = std::nan("");
  try {
    m.validate_parameters(p);
    FAIL();
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find(q.name), std::string::npos) << e.what();
  }
}

namespace {

// Every registered effect without contact terms, on at `values` (or at its off values where `values` has none):
// the diagnosis's joint model.
ModelOptions all_effects_without_contact(unsigned moderate_seed = 0) {
  ModelOptions o;
  for (const auto& e : effect_registry()) {
    ModelOptions one;
    one.effects[e.name] = {};
    if (has_contact(Model(make_cusick_specimen(30), one))) continue;
    o.effects[e.name] = moderate_seed ? moderate_effect_values(e, moderate_seed + 1)[e.name] : EffectValues::mapped_type{};
  }
  return o;
}

}  // namespace

// Term::reads_parameters (the backward's alternatives recompute only the terms that say yes): a term whose energy,
// force or step matrix changes with a parameter says it reads it. Every effect on at a moderate strength, every
// parameter of the layout.
TEST(EffectRegistry, TermsSayWhichParametersTheyRead) {
  const Model model(make_cusick_specimen(40), all_effects_without_contact(41));
  const Eigen::VectorXd p = model.default_parameters();
  const Eigen::VectorXd x = perturbed_positions(model, 2e-3, 9);
  Eigen::VectorXd start = x;
  for (int i = 0; i < model.num_vertices(); ++i) start[3 * i] -= 1e-3 * std::sin(i);
  for (const auto& t : model.terms()) t->begin_step(start, p, 0.05);
  const int n = model.num_dofs(), nnz = static_cast<int>(model.pattern().nnz());
  int read = 0;
  for (int i = 0; i < p.size(); ++i) {
    Eigen::VectorXd q = p;
    q[i] += 1e-3 * std::max(1.0, std::abs(p[i]));
    std::vector<char> mask(p.size(), 0);
    mask[i] = 1;
    for (const auto& term : model.terms()) {
      Eigen::VectorXd gp = Eigen::VectorXd::Zero(n), gq = gp, kp = Eigen::VectorXd::Zero(nnz), kq = kp;
      term->add_gradient(x, p, gp);
      term->add_gradient(x, q, gq);
      term->add_step_matrix(x, p, 1.0, kp);
      term->add_step_matrix(x, q, 1.0, kq);
      const bool changes = term->energy(x, p) != term->energy(x, q) || gp != gq || kp != kq;
      if (changes) {
        EXPECT_TRUE(term->reads_parameters(mask)) << term->name() << " changes with parameter " << i;
        ++read;
      }
    }
  }
  EXPECT_GT(read, 0);
}

// ImplicitEuler::backward's alternatives, as the diagnosis uses them: the registry's second directions (a tilt's
// azimuth at zero angle) scored from the one adjoint equal the adjoint of their own rollout, on the joint model
// with every effect at its off value; the main gradient is unchanged bit for bit; a changed density is refused.
TEST(EffectRegistry, SecondDirectionsFromOneAdjointMatchTheirOwnRollout) {
  const Model model(make_cusick_specimen(60), all_effects_without_contact());
  const Eigen::VectorXd p = model.default_parameters();
  RolloutOptions ro;
  ro.steps = 12;
  const Eigen::VectorXd v0 = 0.05 * random_vector(model.num_dofs(), 7);
  const Eigen::VectorXd seed = random_vector(model.num_dofs(), 8);
  int tested = 0;
  for (const auto& e : effect_registry()) {
    if (e.second_direction.empty()) continue;
    SCOPED_TRACE(e.name);
    Eigen::VectorXd q = p;
    for (const auto& [name, value] : e.second_direction)
      q[model.layout().block(effect_block_name(e.name, name)).offset] = value;
    ASSERT_NE(q, p);
    ImplicitEuler at_p(model), at_q(model);
    const Eigen::VectorXd xp = at_p.forward(p, ro, nullptr, nullptr, &v0);
    ASSERT_EQ(xp, at_q.forward(q, ro, nullptr, nullptr, &v0)) << "the caller's promise: the same rollout";
    const Eigen::VectorXd plain = at_p.backward(seed).parameters;
    std::vector<Eigen::VectorXd> alternatives{q}, grads;
    const RolloutGradient g = at_p.backward(seed, nullptr, nullptr, &alternatives, &grads);
    EXPECT_EQ(g.parameters, plain);
    const Eigen::VectorXd direct = at_q.backward(seed).parameters;
    ASSERT_EQ(grads.size(), 1u);
    EXPECT_LE((grads[0] - direct).norm(), 1e-10 * direct.norm());
    const int primary = model.layout().block(effect_block_name(e.name, e.parameters.front().name)).offset;
    EXPECT_NEAR(grads[0][primary], direct[primary], 1e-9 * std::abs(direct[primary]));
    EXPECT_GT(std::abs(direct[primary] - plain[primary]), 1e-3 * std::abs(plain[primary]))
        << "the turned direction scores differently";
    Eigen::VectorXd heavier = q;
    heavier[model.layout().block("density").offset] *= 1.1;
    alternatives = {heavier};
    EXPECT_THROW(at_p.backward(seed, nullptr, nullptr, &alternatives, &grads), InputError);
    ++tested;
  }
  EXPECT_GT(tested, 0);
}
