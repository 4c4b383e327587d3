// Every term of a model with an effect switched on, the base terms included: an effect may change a base term
// from inside (physics/base_term_changes.hpp: prestrain's rest scaling of the stretch term, heterogeneity_map's
// multiplier on the bend term), which test_terms.cpp (base models) and the per-effect term check of
// test_effects.cpp (the effect's own terms) do not see. For every registered effect at a moderate strength,
// homogeneous and heterogeneous, each term's derivatives in positions and in the effect's parameters match
// central differences, its step matrix is PSD, and its fused kernels (step system, step adjoint) agree with
// the separate products.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <random>
#include <string>

#include "../test_support.hpp"
#include "physics/bend.hpp"
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

// Every term's derivatives in positions and the effect's parameters at (x, pe), against central differences;
// its step matrix PSD; its fused kernels against the separate products.
// only_term: check that term alone (empty: every term). position_differences false: skip the central differences
// in positions (for positions with edges on the C1 blends' nodes; the rest is differences in the parameters, which
// the blends do not see, and exact identities).
void check_every_term(const EffectSpec& spec, const Model& model, const Eigen::VectorXd& x, const Eigen::VectorXd& pe,
                      const std::string& only_term = "", bool position_differences = true) {
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
    if (!only_term.empty() && term->name() != only_term) continue;
    SCOPED_TRACE(term->name());
    const Term& t = *term;
    // positions
    Eigen::VectorXd g = Eigen::VectorXd::Zero(n), gp = g, gm = g, Hd = g;
    t.add_gradient(x, pe, g);
    if (position_differences) {
      const double fdE = (t.energy(x + eps * d, pe) - t.energy(x - eps * d, pe)) / (2 * eps);
      EXPECT_NEAR(g.dot(d), fdE, near_tolerance(fdE, 1e-3 * g.norm() * d.norm() * eps, 1e-6)) << "gradient";
      t.add_gradient(x + eps * d, pe, gp);
      t.add_gradient(x - eps * d, pe, gm);
      t.add_hessian_product(x, pe, d, Hd);
      const Eigen::VectorXd fdH = (gp - gm) / (2 * eps);
      EXPECT_LE((Hd - fdH).norm(), 1e-6 * std::max(1e-12, fdH.norm()) + 1e-12 * g.norm()) << "Hessian product";
    }
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
    if (position_differences) {
      const double fdK =
          (step_form(t, pat, x + eps * d, pe, lambda, w) - step_form(t, pat, x - eps * d, pe, lambda, w)) / (2 * eps);
      EXPECT_NEAR(gx.dot(d), fdK, near_tolerance(fdK, 1e-8 * gx.norm() * d.norm(), 1e-5)) << "d(lambda K w)/dx";
    }
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
  check_every_term(spec, model, perturbed_positions(model, 2e-3, 7), pe);
}

INSTANTIATE_TEST_SUITE_P(Registry, EffectParameters,
                         ::testing::Combine(::testing::ValuesIn(registered_effect_names()), ::testing::Bool()),
                         [](const ::testing::TestParamInfo<std::tuple<std::string, bool>>& info) {
                           return std::get<0>(info.param) + (std::get<1>(info.param) ? "_heterogeneous" : "_homogeneous");
                         });

// high_curvature_bending at -0.8 on a circle of 1500 vertices (edges ~8 mm: alpha up to ~140 /m); the material
// jittered when heterogeneous; k: log_factor's index.
struct BentSpecimen {
  static ModelOptions options(bool heterogeneous) {
    ModelOptions o;
    o.heterogeneous = heterogeneous;
    o.effects["high_curvature_bending"]["log_factor"] = -0.8;
    return o;
  }
  explicit BentSpecimen(bool heterogeneous)
      : model(make_cusick_specimen(1500), options(heterogeneous)),
        p(heterogeneous ? jittered_parameters(model, 3) : model.default_parameters()),
        k(model.layout().block(effect_block_name("high_curvature_bending", "log_factor")).offset) {
    p[k] = -0.8;
  }
  Model model;
  Eigen::VectorXd p;
  int k;
};

// high_curvature_bending acts only where an edge's curvature measure alpha passes the table's 10 /m, which the
// suite's 2 mm perturbation never reaches (and a mesh bent that far has edges on the C1 blends' nodes, where
// central differences of second derivatives fail for the base term too). Its change is a factor M(d) on the
// edge's energy as a function of the angle change d, which every kernel reads through the angle derivatives:
// those are checked here against central differences in d and in log_factor, for d sweeping alpha from 0 past
// the ramp (10-80 /m), away from the blends' nodes; the factor is exactly 1 below the ramp; and at the effect's
// lower bound the energy stays convex in the angle (the bound's promise: no snap).
TEST(HighCurvatureBending, AngleDerivativesAreExactOnTheRampAndBeyondIt) {
  const EffectSpec& spec = find_effect("high_curvature_bending");
  for (bool heterogeneous : {false, true}) {
    SCOPED_TRACE(heterogeneous ? "heterogeneous" : "homogeneous");
    BentSpecimen b(heterogeneous);
    const Model& model = b.model;
    const Eigen::VectorXd& p = b.p;
    const int k = b.k;
    Eigen::VectorXd p0 = p;
    p0[k] = 0.0;
    const BendTerm* bend = nullptr;
    for (const auto& t : model.terms())
      if (t->name() == "bend") bend = dynamic_cast<const BendTerm*>(t.get());
    ASSERT_NE(bend, nullptr);
    int on_ramp = 0, beyond = 0;
    for (int e : {0, bend->num_elements() / 2, bend->num_elements() - 1}) {
      const double H = bend->height_sum(e);
      for (int i = 1; i < 400; ++i) {
        const double d = (i % 2 ? 1.0 : -1.0) * 3.1 * i / 400.0;  // both signs
        const double alpha = std::abs(std::sin(0.5 * d)) / H;
        bool near_node = false;  // the table's columns (2.5 /m apart) and the ramp's ends
        for (double node : {2.5, 5.0, 7.5, 10.0, 80.0})
          if (std::abs(alpha - node) < 0.05) near_node = true;
        if (near_node) continue;
        const auto ad = bend->changed_angle_derivatives(e, d, p);
        const auto base = bend->changed_angle_derivatives(e, d, p0);
        if (alpha < 10.0) {
          for (int n = 0; n < 4; ++n) EXPECT_EQ(ad.E[n], base.E[n]) << "below the ramp, d " << d;
          continue;
        }
        (alpha < 80.0 ? on_ramp : beyond) += 1;
        const double h = 1e-6;
        const auto dp = bend->changed_angle_derivatives(e, d + h, p), dm = bend->changed_angle_derivatives(e, d - h, p);
        for (int n = 0; n < 3; ++n) {
          const double fd = (dp.E[n] - dm.E[n]) / (2 * h);
          EXPECT_NEAR(ad.E[n + 1], fd, 1e-6 * (std::abs(fd) + std::abs(ad.E[n]) + std::abs(ad.E[0]))) << "E^(" << n + 1 << "), d " << d;
        }
        for (int j = 0; j < ad.count; ++j)
          for (int n = 0; n < 2; ++n) {
            const double fd = (dp.phi[j][n] - dm.phi[j][n]) / (2 * h);
            EXPECT_NEAR(ad.phi[j][n + 1], fd, 1e-6 * (std::abs(fd) + std::abs(ad.phi[j][0]))) << "phi, d " << d;
          }
        Eigen::VectorXd pp = p, pm = p;
        pp[k] += h;
        pm[k] -= h;
        const auto qp = bend->changed_angle_derivatives(e, d, pp), qm = bend->changed_angle_derivatives(e, d, pm);
        for (int n = 0; n < 3; ++n) {
          const double fd = (qp.E[n] - qm.E[n]) / (2 * h);
          EXPECT_NEAR(ad.dq[n], fd, 1e-6 * (std::abs(fd) + std::abs(ad.E[n]))) << "dE^(" << n << ")/dq, d " << d;
        }
        if (alpha > 80.0) EXPECT_NEAR(ad.E[0], std::exp(-0.8) * base.E[0], 1e-12 * base.E[0]) << "beyond the ramp";
        if (!heterogeneous) {  // the default table is convex; at the lower bound the factor keeps it so
          Eigen::VectorXd pl = p;
          pl[k] = spec.parameters[0].lower;
          EXPECT_GT(bend->changed_angle_derivatives(e, d, pl).E[2], 0.0) << "convex at the lower bound, d " << d;
        }
      }
    }
    EXPECT_GE(on_ramp, 20);
    EXPECT_GE(beyond, 20);
  }
}

// The kernels' use of the factor (the parameter derivatives, the fused kernels, the step matrix) on a mesh bent past
// the ramp: the suite's checks of the term it changes (bend), the position differences left to the angle test above.
TEST(HighCurvatureBending, KernelsAreExactInLogFactorOnABentMesh) {
  const EffectSpec& spec = find_effect("high_curvature_bending");
  for (bool heterogeneous : {false, true}) {
    SCOPED_TRACE(heterogeneous ? "heterogeneous" : "homogeneous");
    BentSpecimen b(heterogeneous);
    const Model& model = b.model;
    const Eigen::VectorXd& pe = b.p;
    const Eigen::VectorXd x = perturbed_positions(model, 3e-3, 7);  // 3 mm of noise bends some edges past 80 /m
    const Eigen::VectorXd areas = rest_areas(model.mesh());
    int below = 0, ramp = 0, beyond = 0;
    for (const BendingEdge& be : model.bending_edges()) {
      double xe[12];
      const int v[4] = {be.a, be.b, be.c, be.d};
      for (int i = 0; i < 12; ++i) xe[i] = x[3 * v[i / 3] + i % 3];
      const double L = pattern_edge(model.mesh(), be).norm();
      const double H = 2.0 * (std::abs(areas[be.face0]) + std::abs(areas[be.face1])) / L;
      const double alpha = std::abs(std::sin(0.5 * BendTerm::dihedral_angle(xe))) / H;
      (alpha < 10.0 ? below : alpha < 80.0 ? ramp : beyond) += 1;
    }
    EXPECT_GE(below, 100);
    EXPECT_GE(ramp, 100);
    EXPECT_GE(beyond, 10);
    check_every_term(spec, model, x, pe, "bend", false);
  }
}
