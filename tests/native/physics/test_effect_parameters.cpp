// Every term of a model with an effect switched on, the base terms included: an effect may change a base term
// from inside (physics/base_term_changes.hpp: prestrain's rest scaling of the stretch term, heterogeneity_map's
// multiplier on the bend term), which test_terms.cpp (base models) and the per-effect term check of
// test_effects.cpp (the effect's own terms) do not see. For every registered effect at a moderate strength,
// homogeneous and heterogeneous, each term's derivatives in positions and in the effect's parameters match
// central differences, its step matrix is PSD, and its fused kernels (step system, step adjoint) agree with
// the separate products.
#include <gtest/gtest.h>

#include <random>

#include "../test_support.hpp"
#include "physics/effect.hpp"
#include "physics/sparse_pattern.hpp"
#include "solver/cholmod_solver.hpp"

using namespace drapelab;
using namespace drapelab::testing;

namespace {

double near_tolerance(double reference, double scale, double rel) { return rel * std::max(std::abs(reference), scale); }

// lambda^T K(x; p) w with K assembled.
double step_form(const Term& t, const SparsePattern& pat, const Eigen::VectorXd& x, const Eigen::VectorXd& p,
                 const Eigen::VectorXd& lambda, const Eigen::VectorXd& w) {
  Eigen::VectorXd K = Eigen::VectorXd::Zero(pat.nnz());
  t.add_step_matrix(x, p, 1.0, K);
  return lambda.dot(symmetric_multiply(pat, K, w));
}

}  // namespace

class EffectParameters : public ::testing::TestWithParam<std::tuple<std::string, bool>> {};

TEST_P(EffectParameters, EveryTermIsExactInPositionsAndEffectParameters) {
  const EffectSpec& spec = find_effect(std::get<0>(GetParam()));
  ModelOptions o;
  o.heterogeneous = std::get<1>(GetParam());
  o.effects = moderate_effect_values(spec, 41);
  Model model(make_cusick_specimen(60), o);
  const Eigen::VectorXd p = o.heterogeneous ? jittered_parameters(model, 3) : model.default_parameters();
  // keep the effect's own values as set (jitter only the material)
  Eigen::VectorXd pe = p;
  for (const auto& q : spec.parameters) {
    const int k = model.layout().block(effect_block_name(spec.name, q.name)).offset;
    pe[k] = o.effects[spec.name][q.name];
  }
  const Eigen::VectorXd x = perturbed_positions(model, 2e-3, 7);
  const int n = model.num_dofs();
  // A step start 1 mm away for terms with step-start state (damping; contact terms keep their own suite there).
  Eigen::VectorXd start = x;
  for (int i = 0; i < model.num_vertices(); ++i) start[3 * i] -= 1e-3 * std::sin(i);
  for (const auto& term : model.terms())
    if (!term->is_contact()) term->begin_step(start, pe, 0.05);
  const SparsePattern& pat = model.pattern();
  const Eigen::VectorXd lambda = random_vector(n, 11), w = random_vector(n, 12), d = random_vector(n, 13);
  // Small steps: a strain shifted by the prestrain lies near the stretch table's grid nodes (0 +- 0.025), where
  // the C1 blend's second derivative jumps; a step of 1e-6 that straddles one misses the Hessian by percent.
  const double eps = 1e-7;
  for (const auto& term : model.terms()) {
    SCOPED_TRACE(term->name());
    const Term& t = *term;
    // positions
    Eigen::VectorXd g = Eigen::VectorXd::Zero(n), gp = g, gm = g, Hd = g;
    t.add_gradient(x, pe, g);
    const double fdE = (t.energy(x + eps * d, pe) - t.energy(x - eps * d, pe)) / (2 * eps);
    EXPECT_NEAR(g.dot(d), fdE, near_tolerance(fdE, 1e-3 * g.norm() * d.norm() * eps, 1e-6)) << "gradient";
    t.add_gradient(x + eps * d, pe, gp);
    t.add_gradient(x - eps * d, pe, gm);
    t.add_hessian_product(x, pe, d, Hd);
    const Eigen::VectorXd fdH = (gp - gm) / (2 * eps);
    EXPECT_LE((Hd - fdH).norm(), 1e-6 * std::max(1e-12, fdH.norm()) + 1e-12 * g.norm()) << "Hessian product";
    Eigen::VectorXd K = Eigen::VectorXd::Zero(pat.nnz());
    t.add_step_matrix(x, pe, 1.0, K);
    EXPECT_GE(d.dot(symmetric_multiply(pat, K, d)), -1e-12 * std::max(1.0, K.norm())) << "step matrix PSD";
    Eigen::VectorXd Kd = Eigen::VectorXd::Zero(n);
    if (t.add_step_matrix_product(x, pe, d, 1.0, Kd)) {
      const Eigen::VectorXd ref = symmetric_multiply(pat, K, d);
      EXPECT_LE((Kd - ref).norm(), 1e-10 * std::max(1e-14, ref.norm())) << "step matrix product";
    }
    // d(lambda^T K w)/dx against central differences along d
    Eigen::VectorXd gx = Eigen::VectorXd::Zero(n), gpar = Eigen::VectorXd::Zero(pe.size());
    t.add_step_matrix_derivatives(x, pe, lambda, w, 1.0, gx, gpar);
    const double fdK = (step_form(t, pat, x + eps * d, pe, lambda, w) - step_form(t, pat, x - eps * d, pe, lambda, w)) /
                       (2 * eps);
    EXPECT_NEAR(gx.dot(d), fdK, near_tolerance(fdK, 1e-8 * gx.norm() * d.norm(), 1e-5)) << "d(lambda K w)/dx";
    // the effect's parameters
    Eigen::VectorXd dEdp = Eigen::VectorXd::Zero(pe.size()), dGdp = dEdp;
    t.add_energy_parameter_gradient(x, pe, dEdp);
    t.add_gradient_parameter_product(x, pe, lambda, 1.0, dGdp);
    for (const auto& q : spec.parameters) {
      SCOPED_TRACE(q.name);
      const int k = model.layout().block(effect_block_name(spec.name, q.name)).offset;
      const double h = 1e-6 * std::min(1.0, q.prior_scale);
      Eigen::VectorXd pp = pe, pm = pe;
      pp[k] += h;
      pm[k] -= h;
      const double fE = (t.energy(x, pp) - t.energy(x, pm)) / (2 * h);
      Eigen::VectorXd g1 = Eigen::VectorXd::Zero(n), g2 = g1;
      t.add_gradient(x, pp, g1);
      t.add_gradient(x, pm, g2);
      const double fG = lambda.dot(g1 - g2) / (2 * h);
      const double fK = (step_form(t, pat, x, pp, lambda, w) - step_form(t, pat, x, pm, lambda, w)) / (2 * h);
      const double E = std::abs(t.energy(x, pe));
      EXPECT_NEAR(dEdp[k], fE, near_tolerance(fE, 1e-4 * E, 1e-6)) << "dE/dp";
      EXPECT_NEAR(dGdp[k], fG, near_tolerance(fG, 1e-4 * lambda.norm() * g.norm(), 1e-6)) << "d(lambda . g)/dp";
      EXPECT_NEAR(gpar[k], fK, near_tolerance(fK, 1e-4 * std::abs(lambda.dot(symmetric_multiply(pat, K, w))), 1e-5))
          << "d(lambda K w)/dp";
    }
    // fused kernels against the separate products
    {
      const double hstep = 0.05;
      Eigen::VectorXd fx = Eigen::VectorXd::Zero(n), fv = fx, fp = Eigen::VectorXd::Zero(pe.size());
      const bool has_gv = t.add_step_adjoint(x, pe, lambda, w, hstep, fx, fv, fp);
      Eigen::VectorXd sx = Eigen::VectorXd::Zero(n), sv = sx, sp = Eigen::VectorXd::Zero(pe.size()), Hl = sx;
      t.add_hessian_product(x, pe, lambda, Hl);
      sx -= hstep * Hl;
      t.add_step_matrix_derivatives(x, pe, lambda, w, -hstep * hstep, sx, sp);
      t.add_gradient_parameter_product(x, pe, lambda, -hstep, sp);
      sv -= hstep * hstep * symmetric_multiply(pat, K, lambda);
      EXPECT_LE((fx - sx).norm(), 1e-10 * std::max(1e-14, sx.norm())) << "step adjoint, positions";
      EXPECT_LE((fp - sp).norm(), 1e-10 * std::max(1e-14, sp.norm())) << "step adjoint, parameters";
      if (has_gv) EXPECT_LE((fv - sv).norm(), 1e-10 * std::max(1e-14, sv.norm())) << "step adjoint, K lambda";
    }
    {
      Eigen::VectorXd values = Eigen::VectorXd::Zero(pat.nnz()), Kv = Eigen::VectorXd::Zero(n), gs = Kv;
      if (t.add_step_system(x, pe, w, 0.5, values, Kv, gs)) {
        EXPECT_LE((values - 0.5 * K).norm(), 1e-12 * std::max(1e-14, K.norm())) << "step system, matrix";
        const Eigen::VectorXd ref = 0.5 * symmetric_multiply(pat, K, w);
        EXPECT_LE((Kv - ref).norm(), 1e-10 * std::max(1e-14, ref.norm())) << "step system, K v";
        EXPECT_LE((gs - g).norm(), 1e-12 * std::max(1e-14, g.norm())) << "step system, gradient";
      }
    }
  }
}

INSTANTIATE_TEST_SUITE_P(Registry, EffectParameters,
                         ::testing::Combine(::testing::ValuesIn(registered_effect_names()), ::testing::Bool()),
                         [](const ::testing::TestParamInfo<std::tuple<std::string, bool>>& info) {
                           return std::get<0>(info.param) + (std::get<1>(info.param) ? "_heterogeneous" : "_homogeneous");
                         });
