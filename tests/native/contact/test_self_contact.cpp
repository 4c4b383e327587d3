// The self_contact effect (effects/self_contact.cpp over contact/pair_contact.hpp) on two stacked sheets in one
// mesh: the term's derivatives with pairs active (including the off-pattern Hessian part and the thickness
// derivatives) against central differences; a sheet thrown onto another stays intersection-free (and falls
// through without the effect); a rollout's parameter gradient with contact active against central differences;
// a state that starts intersecting is refused naming the triangles.
#include <gtest/gtest.h>

#include <Eigen/Geometry>

#include <array>
#include <random>
#include <utility>

#include "../test_support.hpp"
#include "contact/diagnostics.hpp"
#include "contact/pair_barrier.hpp"
#include "contact/pair_contact.hpp"
#include "contact_support.hpp"
#include "physics/sparse_pattern.hpp"
#include "solver/cholmod_solver.hpp"
#include "solver/implicit_euler.hpp"
#include "solver/static_solve.hpp"
#include "util/error.hpp"

namespace drapelab {
namespace {

// Two sheets in one mesh: the lower (n x n, side `size`, z = 0, uv = xy inside the support radius: held by the
// handle) and the upper (m x m, side `upper_size`, z = gap, uv shifted by 0.5 m: free).
TriangleMesh stacked_sheets(int n, double size, double gap, int m_upper = 0, double upper_size = 0) {
  if (m_upper == 0) {
    m_upper = n;
    upper_size = size;
  }
  const TriangleMesh lower = testing::grid_mesh(n, size, 0.0), upper = testing::grid_mesh(m_upper, upper_size, gap);
  TriangleMesh m;
  const int nl = lower.num_vertices(), nu = upper.num_vertices();
  m.positions.resize(nl + nu, 3);
  m.uv.resize(nl + nu, 2);
  m.faces.resize(lower.num_faces() + upper.num_faces(), 3);
  m.positions << lower.positions, upper.positions;
  m.uv << lower.uv, upper.uv;
  m.uv.bottomRows(nu).col(0).array() += 0.5;
  m.faces << lower.faces, upper.faces.array() + nl;
  return m;
}

ModelOptions self_contact_options(double thickness) {
  ModelOptions o;
  o.support_radius = 0.09;
  o.effects["self_contact"] = {{"thickness_m", thickness}};
  return o;
}

const Term& term_named(const Model& m, const std::string& name) {
  for (const auto& t : m.terms())
    if (t->name() == name) return *t;
  throw std::runtime_error("no term " + name);
}

double rel(double a, double b) { return std::abs(a - b) / std::max({std::abs(a), std::abs(b), 1e-300}); }

TEST(SelfContact, TermDerivativesWithActivePairsMatchCentralDifferences) {
  const TriangleMesh mesh = stacked_sheets(6, 0.05, 6e-4);
  Model model(mesh, self_contact_options(1e-3));
  const Eigen::VectorXd p = model.default_parameters();
  const int n = model.num_dofs();
  Eigen::VectorXd x = model.rest_positions();
  std::mt19937 rng(4);
  std::uniform_real_distribution<double> u(-1, 1);
  for (int i = 0; i < n; ++i) x[i] += 1e-4 * u(rng);
  const auto& term = dynamic_cast<const PairContactTerm&>(term_named(model, "self_contact"));
  const auto pairs = term.active_pairs(x, 1e-3);
  ASSERT_GT(pairs.size(), 50u);
  const SparsePattern& pat = model.pattern();
  for (unsigned s = 0; s < 3; ++s) {
    const Eigen::VectorXd d = testing::random_vector(n, 40 + s);
    const double eps = 1e-9;  // distances ~0.5 mm: (eps / d)^2 truncation far below the tolerance
    Eigen::VectorXd g = Eigen::VectorXd::Zero(n), gp = g, gm = g, Hd = g, rest = g, prest = g;
    term.add_gradient(x, p, g);
    const double fd = (term.energy(x + eps * d, p) - term.energy(x - eps * d, p)) / (2 * eps);
    EXPECT_LT(rel(g.dot(d), fd), 1e-6) << "gradient";
    term.add_gradient(x + eps * d, p, gp);
    term.add_gradient(x - eps * d, p, gm);
    term.add_hessian_product(x, p, d, Hd);
    const Eigen::VectorXd fdH = (gp - gm) / (2 * eps);
    EXPECT_LE((Hd - fdH).norm(), 1e-5 * fdH.norm()) << "Hessian product";
    Eigen::VectorXd H = Eigen::VectorXd::Zero(pat.nnz()), P = H;
    term.add_hessian(x, p, 1.0, H);
    term.add_offpattern_hessian_product(x, p, d, false, rest);
    EXPECT_GT(rest.norm(), 0.0) << "pairs couple vertices outside the pattern";
    EXPECT_LE((symmetric_multiply(pat, H, d) + rest - Hd).norm(), 1e-10 * Hd.norm()) << "assembled + off-pattern";
    term.add_projected_hessian(x, p, 1.0, P);
    term.add_offpattern_hessian_product(x, p, d, true, prest);
    EXPECT_GE(d.dot(symmetric_multiply(pat, P, d)), 0.0);
    EXPECT_GE(d.dot(symmetric_multiply(pat, P, d) + prest), -1e-12 * Hd.norm());
  }
  // thickness derivatives
  const int k = model.layout().block("self_contact.thickness_m").offset;
  const Eigen::VectorXd lambda = testing::random_vector(n, 77);
  Eigen::VectorXd dEdp = Eigen::VectorXd::Zero(p.size()), dgdp = dEdp;
  term.add_energy_parameter_gradient(x, p, dEdp);
  term.add_gradient_parameter_product(x, p, lambda, 1.0, dgdp);
  const double h = 1e-9;
  Eigen::VectorXd pp = p, pm = p;
  pp[k] += h;
  pm[k] -= h;
  EXPECT_LT(rel(dEdp[k], (term.energy(x, pp) - term.energy(x, pm)) / (2 * h)), 1e-5);
  Eigen::VectorXd g1 = Eigen::VectorXd::Zero(n), g2 = g1;
  term.add_gradient(x, pp, g1);
  term.add_gradient(x, pm, g2);
  EXPECT_LT(rel(dgdp[k], lambda.dot(g1 - g2) / (2 * h)), 1e-5);
}

// The upper sheet thrown at 1 m/s onto the held lower one (5 cm per 0.05 s step against a 3 mm gap).
Eigen::VectorXd throw_sheet(const Model& model, int first_upper, int steps, ImplicitEuler& sim, const Eigen::VectorXd& p) {
  Eigen::VectorXd v0 = Eigen::VectorXd::Zero(model.num_dofs());
  for (int i = first_upper; i < model.num_vertices(); ++i) v0[3 * i + 2] = -1.0;
  RolloutOptions ro;
  ro.steps = steps;
  ro.record = false;
  const Eigen::VectorXd x0 = model.rest_positions();
  return sim.forward(p, ro, nullptr, &x0, &v0);
}

// A pair pinched to 1e-13 m, as a walking skirt's fold squeezed by the body's carry (docs/lab/garment-speed.md),
// beside the inertia of a light fabric at a garment's step (1/96 s): the linearised step's assembled matrix
// M/h^2 + sum of the terms' step matrices (the pairs' diagonal blocks) is PSD in exact arithmetic, but the pair's
// Gauss-Newton curvature kappa b''(d) ~ kappa / d^2 reaches 1e18 N/m and more there (the skirt: up to 1e22)
// against M/h^2 below 1 N/m, and CHOLMOD failed on round-off (this test did, without the floor). With the
// curvature floor (contact/pair_barrier.hpp) it factorises and solves accurately.
// The sheets are rotated so that the pair's normal lies along no coordinate axis (an axis-aligned rank-one block
// is eliminated without cancellation).
TEST(SelfContact, PinchedPairStepMatrixFactorises) {
  TriangleMesh mesh = stacked_sheets(6, 0.05, 6e-4);
  const Eigen::Matrix3d R = Eigen::AngleAxisd(0.7, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  mesh.positions = (mesh.positions * R.transpose()).eval();
  Model model(mesh, self_contact_options(1e-3));
  const Eigen::VectorXd p = model.default_parameters();
  Eigen::VectorXd x = model.rest_positions();
  // upper vertex (2, 2) pinched onto the lower face under it: 1e-13 m along the sheets' normal
  const int pinched = 36 + 2 * 6 + 2, below = 2 * 6 + 2;
  const Eigen::Vector3d offset(0.003, 0.001, 1e-13);
  x.segment<3>(3 * pinched) = x.segment<3>(3 * below) + R * offset;
  const auto& term = dynamic_cast<const PairContactTerm&>(term_named(model, "self_contact"));
  double dmin = 1;
  for (const auto& q : term.active_pairs(x, 1e-3)) {
    double x12[12];
    for (int k = 0; k < 4; ++k)
      for (int a = 0; a < 3; ++a) x12[3 * k + a] = x[3 * q.v[k] + a];
    dmin = std::min(dmin, std::sqrt(pair_distance2(q.kind, q.type, x12)));
  }
  ASSERT_LT(dmin, 1e-12);
  ASSERT_GT(dmin, 0.0);
  const SparsePattern& pat = model.pattern();
  const double h = 1.0 / 96, inv_h2 = 1 / (h * h);
  Eigen::VectorXd A = Eigen::VectorXd::Zero(pat.nnz());
  for (const auto& t : model.terms()) t->add_step_matrix(x, p, 1.0, A);
  const Eigen::VectorXd m = model.masses(p);
  for (int i = 0; i < model.num_vertices(); ++i)
    for (int k = 0; k < 3; ++k) A[pat.diagonal(3 * i + k)] += inv_h2 * m[i];
  CholmodSolver solver(pat);
  ASSERT_TRUE(solver.factorize(A));
  const Eigen::VectorXd b = testing::random_vector(model.num_dofs(), 3);
  const Eigen::VectorXd y = solver.solve(b);
  EXPECT_LT((symmetric_multiply(pat, A, y) - b).norm(), 1e-6 * b.norm());
}

TEST(SelfContact, ThrownSheetStaysIntersectionFreeAndFallsThroughWithout) {
  // a 5 cm sheet onto a held 12 cm one (frictionless: it stays as long as it does not slide off the edge)
  const TriangleMesh mesh = stacked_sheets(13, 0.12, 3e-3, 8, 0.05);
  const int first_upper = 13 * 13;
  ModelOptions off;
  off.support_radius = 0.09;
  Model with(mesh, self_contact_options(1e-3)), without(mesh, off);
  ImplicitEuler sw(with), so(without);
  const Eigen::VectorXd xw = throw_sheet(with, first_upper, 10, sw, with.default_parameters());
  const Eigen::VectorXd xo = throw_sheet(without, first_upper, 10, so, without.default_parameters());
  const ContactReport rw = contact_report(mesh.faces, xw);
  EXPECT_EQ(rw.intersecting_pairs, 0);
  EXPECT_GT(rw.min_distance_m, 0.0);
  EXPECT_LT(rw.min_distance_m, 1e-3) << "the sheets should rest in contact";
  double lowest_over = INFINITY, lowest_without = INFINITY;
  for (int i = first_upper; i < with.num_vertices(); ++i) {
    lowest_over = std::min(lowest_over, xw[3 * i + 2]);
    lowest_without = std::min(lowest_without, xo[3 * i + 2]);
  }
  EXPECT_GT(lowest_over, 0.0) << "the thrown sheet rests on the held one";
  EXPECT_LT(lowest_without, -0.05) << "without self contact the sheet falls through";
  std::printf("thrown sheet: min distance %.3g mm, lowest %.3g mm (without: %.3g mm), %d Newton iterations\n",
              1e3 * rw.min_distance_m, 1e3 * lowest_over, 1e3 * lowest_without, sw.timing().newton_iterations);
}

// The stacked sheets' start, jittered by 0.1 mm (against the 2 mm gap). The sheets as built are exactly aligned:
// every upper vertex right above a lower one, every upper edge parallel to the one below. There the linearised
// step is not differentiable (its step matrix's x-derivative, through Hess d, changes with the side of the
// distance-type boundaries a perturbation goes to: central differences of one step disagree with themselves by
// 2 % between steps 1e-6 and 1e-8 and with any gradient by 15 %; over 6 steps a bend entry by 19x, the "defect"
// of docs/lab/contact-speed.md). A generic start has a gradient, and the adjoints must match it.
Eigen::VectorXd jittered_start(const Model& model) {
  return model.rest_positions() + 1e-4 * testing::random_vector(model.num_dofs(), 77);
}

// Both contact step modes (linearised: the adjoint of the cut Newton iterations; Newton: the implicit function
// theorem at each step's minimiser) against central differences, with contact active from the first step.
void check_rollout_gradient(RolloutOptions::ContactStep mode) {
  const TriangleMesh mesh = stacked_sheets(5, 0.04, 2e-3);
  Model model(mesh, self_contact_options(1e-3));
  const Eigen::VectorXd p = model.default_parameters();
  ImplicitEuler sim(model);
  Eigen::VectorXd v0 = Eigen::VectorXd::Zero(model.num_dofs());
  for (int i = model.num_vertices() / 2; i < model.num_vertices(); ++i) v0[3 * i + 2] = -0.1;
  const Eigen::VectorXd x0 = jittered_start(model);
  RolloutOptions ro;
  ro.steps = 6;
  ro.time_step = 0.02;
  ro.contact_step = mode;
  ro.contact_force_tolerance = 1e-11;
  const Eigen::VectorXd w = testing::random_vector(model.num_dofs(), 9);
  const Eigen::VectorXd xf = sim.forward(p, ro, nullptr, &x0, &v0);
  // contact is active at the end
  const auto& term = dynamic_cast<const PairContactTerm&>(term_named(model, "self_contact"));
  ASSERT_GT(term.active_pairs(xf, 1e-3).size(), 10u);
  std::printf("%s: %d iterations (%d cut by collision detection)\n",
              mode == RolloutOptions::ContactStep::kNewton ? "newton" : "linearised", sim.timing().newton_iterations,
              sim.timing().cut_iterations);
  const RolloutGradient g = sim.backward(w);
  RolloutOptions fo = ro;
  fo.record = false;
  // Thickness, density and one bending entry. Step 1e-5 relative: the Newton solves stop at 1e-11 of a vertex
  // weight, so L carries ~1e-12 relative noise, amplified by 1/h (relative) to ~1e-7; the truncation error is
  // O(h^2) ~1e-10 relative; both far below the 1e-4 tolerance. Linearised steps: 1e-6, as their map is only
  // piecewise smooth (K's derivative jumps where a pair crosses the activation distance): the thickness's
  // central difference moves from 11.48 (step 1e-3) over 11.54 (1e-4) and 11.526 (1e-5) to 11.5199 (1e-6)
  // against the adjoint's 11.5200; the CG solves' 1e-10 noise stays below 1e-4 at 1e-6 for the thickness. Not for
  // the bending entry: its central difference (adjoint 0.99072) is 0.99074 at 1e-4 .. 1e-5 and scatters at 1e-6 and
  // below (0.99126, 0.99252, 0.98628 at 1e-6, 3e-7, 1e-7: the noise over h), so density and bending keep 1e-5.
  for (const char* block : {"self_contact.thickness_m", "density", "bend"}) {
    const int k = model.layout().block(block).offset;
    const bool kinked = mode == RolloutOptions::ContactStep::kLinearised &&
                        std::string(block) == "self_contact.thickness_m";
    const double h = (kinked ? 1e-6 : 1e-5) * std::abs(p[k]);
    double fd;
    if (std::string(block) == "self_contact.thickness_m") {
      // structural: the two sides are models built with the thickness moved (same layout and parameters else)
      Model mp(mesh, self_contact_options(p[k] + h)), mm(mesh, self_contact_options(p[k] - h));
      ImplicitEuler sp(mp), sm(mm);
      fd = (w.dot(sp.forward(mp.default_parameters(), fo, nullptr, &x0, &v0)) -
            w.dot(sm.forward(mm.default_parameters(), fo, nullptr, &x0, &v0))) / (2 * h);
    } else {
      Eigen::VectorXd pp = p, pm = p;
      pp[k] += h;
      pm[k] -= h;
      fd = (w.dot(sim.forward(pp, fo, nullptr, &x0, &v0)) - w.dot(sim.forward(pm, fo, nullptr, &x0, &v0))) / (2 * h);
    }
    EXPECT_NEAR(g.parameters[k], fd, 1e-4 * std::abs(fd)) << block;
    std::printf("rollout gradient %s: adjoint %.9g, central difference %.9g\n", block, g.parameters[k], fd);
  }
}

TEST(SelfContact, LinearisedRolloutGradientMatchesCentralDifferences) {
  check_rollout_gradient(RolloutOptions::ContactStep::kLinearised);
}

// One linearised step from the stacked sheets `gap` apart (the upper one falling at 0.1 m/s), its adjoint term by
// term for L = wx . x_{t+1} + wv . v_{t+1}: dL/dx_t, dL/dv_t (directional) and dL/dp (density, a bend entry,
// friction) against central differences of the step map. Returns the relative errors (x_t, v_t, worst p).
// Position steps 1e-8 m: a linearised step is piecewise smooth only (K's x-derivative jumps where a pair enters
// the activation distance, b'''(dhat) != 0), and steps of 1e-6 m on every vertex already straddle such kinks.
std::array<double, 3> linearised_step_errors(double gap, double mu) {
  const TriangleMesh mesh = stacked_sheets(5, 0.04, 2e-3);
  Model model(mesh, self_contact_options(1e-3));
  Eigen::VectorXd p = model.default_parameters();
  p[model.layout().block("self_contact.friction").offset] = mu;
  const int n = model.num_dofs();
  Eigen::VectorXd v0 = Eigen::VectorXd::Zero(n);
  for (int i = model.num_vertices() / 2; i < model.num_vertices(); ++i) v0[3 * i + 2] = -0.1;
  Eigen::VectorXd x0 = jittered_start(model);
  for (int i = model.num_vertices() / 2; i < model.num_vertices(); ++i) x0[3 * i + 2] -= 2e-3 - gap;
  RolloutOptions ro;
  ro.steps = 1;
  ro.time_step = 0.02;
  ro.contact_step = RolloutOptions::ContactStep::kLinearised;
  ImplicitEuler sim(model);
  sim.forward(p, ro, nullptr, &x0, &v0);
  EXPECT_GT(sim.timing().cg_iterations, 0) << "pairs couple vertices off the pattern";
  std::printf("gap %.2g mm, friction %g: %d iterations (%d cut), %d CG iterations\n", 1e3 * gap, mu,
              sim.timing().newton_iterations, sim.timing().cut_iterations, sim.timing().cg_iterations);
  const Eigen::VectorXd wx = testing::random_vector(n, 9), wv = testing::random_vector(n, 10);
  const RolloutGradient g = sim.backward(wx, &wv);
  RolloutOptions fo = ro;
  fo.record = false;
  auto L = [&](const Eigen::VectorXd& pp, const Eigen::VectorXd& xx, const Eigen::VectorXd& vv) {
    ImplicitEuler s(model);
    const Eigen::VectorXd xf = s.forward(pp, fo, nullptr, &xx, &vv);
    return wx.dot(xf) + wv.dot(s.velocities());
  };
  const Eigen::VectorXd dx = testing::random_vector(n, 11), dv = testing::random_vector(n, 12);
  const double ex = 1e-8, ev = 1e-6;
  const double fdx = (L(p, x0 + ex * dx, v0) - L(p, x0 - ex * dx, v0)) / (2 * ex);
  const double fdv = (L(p, x0, v0 + ev * dv) - L(p, x0, v0 - ev * dv)) / (2 * ev);
  std::printf("  dL/dx_t . d: adjoint %.9g, central difference %.9g\n", g.positions0.dot(dx), fdx);
  std::printf("  dL/dv_t . d: adjoint %.9g, central difference %.9g\n", g.velocities0.dot(dv), fdv);
  std::array<double, 3> e{rel(g.positions0.dot(dx), fdx), rel(g.velocities0.dot(dv), fdv), 0.0};
  for (const char* block : {"density", "bend", "self_contact.friction"}) {
    const int k = model.layout().block(block).offset;
    if (p[k] == 0) continue;
    const double h = 1e-5 * std::abs(p[k]);
    Eigen::VectorXd pp = p, pm = p;
    pp[k] += h;
    pm[k] -= h;
    const double fd = (L(pp, x0, v0) - L(pm, x0, v0)) / (2 * h);
    std::printf("  dL/d%s: adjoint %.9g, central difference %.9g\n", block, g.parameters[k], fd);
    e[2] = std::max(e[2], rel(g.parameters[k], fd));
  }
  return e;
}

// Pairs active only in the step's later iterations (2 mm apart: the first move is cut), and from its start
// (0.4 mm apart) without friction: the adjoint is the step map's derivative.
TEST(SelfContact, LinearisedStepAdjointMatchesCentralDifferences) {
  for (const auto& [gap, mu] : {std::pair{2e-3, 0.3}, std::pair{4e-4, 0.0}, std::pair{8e-4, 0.0}}) {
    const auto e = linearised_step_errors(gap, mu);
    EXPECT_LT(e[0], 1e-5) << "dL/dx_t, gap " << gap;
    EXPECT_LT(e[1], 1e-5) << "dL/dv_t, gap " << gap;
    EXPECT_LT(e[2], 1e-4) << "dL/dp, gap " << gap;
  }
}

// With friction acting from the step's start the adjoint includes how x_t enters the lagged friction: as the
// slip's start and through the lagged normal forces, normals and closest-point weights (Term::
// add_step_start_adjoint; before, dL/dx_t was 2.4 % and 3.1 % off here without the lagged quantities' part, 3.5 %
// and 15 % without the slip's start either).
TEST(SelfContact, LinearisedStepAdjointWithLaggedFriction) {
  for (double gap : {4e-4, 8e-4}) {
    const auto e = linearised_step_errors(gap, 0.3);
    EXPECT_LT(e[0], 1e-5) << "dL/dx_t, gap " << gap;
    EXPECT_LT(e[1], 1e-5) << "dL/dv_t, gap " << gap;
    EXPECT_LT(e[2], 1e-4) << "dL/dp, gap " << gap;
  }
}

TEST(SelfContact, RolloutGradientMatchesCentralDifferences) {
  check_rollout_gradient(RolloutOptions::ContactStep::kNewton);
}

TEST(SelfContact, FrictionDerivativesMatchCentralDifferences) {
  const TriangleMesh mesh = stacked_sheets(6, 0.05, 6e-4);
  ModelOptions o = self_contact_options(1e-3);
  o.effects["self_contact"]["friction"] = 0.4;
  Model model(mesh, o);
  const Eigen::VectorXd p = model.default_parameters();
  const int n = model.num_dofs();
  Eigen::VectorXd x = model.rest_positions();
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(-1, 1);
  for (int i = 0; i < n; ++i) x[i] += 1e-4 * u(rng);
  Term& term = const_cast<Term&>(term_named(model, "self_contact"));
  // the step started 0-40 um away in the plane: slips both in the smoothed (< eps_v h = 50 um) and the
  // sliding regime
  Eigen::VectorXd start = x;
  for (int i = 0; i < model.num_vertices(); ++i) {
    start[3 * i] -= 4e-5 * std::sin(i);
    start[3 * i + 1] += 4e-5 * std::cos(3 * i);
  }
  const double E0 = term.energy(x, p);
  term.begin_step(start, p, 0.05);
  const double E1 = term.energy(x, p);
  EXPECT_GT(E1, E0) << "friction adds dissipation potential";
  const SparsePattern& pat = model.pattern();
  for (unsigned s = 0; s < 3; ++s) {
    const Eigen::VectorXd d = testing::random_vector(n, 60 + s);
    const double eps = 1e-9;
    Eigen::VectorXd g = Eigen::VectorXd::Zero(n), gp = g, gm = g, Hd = g, rest = g;
    term.add_gradient(x, p, g);
    const double fd = (term.energy(x + eps * d, p) - term.energy(x - eps * d, p)) / (2 * eps);
    EXPECT_LT(rel(g.dot(d), fd), 1e-6) << "gradient";
    term.add_gradient(x + eps * d, p, gp);
    term.add_gradient(x - eps * d, p, gm);
    term.add_hessian_product(x, p, d, Hd);
    const Eigen::VectorXd fdH = (gp - gm) / (2 * eps);
    EXPECT_LE((Hd - fdH).norm(), 1e-5 * fdH.norm()) << "Hessian product";
    Eigen::VectorXd H = Eigen::VectorXd::Zero(pat.nnz());
    term.add_hessian(x, p, 1.0, H);
    term.add_offpattern_hessian_product(x, p, d, false, rest);
    EXPECT_LE((symmetric_multiply(pat, H, d) + rest - Hd).norm(), 1e-10 * Hd.norm()) << "assembled + off-pattern";
  }
  const int k = model.layout().block("self_contact.friction").offset;
  const Eigen::VectorXd lambda = testing::random_vector(n, 78);
  Eigen::VectorXd dEdp = Eigen::VectorXd::Zero(p.size()), dgdp = dEdp;
  term.add_energy_parameter_gradient(x, p, dEdp);
  term.add_gradient_parameter_product(x, p, lambda, 1.0, dgdp);
  Eigen::VectorXd pp = p, pm = p;
  pp[k] += 1e-6;
  pm[k] -= 1e-6;
  EXPECT_GT(std::abs(dEdp[k]), 0.0);
  EXPECT_LT(rel(dEdp[k], (term.energy(x, pp) - term.energy(x, pm)) / 2e-6), 1e-6);
  Eigen::VectorXd g1 = Eigen::VectorXd::Zero(n), g2 = g1;
  term.add_gradient(x, pp, g1);
  term.add_gradient(x, pm, g2);
  EXPECT_LT(rel(dgdp[k], lambda.dot(g1 - g2) / 2e-6), 1e-6);
}

TEST(SelfContact, FrictionHoldsASheetOnASlope) {
  // A 4 cm sheet resting 0.6 mm over a held 12 cm sheet tilted by atan(0.3) = 16.7 deg: without friction it
  // slides off within the second; with mu = 0.6 > 0.3 it sticks (creeping at most at the smoothing speed,
  // 1 mm/s).
  TriangleMesh mesh = stacked_sheets(13, 0.12, 6e-4, 7, 0.04);
  for (int i = 0; i < mesh.num_vertices(); ++i) mesh.positions(i, 2) += 0.3 * mesh.positions(i, 0);
  const int first_upper = 13 * 13;
  auto slide = [&](double mu) {
    ModelOptions o = self_contact_options(1e-3);
    o.effects["self_contact"]["friction"] = mu;
    Model model(mesh, o);
    ImplicitEuler sim(model);
    RolloutOptions ro;
    ro.steps = 20;
    ro.record = false;
    const Eigen::VectorXd x = sim.forward(model.default_parameters(), ro);
    const ContactReport r = contact_report(mesh.faces, x);
    EXPECT_EQ(r.intersecting_pairs, 0);
    double moved = 0;
    for (int i = first_upper; i < model.num_vertices(); ++i) moved += std::abs(x[3 * i] - mesh.positions(i, 0));
    return moved / (model.num_vertices() - first_upper);
  };
  const double stick = slide(0.6), slip = slide(0.0);
  EXPECT_LT(stick, 3e-3);
  EXPECT_GT(slip, 3e-2);
  std::printf("sheet on a 16.7 deg slope, 1 s: mean slide %.3g mm with mu 0.6, %.3g mm without friction\n",
              1e3 * stick, 1e3 * slip);
}

TEST(SelfContact, StaticSolveAndAdjointWithActivePairs) {
  // Two 6 cm sheets 0.6 mm apart, both held at their centres (uv alike, support radius 1.2 cm): their rims droop
  // together, the upper resting on the lower within the 1 mm thickness (pairs active at the equilibrium).
  TriangleMesh mesh = stacked_sheets(9, 0.06, 6e-4);
  mesh.uv.bottomRows(81).col(0).array() -= 0.5;
  ModelOptions o = self_contact_options(1e-3);
  o.support_radius = 0.012;
  Model model(mesh, o);
  const Eigen::VectorXd p = model.default_parameters();
  StaticSolver solver(model);
  StaticOptions tight;
  tight.force_tolerance = 1e-10;
  const StaticResult r = solver.solve(p, tight);
  const auto& term = dynamic_cast<const PairContactTerm&>(term_named(model, "self_contact"));
  ASSERT_GT(term.active_pairs(r.positions, 1e-3).size(), 20u);
  const ContactReport report = contact_report(mesh.faces, r.positions);
  EXPECT_EQ(report.intersecting_pairs, 0);
  EXPECT_GT(report.min_distance_m, 0.0);
  const Eigen::VectorXd w = testing::random_vector(model.num_dofs(), 12);
  const Eigen::VectorXd g = solver.adjoint(w);
  // Central differences, warm-started on one branch; h = 1e-4 relative: solves stop at 1e-10 of a vertex weight
  // (noise ~1e-10 relative / h = 1e-6), truncation O(h^2) = 1e-8, both below the 1e-4 tolerance.
  for (const char* block : {"self_contact.thickness_m", "density"}) {
    const int k = model.layout().block(block).offset;
    const double h = 1e-4 * std::abs(p[k]);
    double fd;
    if (std::string(block) == "self_contact.thickness_m") {  // structural: models built with it moved
      ModelOptions op = o, om = o;
      op.effects["self_contact"]["thickness_m"] = p[k] + h;
      om.effects["self_contact"]["thickness_m"] = p[k] - h;
      Model mp(mesh, op), mm(mesh, om);
      StaticSolver sp(mp), sm(mm);
      fd = (w.dot(sp.solve(mp.default_parameters(), tight, nullptr, &r.positions).positions) -
            w.dot(sm.solve(mm.default_parameters(), tight, nullptr, &r.positions).positions)) / (2 * h);
    } else {
      Eigen::VectorXd pp = p, pm = p;
      pp[k] += h;
      pm[k] -= h;
      fd = (w.dot(solver.solve(pp, tight, nullptr, &r.positions).positions) -
            w.dot(solver.solve(pm, tight, nullptr, &r.positions).positions)) / (2 * h);
    }
    EXPECT_NEAR(g[k], fd, 1e-4 * std::abs(fd)) << block;
    std::printf("static gradient %s: adjoint %.9g, central difference %.9g\n", block, g[k], fd);
  }
}

TEST(SelfContact, StartingIntersectedIsAnErrorNamingTheTriangles) {
  TriangleMesh mesh = stacked_sheets(5, 0.04, 1e-3);
  // tilt the upper sheet through the lower one
  const int nv = mesh.num_vertices() / 2;
  for (int i = nv; i < 2 * nv; ++i) mesh.positions(i, 2) = 0.5 * mesh.positions(i, 0);
  Model model(mesh, self_contact_options(1e-3));
  ImplicitEuler sim(model);
  RolloutOptions ro;
  ro.steps = 1;
  try {
    sim.forward(model.default_parameters(), ro);
    FAIL() << "no error";
  } catch (const SolverError& e) {
    EXPECT_NE(std::string(e.what()).find("cloth triangle"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("intersect"), std::string::npos) << e.what();
  }
  EXPECT_GT(contact_report(mesh.faces, model.rest_positions()).intersecting_pairs, 0);
}

// max_step's swept broad phase keeps its candidates for the states along its move (contact/pair_contact.cpp): the
// active pairs found from them anywhere on the segment equal a fresh term's (its own broad phase at that state).
TEST(SelfContact, SweptCandidatesGiveTheActivePairsAlongTheMove) {
  const TriangleMesh mesh = stacked_sheets(7, 0.05, 2e-3);
  Model model(mesh, self_contact_options(1e-3));
  const Eigen::VectorXd p = model.default_parameters();
  const auto& term = dynamic_cast<const PairContactTerm&>(term_named(model, "self_contact"));
  const int n = model.num_dofs();
  const Eigen::VectorXd x0 = jittered_start(model);
  Eigen::VectorXd dx = 1e-4 * testing::random_vector(n, 5);
  for (int i = model.num_vertices() / 2; i < model.num_vertices(); ++i) dx[3 * i + 2] -= 1.8e-3;  // 0.2 mm apart
  const double alpha = term.max_step(x0, dx, p);
  ASSERT_GT(alpha, 0.5);
  size_t active_at_end = 0;
  for (double s : {0.0, 0.3, 0.55, 0.8, 1.0}) {
    const Eigen::VectorXd x = x0 + s * alpha * dx;
    Model fresh_model(mesh, self_contact_options(1e-3));
    const auto& fresh = dynamic_cast<const PairContactTerm&>(term_named(fresh_model, "self_contact"));
    const std::vector<ActivePair> a = term.active_pairs(x, 1e-3), b = fresh.active_pairs(x, 1e-3);
    ASSERT_EQ(a.size(), b.size()) << "s = " << s;
    for (size_t k = 0; k < a.size(); ++k) {
      EXPECT_EQ(a[k].kind, b[k].kind);
      EXPECT_EQ(a[k].type, b[k].type);
      EXPECT_EQ(a[k].v, b[k].v);
    }
    active_at_end = a.size();
  }
  EXPECT_GT(active_at_end, 20u) << "the layers end within the thickness";
}

// Two identical models of two stacked sheets 0.4 mm apart with self contact and friction 0.3 (one to restore a
// state into, its twin to compute it afresh); xt: the jittered start.
struct TwinStackedSheets {
  TriangleMesh mesh = stacked_sheets(5, 0.04, 2e-3);
  ModelOptions o = options();
  Model model{mesh, o}, other{mesh, o};
  Eigen::VectorXd p = parameters(model);
  PairContactTerm *term = pair_term(model), *twin = pair_term(other);
  int n = model.num_dofs();
  Eigen::VectorXd xt = start(model);

  static ModelOptions options() {
    ModelOptions o = self_contact_options(1e-3);
    o.effects["self_contact"]["friction"] = 0.3;
    return o;
  }
  static Eigen::VectorXd parameters(const Model& m) {
    Eigen::VectorXd p = m.default_parameters();
    p[m.layout().block("self_contact.friction").offset] = 0.3;
    return p;
  }
  static PairContactTerm* pair_term(const Model& m) {
    for (const auto& t : m.terms())
      if (t->name() == "self_contact") return dynamic_cast<PairContactTerm*>(t.get());
    throw std::runtime_error("no self_contact term");
  }
  static Eigen::VectorXd start(const Model& m) {
    Eigen::VectorXd xt = jittered_start(m);
    for (int i = m.num_vertices() / 2; i < m.num_vertices(); ++i) xt[3 * i + 2] -= 1.6e-3;  // 0.4 mm apart
    return xt;
  }
};

// The state a step began with (SteppedContact::step_state: lagged friction pairs, active pairs and candidates at
// its start), restored after other steps, gives the energy, gradient and friction start adjoint of a term that
// began that step itself, bit for bit (the adjoint restores it instead of a broad phase; continue_step is
// begin_step without the intersection check).
TEST(SelfContact, RestoredStepStateMatchesABegunStep) {
  TwinStackedSheets sheets;
  PairContactTerm *term = sheets.term, *begun = sheets.twin;
  const int n = sheets.n;
  const Eigen::VectorXd &xt = sheets.xt, &p = sheets.p;
  const Eigen::VectorXd x = xt + 1e-5 * testing::random_vector(n, 3), lambda = testing::random_vector(n, 4);
  const double h = 0.02;
  term->begin_step(xt, p, h);
  const std::shared_ptr<const void> state = term->step_state();
  term->continue_step(xt + 1e-4 * testing::random_vector(n, 6), p, h);  // another step's state
  term->restore_step(state);
  begun->begin_step(xt, p, h);
  auto evaluate = [&](const PairContactTerm& t, double& E, Eigen::VectorXd& g, Eigen::VectorXd& start) {
    E = t.energy(x, p);
    g = Eigen::VectorXd::Zero(n);
    t.add_gradient(x, p, g);
    start = Eigen::VectorXd::Zero(n);
    t.add_step_start_adjoint(x, p, lambda, lambda, 1.0, start);
  };
  double Er, Eb;
  Eigen::VectorXd gr, gb, sr, sb;
  evaluate(*term, Er, gr, sr);
  evaluate(*begun, Eb, gb, sb);
  EXPECT_GT(sb.norm(), 0.0) << "friction pairs at the step's start";
  EXPECT_EQ(Er, Eb);
  EXPECT_EQ((gr - gb).lpNorm<Eigen::Infinity>(), 0.0);
  EXPECT_EQ((sr - sb).lpNorm<Eigen::Infinity>(), 0.0);
}

// The active pairs at an iterate of a step (SteppedContact::iterate_state), restored after the term was evaluated
// elsewhere, give the energy, gradient, Hessian product and step-matrix derivatives at that iterate of a term
// that evaluated it itself, bit for bit (the adjoint restores them instead of a broad phase at each iterate
// after a cut move); a state is taken only for the iterate the term last evaluated.
TEST(SelfContact, RestoredIterateStateMatchesAnEvaluatedIterate) {
  TwinStackedSheets sheets;
  PairContactTerm *term = sheets.term, *evaluated = sheets.twin;
  const int n = sheets.n;
  const Eigen::VectorXd &xt = sheets.xt, &p = sheets.p;
  const Eigen::VectorXd x = xt + 1e-5 * testing::random_vector(n, 3), lambda = testing::random_vector(n, 4),
                        w = testing::random_vector(n, 5);
  const Eigen::VectorXd elsewhere = xt + 3e-4 * testing::random_vector(n, 6);
  const double h = 0.02;
  term->begin_step(xt, p, h);
  const double E_iterate = term->energy(x, p);  // the iterate's assembly finds its pairs
  const std::shared_ptr<const void> state = term->iterate_state(x);
  ASSERT_TRUE(state);
  EXPECT_FALSE(term->iterate_state(elsewhere)) << "the term has not evaluated that state";
  term->energy(elsewhere, p);  // a later iterate's pairs replace the cached ones
  EXPECT_FALSE(term->iterate_state(x));
  term->restore_iterate(state, x);
  EXPECT_TRUE(term->iterate_state(x)) << "the restored pairs are the term's pairs at x (no evaluation needed)";
  evaluated->begin_step(xt, p, h);
  auto evaluate = [&](const PairContactTerm& t, double& E, Eigen::VectorXd& g, Eigen::VectorXd& Hl,
                      Eigen::VectorXd& gx, Eigen::VectorXd& gp) {
    E = t.energy(x, p);
    g = Eigen::VectorXd::Zero(n);
    t.add_gradient(x, p, g);
    Hl = Eigen::VectorXd::Zero(n);
    t.add_hessian_product(x, p, lambda, Hl);
    gx = Eigen::VectorXd::Zero(n);
    gp = Eigen::VectorXd::Zero(p.size());
    t.add_step_matrix_derivatives(x, p, lambda, w, 1.0, gx, gp);
  };
  double Er, Ee;
  Eigen::VectorXd gr, ge, Hr, He, xr, xe, pr, pe;
  evaluate(*term, Er, gr, Hr, xr, pr);
  evaluate(*evaluated, Ee, ge, He, xe, pe);
  EXPECT_GT(Ee, 0.0) << "pairs within the thickness at the iterate";
  EXPECT_EQ(Er, E_iterate);
  EXPECT_EQ(Er, Ee);
  EXPECT_EQ((gr - ge).lpNorm<Eigen::Infinity>(), 0.0);
  EXPECT_EQ((Hr - He).lpNorm<Eigen::Infinity>(), 0.0);
  EXPECT_EQ((xr - xe).lpNorm<Eigen::Infinity>(), 0.0);
  EXPECT_EQ((pr - pe).lpNorm<Eigen::Infinity>(), 0.0);
}

// The pair friction's step-start adjoint (Term::add_step_start_adjoint): the x_t-derivative of
// lambda . grad E(x) + c lambda^T K(x) w at fixed x, where the term began its step at x_t (the slip's start and
// the lagged normal forces, normals and closest-point weights), against central differences of begin_step's x_t.
TEST(SelfContact, FrictionStepStartAdjointMatchesCentralDifferences) {
  const TriangleMesh mesh = stacked_sheets(5, 0.04, 2e-3);
  ModelOptions o = self_contact_options(1e-3);
  o.effects["self_contact"]["friction"] = 0.3;
  Model model(mesh, o);
  Eigen::VectorXd p = model.default_parameters();
  p[model.layout().block("self_contact.friction").offset] = 0.3;
  Term* term = nullptr;
  for (const auto& t : model.terms())
    if (t->name() == "self_contact") term = t.get();
  ASSERT_NE(term, nullptr);
  const int n = model.num_dofs();
  Eigen::VectorXd xt = jittered_start(model);
  for (int i = model.num_vertices() / 2; i < model.num_vertices(); ++i) xt[3 * i + 2] -= 1.5e-3;  // 0.5 mm apart
  const double h = 0.02;
  for (double slip : {5e-6, 2e-4}) {  // within the stick zone (eps_v h = 2e-5 m) and sliding
    const Eigen::VectorXd x = xt + slip * testing::random_vector(n, 42);
    const Eigen::VectorXd lambda = testing::random_vector(n, 43), w = testing::random_vector(n, 44);
    const double c = 0.7;
    auto phi = [&](const Eigen::VectorXd& start) {
      term->resume_step(start, p, h);
      Eigen::VectorXd g = Eigen::VectorXd::Zero(n), Kw = Eigen::VectorXd::Zero(n);
      term->add_gradient(x, p, g);
      // K w = the assembled diagonal blocks' product plus the off-pattern remainder's
      Eigen::VectorXd values = Eigen::VectorXd::Zero(model.pattern().nnz());
      term->add_step_matrix(x, p, 1.0, values);
      Kw = symmetric_multiply(model.pattern(), values, w);
      term->add_offpattern_step_matrix_product(x, p, w, Kw);
      return lambda.dot(g) + c * lambda.dot(Kw);
    };
    const Eigen::VectorXd d = testing::random_vector(n, 45);
    const double e = 1e-9;
    const double fd = (phi(xt + e * d) - phi(xt - e * d)) / (2 * e);
    term->resume_step(xt, p, h);
    Eigen::VectorXd gxt = Eigen::VectorXd::Zero(n);
    term->add_step_start_adjoint(x, p, lambda, w, c, gxt);
    std::printf("pair friction start adjoint (slip %g m): %.9g, central difference %.9g\n", slip, gxt.dot(d), fd);
    EXPECT_NEAR(gxt.dot(d), fd, 1e-5 * std::abs(fd)) << "slip " << slip;
  }
}

}  // namespace
}  // namespace drapelab
