// Finite-difference checks of every term's derivatives on a small mesh in a generic (perturbed) state.
#include <gtest/gtest.h>

#include "../test_support.hpp"
#include "physics/sparse_pattern.hpp"
#include "solver/cholmod_solver.hpp"

using namespace drapelab;
using namespace drapelab::testing;

namespace {

struct TermCase {
  std::unique_ptr<Model> model;
  Eigen::VectorXd x, p;
};

TermCase make_case(bool heterogeneous, unsigned seed) {
  ModelOptions o;
  o.heterogeneous = heterogeneous;
  TermCase c;
  c.model = std::make_unique<Model>(make_cusick_specimen(60), o);
  // Strains of a few percent reach the nonlinear table rows; bending angles cover several columns.
  c.x = perturbed_positions(*c.model, 2e-3, seed);
  c.p = heterogeneous ? jittered_parameters(*c.model, seed + 1) : c.model->default_parameters();
  return c;
}

double rel_err(const Eigen::VectorXd& a, const Eigen::VectorXd& b) {
  return (a - b).norm() / std::max(1e-300, std::max(a.norm(), b.norm()));
}

Eigen::VectorXd dense_multiply(const SparsePattern& pat, const Eigen::VectorXd& vals, const Eigen::VectorXd& d) {
  return symmetric_multiply(pat, vals, d);
}

}  // namespace

class TermDerivatives : public ::testing::TestWithParam<std::tuple<int, bool>> {};

TEST_P(TermDerivatives, GradientMatchesEnergy) {
  const auto [term_index, het] = GetParam();
  TermCase c = make_case(het, 7);
  const Term& term = *c.model->terms()[term_index];
  const int n = c.model->num_dofs();
  for (unsigned s = 0; s < 3; ++s) {
    const Eigen::VectorXd d = random_vector(n, 100 + s);
    Eigen::VectorXd g = Eigen::VectorXd::Zero(n);
    term.add_gradient(c.x, c.p, g);
    const double eps = 1e-7;
    const double fd = (term.energy(c.x + eps * d, c.p) - term.energy(c.x - eps * d, c.p)) / (2 * eps);
    EXPECT_NEAR(g.dot(d), fd, 1e-5 * std::max(1e-12, std::abs(fd)) + 1e-14) << term.name();
  }
}

TEST_P(TermDerivatives, HessianMatchesGradient) {
  const auto [term_index, het] = GetParam();
  TermCase c = make_case(het, 11);
  const Term& term = *c.model->terms()[term_index];
  const int n = c.model->num_dofs();
  const Eigen::VectorXd d = random_vector(n, 5);
  Eigen::VectorXd gp = Eigen::VectorXd::Zero(n), gm = Eigen::VectorXd::Zero(n);
  const double eps = 1e-7;
  term.add_gradient(c.x + eps * d, c.p, gp);
  term.add_gradient(c.x - eps * d, c.p, gm);
  const Eigen::VectorXd fd = (gp - gm) / (2 * eps);
  Eigen::VectorXd Hd = Eigen::VectorXd::Zero(n);
  term.add_hessian_product(c.x, c.p, d, Hd);
  EXPECT_LT(rel_err(Hd, fd), 1e-5) << term.name();
  // The assembled exact Hessian agrees with the Hessian-vector product.
  Eigen::VectorXd H = Eigen::VectorXd::Zero(c.model->pattern().nnz());
  term.add_hessian(c.x, c.p, 1.0, H);
  EXPECT_LT(rel_err(dense_multiply(c.model->pattern(), H, d), Hd), 1e-10) << term.name();
}

TEST_P(TermDerivatives, ParameterGradients) {
  const auto [term_index, het] = GetParam();
  TermCase c = make_case(het, 13);
  const Term& term = *c.model->terms()[term_index];
  const int n = c.model->num_dofs(), np = static_cast<int>(c.p.size());
  const Eigen::VectorXd dp = random_vector(np, 9).cwiseProduct(c.p.cwiseAbs()) * 0.1;
  const double eps = 1e-6;
  // dE/dp
  Eigen::VectorXd gE = Eigen::VectorXd::Zero(np);
  term.add_energy_parameter_gradient(c.x, c.p, gE);
  const double fdE = (term.energy(c.x, c.p + eps * dp) - term.energy(c.x, c.p - eps * dp)) / (2 * eps);
  EXPECT_NEAR(gE.dot(dp), fdE, 1e-6 * std::abs(fdE) + 1e-14) << term.name();
  // d(lambda . dE/dx)/dp
  const Eigen::VectorXd lambda = random_vector(n, 21);
  Eigen::VectorXd gl = Eigen::VectorXd::Zero(np);
  term.add_gradient_parameter_product(c.x, c.p, lambda, 1.0, gl);
  Eigen::VectorXd g1 = Eigen::VectorXd::Zero(n), g2 = Eigen::VectorXd::Zero(n);
  term.add_gradient(c.x, c.p + eps * dp, g1);
  term.add_gradient(c.x, c.p - eps * dp, g2);
  const double fdl = lambda.dot(g1 - g2) / (2 * eps);
  EXPECT_NEAR(gl.dot(dp), fdl, 1e-6 * std::abs(fdl) + 1e-14) << term.name();
}

TEST_P(TermDerivatives, StepMatrixDerivatives) {
  const auto [term_index, het] = GetParam();
  TermCase c = make_case(het, 17);
  const Term& term = *c.model->terms()[term_index];
  const SparsePattern& pat = c.model->pattern();
  const int n = c.model->num_dofs(), np = static_cast<int>(c.p.size());
  const Eigen::VectorXd lambda = random_vector(n, 3), w = random_vector(n, 4);
  auto quad = [&](const Eigen::VectorXd& x, const Eigen::VectorXd& p) {
    Eigen::VectorXd K = Eigen::VectorXd::Zero(pat.nnz());
    term.add_step_matrix(x, p, 1.0, K);
    return lambda.dot(symmetric_multiply(pat, K, w));
  };
  Eigen::VectorXd gx = Eigen::VectorXd::Zero(n), gp = Eigen::VectorXd::Zero(np);
  term.add_step_matrix_derivatives(c.x, c.p, lambda, w, 1.0, gx, gp);
  const Eigen::VectorXd dx = random_vector(n, 8);
  const Eigen::VectorXd dp = random_vector(np, 9).cwiseProduct(c.p.cwiseAbs()) * 0.1;
  const double eps = 1e-7;
  const double fdx = (quad(c.x + eps * dx, c.p) - quad(c.x - eps * dx, c.p)) / (2 * eps);
  EXPECT_NEAR(gx.dot(dx), fdx, 1e-5 * std::abs(fdx) + 1e-12) << term.name();
  // K is piecewise linear in the tables: a larger step avoids round-off from cancellations in the sum.
  const double eps_p = 1e-4;
  const double fdp = (quad(c.x, c.p + eps_p * dp) - quad(c.x, c.p - eps_p * dp)) / (2 * eps_p);
  EXPECT_NEAR(gp.dot(dp), fdp, 1e-6 * std::abs(fdp) + 1e-12) << term.name();
}

TEST_P(TermDerivatives, StepMatrixIsPositiveSemidefinite) {
  const auto [term_index, het] = GetParam();
  TermCase c = make_case(het, 19);
  const Term& term = *c.model->terms()[term_index];
  const SparsePattern& pat = c.model->pattern();
  Eigen::VectorXd K = Eigen::VectorXd::Zero(pat.nnz());
  term.add_step_matrix(c.x, c.p, 1.0, K);
  for (unsigned s = 0; s < 5; ++s) {
    const Eigen::VectorXd d = random_vector(c.model->num_dofs(), 40 + s);
    EXPECT_GE(d.dot(symmetric_multiply(pat, K, d)), -1e-12) << term.name();
  }
}

// The projected Hessian (each element block made PSD) is PSD, and it is the exact Hessian wherever the exact
// one is already PSD element by element: in the flat rest state with the handle, gravity and stretch terms
// (convex there), and for the PSD terms (handle, gravity) in any state.
TEST_P(TermDerivatives, ProjectedHessianIsPositiveSemidefiniteAndExactWhereStable) {
  const auto [term_index, het] = GetParam();
  TermCase c = make_case(het, 23);
  const Term& term = *c.model->terms()[term_index];
  const SparsePattern& pat = c.model->pattern();
  Eigen::VectorXd P = Eigen::VectorXd::Zero(pat.nnz()), H = Eigen::VectorXd::Zero(pat.nnz());
  term.add_projected_hessian(c.x, c.p, 1.0, P);
  term.add_hessian(c.x, c.p, 1.0, H);
  double scale = 0;
  for (unsigned s = 0; s < 5; ++s) {
    const Eigen::VectorXd d = random_vector(c.model->num_dofs(), 60 + s);
    const double dPd = d.dot(symmetric_multiply(pat, P, d)), dHd = d.dot(symmetric_multiply(pat, H, d));
    scale = std::max(scale, std::abs(dHd));
    EXPECT_GE(dPd, -1e-12 * std::max(1.0, scale)) << term.name();
    EXPECT_GE(dPd, dHd - 1e-9 * std::max(1e-12, scale)) << term.name() << ": projection only adds curvature";
  }
  if (term.name() == "handle" || term.name() == "gravity")
    EXPECT_LE((P - H).norm(), 1e-12 * std::max(1.0, H.norm())) << term.name();
  Eigen::VectorXd P0 = Eigen::VectorXd::Zero(pat.nnz()), H0 = Eigen::VectorXd::Zero(pat.nnz());
  const Eigen::VectorXd rest = c.model->rest_positions();
  term.add_projected_hessian(rest, c.p, 1.0, P0);
  term.add_hessian(rest, c.p, 1.0, H0);
  if (term.name() != "bend")  // bending at exactly flat: the angle's Hessian times E'(0) = 0, also PSD
    EXPECT_LE((P0 - H0).norm(), 1e-9 * std::max(1e-12, H0.norm())) << term.name() << " at rest";
}

// The static solve's Newton matrix: the exact Hessian, except bending's Gauss-Newton step matrix (its exact
// Hessian's E'(theta) Hess theta is indefinite in folds); PSD for bending, symmetric like the others.
TEST_P(TermDerivatives, StaticNewtonMatrixIsExactHessianOrBendingStepMatrix) {
  const auto [term_index, het] = GetParam();
  TermCase c = make_case(het, 29);
  const Term& term = *c.model->terms()[term_index];
  const SparsePattern& pat = c.model->pattern();
  Eigen::VectorXd N = Eigen::VectorXd::Zero(pat.nnz()), R = Eigen::VectorXd::Zero(pat.nnz());
  term.add_static_newton_matrix(c.x, c.p, 0.5, N);
  if (term.name() == "bend") term.add_step_matrix(c.x, c.p, 0.5, R);
  else term.add_hessian(c.x, c.p, 0.5, R);
  EXPECT_LE((N - R).norm(), 1e-15 * std::max(1e-300, R.norm())) << term.name();
}

INSTANTIATE_TEST_SUITE_P(AllTerms, TermDerivatives,
                         ::testing::Combine(::testing::Values(0, 1, 2, 3), ::testing::Bool()));
