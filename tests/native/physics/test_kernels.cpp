// The hand-written per-element kernels (chain rule through the strains / the dihedral angle) against the
// jet-derived reference (ElementTerm's generic versions) on random states: equal to round-off.
#include <gtest/gtest.h>

#include "../test_support.hpp"
#include "physics/bend.hpp"
#include "physics/stretch.hpp"
#include "solver/cholmod_solver.hpp"

using namespace drapelab;
using namespace drapelab::testing;

namespace {

double rel_err(const Eigen::VectorXd& a, const Eigen::VectorXd& b) {
  return (a - b).norm() / std::max(1e-300, std::max(a.norm(), b.norm()));
}

// States from gentle to violent: sag plus noise (strains across the whole table, compressions that switch
// the geometric stiffness' positive part, folds with large dihedral angles of both signs).
Eigen::VectorXd kernel_state(const Model& model, int kind, unsigned seed) {
  const double noise[4] = {2e-4, 2e-3, 6e-3, 1.5e-2};
  Eigen::VectorXd x = perturbed_positions(model, noise[kind], seed);
  if (kind == 3) {  // a strong uniform stretch on top
    for (int i = 0; i < model.num_vertices(); ++i) x.segment<2>(3 * i) *= 1.08;
  }
  return x;
}

template <class TermT>
const TermT& find_term(const Model& model) {
  for (const auto& t : model.terms())
    if (auto* p = dynamic_cast<const TermT*>(t.get())) return *p;
  throw std::logic_error("term not found");
}

template <class TermT>
void compare_kernels(bool heterogeneous) {
  using Ref = typename TermT::Reference;
  constexpr double kTol = 1e-12;
  ModelOptions o;
  o.heterogeneous = heterogeneous;
  Model model(make_cusick_specimen(60), o);
  const TermT& term = find_term<TermT>(model);
  const Ref& ref = term;
  const int n = model.num_dofs(), np = static_cast<int>(model.default_parameters().size()), nnz = model.pattern().nnz();
  for (int kind = 0; kind < 4; ++kind) {
    const unsigned seed = 31 + 7 * kind;
    const Eigen::VectorXd x = kernel_state(model, kind, seed);
    const Eigen::VectorXd p = heterogeneous ? jittered_parameters(model, seed) : model.default_parameters();
    const Eigen::VectorXd d = random_vector(n, seed + 1), l = random_vector(n, seed + 2), w = random_vector(n, seed + 3);
    SCOPED_TRACE(term.name() + " state " + std::to_string(kind));
    EXPECT_NEAR(term.energy(x, p), ref.Ref::energy(x, p), kTol * std::abs(ref.Ref::energy(x, p)));
    {
      Eigen::VectorXd a = Eigen::VectorXd::Zero(n), b = Eigen::VectorXd::Zero(n);
      term.add_gradient(x, p, a);
      ref.Ref::add_gradient(x, p, b);
      EXPECT_LT(rel_err(a, b), kTol) << "gradient";
    }
    {
      Eigen::VectorXd a = Eigen::VectorXd::Zero(nnz), b = Eigen::VectorXd::Zero(nnz);
      term.add_step_matrix(x, p, 0.7, a);
      ref.Ref::add_step_matrix(x, p, 0.7, b);
      EXPECT_LT(rel_err(a, b), kTol) << "step matrix";
    }
    {
      Eigen::VectorXd a = Eigen::VectorXd::Zero(nnz), b = Eigen::VectorXd::Zero(nnz);
      term.add_hessian(x, p, 1.3, a);
      ref.Ref::add_hessian(x, p, 1.3, b);
      EXPECT_LT(rel_err(a, b), kTol) << "hessian";
    }
    {
      Eigen::VectorXd a = Eigen::VectorXd::Zero(nnz), b = Eigen::VectorXd::Zero(nnz);
      term.add_projected_hessian(x, p, 1.3, a);
      ref.Ref::add_projected_hessian(x, p, 1.3, b);
      EXPECT_LT(rel_err(a, b), 1e-10) << "projected hessian";  // eigen-decompositions of equal matrices
    }
    {
      Eigen::VectorXd a = Eigen::VectorXd::Zero(n), b = Eigen::VectorXd::Zero(n);
      term.add_hessian_product(x, p, d, a);
      ref.Ref::add_hessian_product(x, p, d, b);
      EXPECT_LT(rel_err(a, b), kTol) << "hessian product";
    }
    {
      Eigen::VectorXd a = Eigen::VectorXd::Zero(np), b = Eigen::VectorXd::Zero(np);
      term.add_energy_parameter_gradient(x, p, a);
      ref.Ref::add_energy_parameter_gradient(x, p, b);
      EXPECT_LT(rel_err(a, b), kTol) << "energy parameter gradient";
    }
    {
      Eigen::VectorXd a = Eigen::VectorXd::Zero(np), b = Eigen::VectorXd::Zero(np);
      term.add_gradient_parameter_product(x, p, l, -0.4, a);
      ref.Ref::add_gradient_parameter_product(x, p, l, -0.4, b);
      EXPECT_LT(rel_err(a, b), kTol) << "gradient parameter product";
    }
    {
      Eigen::VectorXd ax = Eigen::VectorXd::Zero(n), bx = Eigen::VectorXd::Zero(n);
      Eigen::VectorXd ap = Eigen::VectorXd::Zero(np), bp = Eigen::VectorXd::Zero(np);
      term.add_step_matrix_derivatives(x, p, l, w, -2.5, ax, ap);
      ref.Ref::add_step_matrix_derivatives(x, p, l, w, -2.5, bx, bp);
      EXPECT_LT(rel_err(ax, bx), kTol) << "step matrix x-derivative";
      EXPECT_LT(rel_err(ap, bp), kTol) << "step matrix p-derivative";
    }
    {  // K d without assembling K, against the assembled reference K
      Eigen::VectorXd a = Eigen::VectorXd::Zero(n), b = Eigen::VectorXd::Zero(n), K = Eigen::VectorXd::Zero(nnz);
      ASSERT_TRUE(term.add_step_matrix_product(x, p, d, 0.3, a));
      ASSERT_TRUE(ref.Ref::add_step_matrix_product(x, p, d, 0.3, b));
      EXPECT_LT(rel_err(a, b), kTol) << "step matrix product (generic)";
      ref.Ref::add_step_matrix(x, p, 0.3, K);
      EXPECT_LT(rel_err(a, symmetric_multiply(model.pattern(), K, d)), kTol) << "step matrix product (assembled)";
    }
    {  // the fused step system against the separate reference methods
      Eigen::VectorXd A = Eigen::VectorXd::Zero(nnz), Kv = Eigen::VectorXd::Zero(n), g = Eigen::VectorXd::Zero(n);
      ASSERT_TRUE(term.add_step_system(x, p, w, 0.0025, A, Kv, g));
      Eigen::VectorXd eA = Eigen::VectorXd::Zero(nnz), eg = Eigen::VectorXd::Zero(n);
      ref.Ref::add_step_matrix(x, p, 0.0025, eA);
      ref.Ref::add_gradient(x, p, eg);
      EXPECT_LT(rel_err(A, eA), kTol) << "step system matrix";
      EXPECT_LT(rel_err(Kv, symmetric_multiply(model.pattern(), eA, w)), kTol) << "step system K v";
      EXPECT_LT(rel_err(g, eg), kTol) << "step system gradient";
    }
    {  // the fused adjoint pass against the separate reference products
      const double h = 0.05;
      Eigen::VectorXd gx = Eigen::VectorXd::Zero(n), gv = Eigen::VectorXd::Zero(n), gp = Eigen::VectorXd::Zero(np);
      Eigen::VectorXd ex = gx, ev = gv, ep = gp;
      ASSERT_TRUE(term.add_step_adjoint(x, p, l, w, h, gx, gv, gp));
      Eigen::VectorXd Hl = Eigen::VectorXd::Zero(n), K = Eigen::VectorXd::Zero(nnz);
      ref.Ref::add_hessian_product(x, p, l, Hl);
      ex -= h * Hl;
      ref.Ref::add_step_matrix_derivatives(x, p, l, w, -h * h, ex, ep);
      ref.Ref::add_gradient_parameter_product(x, p, l, -h, ep);
      ref.Ref::add_step_matrix(x, p, h * h, K);
      ev -= symmetric_multiply(model.pattern(), K, l);
      EXPECT_LT(rel_err(gx, ex), kTol) << "adjoint gx";
      EXPECT_LT(rel_err(gv, ev), kTol) << "adjoint gv";
      EXPECT_LT(rel_err(gp, ep), kTol) << "adjoint gp";
    }
  }
}

}  // namespace

TEST(TermKernels, StretchMatchesJetReference) {
  compare_kernels<StretchTerm>(false);
  compare_kernels<StretchTerm>(true);
}

TEST(TermKernels, BendMatchesJetReference) {
  compare_kernels<BendTerm>(false);
  compare_kernels<BendTerm>(true);
}
