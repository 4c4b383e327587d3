// solve_with_offpattern (solver/contact_linear_solve.hpp): with contact pairs coupling vertices outside the
// model's pattern, the preconditioned CG solve equals a dense solve of the full operator; with no pair active it
// is the direct solve (no CG iteration).
#include <gtest/gtest.h>

#include <Eigen/Dense>

#include "../contact/contact_support.hpp"
#include "../test_support.hpp"
#include "solver/cholmod_solver.hpp"
#include "solver/contact_linear_solve.hpp"

namespace drapelab {
namespace {

// Two 4 x 4 sheets (2 cm) 0.5 mm apart in one mesh, self contact 1 mm: pairs couple the layers.
TriangleMesh two_layers(double gap) {
  const TriangleMesh a = testing::grid_mesh(4, 0.02, 0.0), b = testing::grid_mesh(4, 0.02, gap);
  TriangleMesh m;
  m.positions.resize(32, 3);
  m.uv.resize(32, 2);
  m.faces.resize(36, 3);
  m.positions << a.positions, b.positions;
  m.uv << a.uv, b.uv;
  m.faces << a.faces, b.faces.array() + 16;
  return m;
}

void check(double gap, bool expect_iterations) {
  ModelOptions o;
  o.effects["self_contact"] = {{"thickness_m", 1e-3}};
  Model model(two_layers(gap), o);
  ASSERT_TRUE(has_offpattern_terms(model));
  const Eigen::VectorXd p = model.default_parameters();
  Eigen::VectorXd x = model.rest_positions() + 5e-5 * testing::random_vector(model.num_dofs(), 2);
  const SparsePattern& pat = model.pattern();
  const int n = model.num_dofs();
  for (bool projected : {true, false}) {
    SCOPED_TRACE(projected ? "projected" : "exact");
    Eigen::VectorXd A = Eigen::VectorXd::Zero(pat.nnz());
    for (const auto& t : model.terms()) {
      if (projected) t->add_projected_hessian(x, p, 1.0, A);
      else t->add_hessian(x, p, 1.0, A);
    }
    const Eigen::VectorXd m = model.masses(p);
    for (int i = 0; i < model.num_vertices(); ++i)
      for (int k = 0; k < 3; ++k) A[pat.diagonal(3 * i + k)] += 400.0 * m[i];  // M / h^2 of a 0.05 s step
    CholmodSolver solver(pat);
    ASSERT_TRUE(solver.factorize(A));
    const Eigen::VectorXd b = testing::random_vector(n, 3);
    Eigen::VectorXd y;
    OffpatternSolveStats stats;
    ASSERT_TRUE(solve_with_offpattern(model, solver, A, x, p, projected, b, y, 1e-12, 200, &stats));
    // dense full operator: assembled columns plus the off-pattern products
    Eigen::MatrixXd F(n, n);
    for (int j = 0; j < n; ++j) {
      Eigen::VectorXd e = Eigen::VectorXd::Zero(n), col = Eigen::VectorXd::Zero(n);
      e[j] = 1;
      for (const auto& t : model.terms()) t->add_offpattern_hessian_product(x, p, e, projected, col);
      F.col(j) = symmetric_multiply(pat, A, e) + col;
    }
    const Eigen::VectorXd yd = F.ldlt().solve(b);
    EXPECT_LE((y - yd).norm(), 1e-8 * yd.norm());
    if (expect_iterations) EXPECT_GT(stats.iterations, 0);
    else EXPECT_EQ(stats.iterations, 0);
    std::printf("gap %.1f mm, %s: %d CG iterations, relative residual %.2g\n", 1e3 * gap,
                projected ? "projected" : "exact", stats.iterations, stats.relative_residual);
  }
}

TEST(ContactLinearSolve, MatchesDenseSolveWithOffPatternPairs) { check(5e-4, true); }
TEST(ContactLinearSolve, IsTheDirectSolveWithoutActivePairs) { check(5e-3, false); }

}  // namespace
}  // namespace drapelab
