// Cloth edges against the garment body (garment/revolved_edge.hpp, garment/revolved_body.hpp): the segment's
// minimum clearance against dense sampling, the edge barrier's derivatives against central differences (smooth
// interior minima, minima at a profile corner, the hand-over weight, a moving pose), the PSD step matrix, and a
// coarse cloth ring around a leg whose chords cut it between vertices: refused by the edge barrier and stopped by
// the edge CCD, for the cloth moving and for the leg swinging into a long edge.
#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>
#include <cmath>
#include <random>

#include "contact/barrier.hpp"
#include "contact/pair_barrier.hpp"
#include "garment/revolved_body.hpp"
#include "physics/model.hpp"
#include "physics/sparse_pattern.hpp"
#include "solver/implicit_euler.hpp"
#include "../test_support.hpp"

namespace drapelab {
namespace {

constexpr double kReach = 2e-3;

// A leg hanging from (x, 0, 1): conical ends, a bulge to 7 cm at s = 0.3 (a convex corner: minima sit on it).
RevolvedPart bulged_leg(double x) {
  return RevolvedPart{Eigen::Vector3d(x, 0, 1), {0.0, 0.06, 0.3, 0.5, 0.56}, {0.0, 0.06, 0.07, 0.06, 0.0}};
}
RevolvedPart leg(double x) {  // radius 6 cm, conical ends, 56 cm long
  return RevolvedPart{Eigen::Vector3d(x, 0, 1), {0.0, 0.06, 0.5, 0.56}, {0.0, 0.06, 0.06, 0.0}};
}

ProfileView view(const RevolvedPart& p) {
  return ProfileView{p.origin.data(), p.s.data(), p.r.data(), static_cast<int>(p.s.size())};
}

// g of a world point against a part at rest (the vertex clearance) and the minimum over dense samples of a segment.
double sampled_minimum(const RevolvedBodyContact& body, int k, const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                       int n = 20000) {
  double best = INFINITY;
  for (int i = 0; i <= n; ++i) best = std::min(best, body.part_clearance(k, a + (b - a) * (double(i) / n)));
  return best;
}

double worst_edge_sampled(const RevolvedBodyContact& body, const Eigen::VectorXd& x, int n = 2000) {
  double best = INFINITY;
  for (const auto& e : body.edges())
    for (int k = 0; k < 1; ++k)
      best = std::min(best, sampled_minimum(body, k, x.segment<3>(3 * e[0]), x.segment<3>(3 * e[1]), n));
  return best;
}

TEST(RevolvedBodyEdges, SegmentMinimumMatchesDenseSampling) {
  const RevolvedPart part = bulged_leg(0.0);
  RevolvedBodyContact body{{part}, Eigen::VectorXd::Constant(2, 1e-4), kReach};
  const ProfileView P = view(part);
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-1, 1), h(0.3, 1.1), len(0.002, 0.15);
  int kinds[3] = {0, 0, 0};
  double worst = 0;
  for (int trial = 0; trial < 3000; ++trial) {
    // Points around the part (including beyond the apexes and inside it), edges of 2 mm to 15 cm.
    const double ang = 3.14159 * u(rng), rad = 0.075 + 0.03 * u(rng);
    const Eigen::Vector3d a(rad * std::cos(ang), rad * std::sin(ang), h(rng));
    const Eigen::Vector3d b = a + len(rng) * Eigen::Vector3d(u(rng), u(rng), u(rng)).normalized();
    const SegmentPartMinimum m = segment_part_minimum(P, a.data(), b.data());
    ++kinds[m.kind];
    const double sampled = sampled_minimum(body, 0, a, b, 4000);
    ASSERT_LE(m.clearance, sampled + 1e-12) << trial;  // the minimum is at most any sample
    ASSERT_NEAR(body.part_clearance(0, a + m.t * (b - a)), m.clearance, 1e-12) << trial;  // and is attained
    // ... and the samples come within their spacing's reach of it (g is Lipschitz, its minimum smooth or a kink)
    worst = std::max(worst, sampled - m.clearance);
    ASSERT_LT(sampled - m.clearance, 8.0 * (b - a).norm() / 4000) << trial;
  }
  EXPECT_GT(kinds[SegmentPartMinimum::kSmooth], 100);
  EXPECT_GT(kinds[SegmentPartMinimum::kKink], 10);
  EXPECT_GT(kinds[SegmentPartMinimum::kEnd], 100);
  std::printf("segment minima: %d end, %d smooth, %d kink; dense samples above the minimum by at most %.3g m\n",
              kinds[0], kinds[1], kinds[2], worst);
}

// The Hessian's values in the pattern as a dense symmetric matrix.
Eigen::MatrixXd dense(const SparsePattern& pattern, const Eigen::VectorXd& values) {
  return testing::dense_symmetric(pattern, values);
}

// Central differences of energy, gradient and Hessian at x; the step matrix is PSD; the edges add energy.
void check_derivatives(RevolvedBodyContact& body, const Eigen::VectorXd& x, const char* what) {
  const int n = static_cast<int>(x.size());
  const SparsePattern pattern(n / 3, body.stencils());
  body.bind_pattern(pattern);
  const Eigen::VectorXd p;
  const double Ee = body.edge_energy(x);
  ASSERT_GT(Ee, 0.0) << what << ": the edges are not in reach";
  ASSERT_TRUE(std::isfinite(Ee)) << what;
  Eigen::VectorXd g = Eigen::VectorXd::Zero(n);
  body.add_gradient(x, p, g);
  Eigen::VectorXd values = Eigen::VectorXd::Zero(pattern.nnz());
  body.add_hessian(x, p, 1.0, values);
  const Eigen::MatrixXd H = dense(pattern, values);
  const double eps = 1e-8;
  for (int j = 0; j < n; ++j) {
    Eigen::VectorXd xp = x, xm = x;
    xp[j] += eps;
    xm[j] -= eps;
    const double fd = (body.energy(xp, p) - body.energy(xm, p)) / (2 * eps);
    EXPECT_NEAR(g[j], fd, 1e-6 * g.lpNorm<Eigen::Infinity>()) << what << " gradient " << j;
    Eigen::VectorXd gp = Eigen::VectorXd::Zero(n), gm = Eigen::VectorXd::Zero(n);
    body.add_gradient(xp, p, gp);
    body.add_gradient(xm, p, gm);
    const Eigen::VectorXd fdcol = (gp - gm) / (2 * eps);
    EXPECT_LT((H.col(j) - fdcol).norm(), 1e-5 * H.norm()) << what << " Hessian column " << j;
    Eigen::VectorXd e = Eigen::VectorXd::Zero(n), hcol = Eigen::VectorXd::Zero(n);
    e[j] = 1;
    body.add_hessian_product(x, p, e, hcol);
    EXPECT_LT((H.col(j) - hcol).norm(), 1e-12 * H.norm()) << what << " Hessian product " << j;
  }
  Eigen::VectorXd step = Eigen::VectorXd::Zero(pattern.nnz()), proj = Eigen::VectorXd::Zero(pattern.nnz());
  body.add_step_matrix(x, p, 1.0, step);
  body.add_projected_hessian(x, p, 1.0, proj);
  const double tol = 1e-10 * H.norm();
  EXPECT_GT(Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd>(dense(pattern, step)).eigenvalues().minCoeff(), -tol) << what;
  EXPECT_GT(Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd>(dense(pattern, proj)).eigenvalues().minCoeff(), -tol) << what;
}

// Two points at radius rad around part axis (cx, 0) at angles a0, a1 and heights z0, z1.
void place(Eigen::VectorXd& x, int i, double cx, double rad, double a, double z) {
  x.segment<3>(3 * i) = Eigen::Vector3d(cx + rad * std::cos(a), rad * std::sin(a), z);
}

TEST(RevolvedBodyEdges, EdgeBarrierDerivativesMatchCentralDifferences) {
  // (1) chords around a straight leg dipping 0.7 mm below their ends (weight 1), (2) dipping 0.08 mm (the
  // hand-over weight between 0 and 1), (3) a nearly vertical edge across the bulge's corner (a kink minimum).
  const double R = 0.06 + 1.5e-3;
  {
    RevolvedBodyContact body{{leg(0.1)}, Eigen::VectorXd::Constant(4, 1e-4), kReach, {{0, 1}, {2, 3}}};
    Eigen::VectorXd x(12);
    place(x, 0, 0.1, R, 0.3, 0.7), place(x, 1, 0.1, R, 0.6, 0.705);
    place(x, 2, 0.1, R, 2.0, 0.72), place(x, 3, 0.1, R + 1e-4, 2.1, 0.716);
    const Eigen::VectorXd y = x;
    const SegmentPartMinimum m0 = segment_part_minimum(view(leg(0.1)), y.data(), y.data() + 3);
    const SegmentPartMinimum m1 = segment_part_minimum(view(leg(0.1)), y.data() + 6, y.data() + 9);
    ASSERT_EQ(m0.kind, SegmentPartMinimum::kSmooth);
    ASSERT_EQ(m1.kind, SegmentPartMinimum::kSmooth);
    const double dip0 = 1.5e-3 - m0.clearance, dip1 = 1.5e-3 - m1.clearance;  // (the nearer end's dip)
    EXPECT_GT(dip0, 1e-4);                     // weight 1
    EXPECT_TRUE(dip1 > 1e-5 && dip1 < 1e-4);  // inside the hand-over
    check_derivatives(body, x, "chords");
  }
  {
    RevolvedBodyContact body{{bulged_leg(0.0)}, Eigen::VectorXd::Constant(2, 1e-4), kReach, {{0, 1}}};
    Eigen::VectorXd x(6);
    place(x, 0, 0.0, 0.07 + 1.2e-3, 0.4, 1 - 0.27), place(x, 1, 0.0, 0.07 + 1.1e-3, 0.41, 1 - 0.33);
    const SegmentPartMinimum m = segment_part_minimum(view(bulged_leg(0.0)), x.data(), x.data() + 3);
    ASSERT_EQ(m.kind, SegmentPartMinimum::kKink);
    check_derivatives(body, x, "kink");
  }
  {
    // A moving pose: the leg swung by 0.08 rad about its hip and shifted, 0.4 of the way.
    RevolvedBodyContact body{{leg(0.1)}, Eigen::VectorXd::Constant(2, 1e-4), kReach, {{0, 1}}};
    const Eigen::Vector3d hip(0.1, 0, 1);
    RigidPose swing;
    swing.R = Eigen::AngleAxisd(0.08, Eigen::Vector3d::UnitX()).toRotationMatrix();
    swing.c = hip - swing.R * hip + Eigen::Vector3d(0, 0.01, 0);
    body.set_poses({RigidPose{}}, {swing});
    body.advance_obstacle(0.4);
    const RigidPose P = RevolvedBodyContact::interpolate(RigidPose{}, swing, 0.4);
    Eigen::VectorXd local(6), x(6);
    place(local, 0, 0.1, R, 1.0, 0.6), place(local, 1, 0.1, R, 1.35, 0.61);
    for (int i = 0; i < 2; ++i) x.segment<3>(3 * i) = P.R * local.segment<3>(3 * i) + P.c;
    check_derivatives(body, x, "moving pose");
  }
}

TEST(RevolvedBodyEdges, HandOverToTheVertexBarrierIsContinuous) {
  // A chord whose minimum runs from end a through the inside to end b as b moves in: the edge energy rises from 0
  // and falls back to 0 continuously (the vertex barriers take over at both ends).
  RevolvedBodyContact body{{leg(0.0)}, Eigen::VectorXd::Constant(2, 1e-4), kReach, {{0, 1}}};
  Eigen::VectorXd x(6);
  double last = -1, jump = 0, top = 0;
  const int steps = 2000;
  for (int i = 0; i <= steps; ++i) {
    const double rb = 0.0620 - 1.2e-3 * i / steps;
    place(x, 0, 0.0, 0.0615, 0.0, 0.7), place(x, 1, 0.0, rb, 0.1, 0.7);
    const double E = body.edge_energy(x);
    ASSERT_TRUE(std::isfinite(E));
    if (i == 0) {
      EXPECT_EQ(E, 0.0) << "the minimum at end a";
    }
    if (last >= 0) jump = std::max(jump, std::abs(E - last));
    last = E;
    top = std::max(top, E);
  }
  EXPECT_EQ(last, 0.0) << "the minimum at end b";
  EXPECT_GT(top, 0.0);
  EXPECT_LT(jump, 0.03 * top);
}

// A ring of n vertices at radius rad around a leg at x = 0.1 (height 0.7): each chord is one edge.
Eigen::VectorXd ring(int n, double rad) {
  Eigen::VectorXd x(3 * n);
  for (int i = 0; i < n; ++i) place(x, i, 0.1, rad, 2 * 3.14159265358979 * i / n, 0.7);
  return x;
}

TEST(RevolvedBodyEdges, CoarseClothCannotCutTheLegBetweenTwoVertices) {
  const int n = 8;
  std::vector<std::array<int, 2>> edges;
  for (int i = 0; i < n; ++i) edges.push_back({i, (i + 1) % n});
  RevolvedBodyContact vertices_only{{leg(0.1)}, Eigen::VectorXd::Constant(n, 1e-4), kReach};
  RevolvedBodyContact body{{leg(0.1)}, Eigen::VectorXd::Constant(n, 1e-4), kReach, edges};
  const Eigen::VectorXd p;
  // Every vertex 0.2 mm off the leg: the vertex barrier is finite, but the chords cut 4.4 mm into it.
  const Eigen::VectorXd cut = ring(n, 0.0602);
  EXPECT_NEAR(vertices_only.clearance(cut).minCoeff(), 2e-4, 1e-9);
  const double cut_edge = worst_edge_sampled(body, cut);
  EXPECT_LT(cut_edge, -4e-3);
  EXPECT_NEAR(body.edge_clearance(cut).minCoeff(), cut_edge, 1e-6);
  EXPECT_TRUE(std::isfinite(vertices_only.energy(cut, p))) << "the vertex barrier alone accepts the cut";
  EXPECT_FALSE(std::isfinite(body.energy(cut, p))) << "the edge barrier refuses it";
  // From a ring whose chords are clear (2 cm), the step toward the cut state.
  const Eigen::VectorXd safe = ring(n, 0.06 / std::cos(3.14159265358979 / n) + 0.02);
  ASSERT_GT(worst_edge_sampled(body, safe), 0.0);
  const Eigen::VectorXd dx = cut - safe;
  const double alpha_vertex = vertices_only.max_step(safe, dx, p);
  const double vertex_stop_edge = worst_edge_sampled(body, safe + alpha_vertex * dx);
  EXPECT_LT(vertex_stop_edge, 0.0) << "the vertex bound alone lets the chords through the leg";
  const double alpha = body.max_step(safe, dx, p);
  EXPECT_GT(alpha, 0.0);
  EXPECT_LT(alpha, alpha_vertex);
  const Eigen::VectorXd stop = safe + alpha * dx;
  const double stop_edge = worst_edge_sampled(body, stop);
  EXPECT_GT(stop_edge, 0.0) << "the bounded step keeps every chord off the leg";
  EXPECT_TRUE(std::isfinite(body.energy(stop, p)));
  // Not vacuous: the chords came within half of their start clearance.
  EXPECT_LT(stop_edge, 0.5 * worst_edge_sampled(body, safe));
  std::printf("ring of %d around a leg: vertex clearance 0.2 mm, chords %.2f mm inside; vertex CCD alone: alpha %.3f, "
              "chords %.2f mm; with the edge CCD: alpha %.3f, chords %.3f mm clear\n",
              n, -cut_edge * 1e3, alpha_vertex, vertex_stop_edge * 1e3, alpha, stop_edge * 1e3);
}

TEST(RevolvedBodyEdges, SwingingLegIsStoppedByALongEdgeBetweenFarVertices) {
  // A 30 cm edge in front of the right leg, its ends 15 cm to either side (far from both legs): the leg swings
  // forward 0.3 rad about its hip into it. Vertices alone never see the leg; the edge stops the advance.
  const Eigen::Vector3d hip(0.1, 0, 1);
  RigidPose swing;
  swing.R = Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitX()).toRotationMatrix();  // the foot moves to +y
  swing.c = hip - swing.R * hip;
  Eigen::VectorXd x(6);
  x << 0.1 - 0.15, 0.09, 0.6, 0.1 + 0.15, 0.09, 0.6;
  const Eigen::VectorXd u = Eigen::VectorXd::Zero(6);
  RevolvedBodyContact vertices_only{{leg(0.1)}, Eigen::VectorXd::Constant(2, 1e-4), kReach};
  RevolvedBodyContact body{{leg(0.1)}, Eigen::VectorXd::Constant(2, 1e-4), kReach, {{0, 1}}};
  vertices_only.set_poses({RigidPose{}}, {swing});
  body.set_poses({RigidPose{}}, {swing});
  EXPECT_EQ(vertices_only.obstacle_max_advance(x, u), 1.0);
  const double tau = body.obstacle_max_advance(x, u);
  EXPECT_GT(tau, 0.0);
  EXPECT_LT(tau, 1.0);
  auto edge_at = [&](double t) {
    const RigidPose P = RevolvedBodyContact::interpolate(RigidPose{}, swing, t);
    double best = INFINITY;
    for (int i = 0; i <= 3000; ++i) {
      const Eigen::Vector3d q = x.segment<3>(0) + (x.segment<3>(3) - x.segment<3>(0)) * (i / 3000.0);
      best = std::min(best, body.part_clearance_at(0, P, q));
    }
    return best;
  };
  ASSERT_LT(edge_at(1.0), 0.0) << "the full swing cuts the edge";
  double closest = INFINITY;
  for (int s = 0; s <= 100; ++s) closest = std::min(closest, edge_at(tau * s / 100.0));
  EXPECT_GT(closest, 0.0) << "the bounded advance keeps the edge clear";
  EXPECT_LT(edge_at(std::min(1.0, 1.2 * tau)), 0.2 * edge_at(0.0)) << "and is not vacuous";
  std::printf("leg swinging into a 30 cm edge: advance %.3f, edge clearance %.2f mm -> %.3f mm\n", tau,
              edge_at(0.0) * 1e3, edge_at(tau) * 1e3);
}

// A coarse strip (3 x 2 vertices, its cross edges 20 cm long) dropped 1 cm above a horizontal bar (a leg turned to
// lie along x, radius 6 cm): every vertex is 10 cm to either side of the bar's axis, beside it, so with vertices
// alone the strip falls straight through the bar; with the edges it comes to rest on it, every edge clear of it
// at every step.
double drop_strip_on_bar(bool edges_too, double* worst_edge, double* lowest) {
  TriangleMesh mesh;
  mesh.positions.resize(6, 3);
  mesh.uv.resize(6, 2);
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 2; ++j) {
      const int v = 2 * i + j;
      mesh.positions.row(v) << -0.1 + 0.1 * i, -0.1 + 0.2 * j, 0.57;
      mesh.uv.row(v) << -0.1 + 0.1 * i, -0.1 + 0.2 * j;
    }
  mesh.faces.resize(4, 3);
  mesh.faces << 0, 2, 1, 1, 2, 3, 2, 4, 3, 3, 4, 5;
  ModelOptions o;
  o.held_vertices = {0};      // the model needs a handle: a negligible one
  o.handle_stiffness = 1e-6;  // N/m (the vertex weighs 0.02 N)
  Model model(mesh, o);
  const Eigen::VectorXd p = model.default_parameters();
  const Eigen::VectorXd kappa = model.masses(p) * o.gravity * kReach;
  std::vector<std::array<int, 2>> edges;
  if (edges_too) edges = {{0, 1}, {0, 2}, {1, 2}, {1, 3}, {2, 3}, {2, 4}, {3, 4}, {3, 5}, {4, 5}};
  RigidPose bar;  // the leg's axis (down its rest -z) along +x, its middle (s = 0.28) at (0, 0, 0.5)
  bar.R = Eigen::AngleAxisd(-M_PI / 2, Eigen::Vector3d::UnitY()).toRotationMatrix();
  bar.c = Eigen::Vector3d(0, 0, 0.5) - bar.R * Eigen::Vector3d(0, 0, 1.0 - 0.28);  // (leg(0) hangs from (0, 0, 1))
  auto* body = model.add_term(std::make_unique<RevolvedBodyContact>(std::vector<RevolvedPart>{leg(0.0)}, kappa,
                                                                    kReach, edges));
  body->set_poses({bar}, {bar});
  ImplicitEuler sim(model);
  RolloutOptions ro;
  ro.time_step = 1.0 / 48;
  ro.steps = 1;
  ro.record = false;
  ro.contact_step = RolloutOptions::ContactStep::kNewton;
  ro.contact_force_tolerance = 1e-2;
  Eigen::VectorXd x = Eigen::Map<const Eigen::VectorXd>(mesh.positions.data(), 18);
  Eigen::VectorXd v = Eigen::VectorXd::Zero(18);
  // (positions are row-major: x is the flat 3V vector)
  RevolvedBodyContact probe{{leg(0.0)}, kappa, kReach, {{0, 1}, {0, 2}, {1, 2}, {1, 3}, {2, 3}, {2, 4}, {3, 4}, {3, 5}, {4, 5}}};
  probe.set_poses({bar}, {bar});
  *worst_edge = INFINITY;
  for (int step = 0; step < 24; ++step) {
    const Eigen::VectorXd next = sim.forward(p, ro, nullptr, &x, &v);
    v = (next - x) / ro.time_step;
    x = next;
    for (const auto& e : probe.edges()) {
      for (int q = 0; q <= 400; ++q) {
        const RigidPose& P = bar;
        const Eigen::Vector3d pt = x.segment<3>(3 * e[0]) + (x.segment<3>(3 * e[1]) - x.segment<3>(3 * e[0])) * (q / 400.0);
        *worst_edge = std::min(*worst_edge, probe.part_clearance_at(0, P, pt));
      }
    }
  }
  *lowest = INFINITY;
  for (int i = 0; i < 6; ++i) *lowest = std::min(*lowest, x[3 * i + 2]);
  return x.segment<3>(6).z();
}

TEST(RevolvedBodyEdges, CoarseStripDroppedOnABarHangsOnItsEdges) {
  double worst_vertices_only, lowest_vertices_only, worst, lowest;
  drop_strip_on_bar(false, &worst_vertices_only, &lowest_vertices_only);
  drop_strip_on_bar(true, &worst, &lowest);
  EXPECT_LT(worst_vertices_only, -0.05) << "vertices alone: the edges pass through the bar";
  EXPECT_LT(lowest_vertices_only, 0.44) << "vertices alone: the strip falls past the bar";
  EXPECT_GT(worst, 0.0) << "with the edges: no edge point inside the bar at any step";
  EXPECT_GT(lowest, 0.5) << "with the edges: the strip rests on the bar";
  std::printf("strip dropped on a bar, 0.5 s: vertices only: lowest vertex z %.3f m, deepest edge point %.1f mm inside; "
              "with edges: lowest vertex z %.3f m, least edge clearance %.3f mm\n",
              lowest_vertices_only, -worst_vertices_only * 1e3, lowest, worst * 1e3);
}

}  // namespace
}  // namespace drapelab

namespace drapelab {
namespace {

// The step matrix's curvature cap (garment/revolved_body.hpp): a vertex pinched to 1e-13 m gets the Gauss-Newton
// block of the floor's curvature, one above the floor its own; an edge pinched at its middle gets a step matrix of
// the size it has at the floor (uncapped it would be ~1e16 times larger and CHOLMOD fails on round-off).
TEST(RevolvedBodyEdges, StepMatrixCurvatureIsCappedForPinchedContacts) {
  const double floor = kGaussNewtonDistanceFloor * kReach;
  const Eigen::VectorXd p;
  for (const double gap : {1e-13, 3.0 * floor}) {
    RevolvedBodyContact body({leg(0.0)}, Eigen::VectorXd::Constant(1, 1e-4), kReach);
    const SparsePattern pattern(1, body.stencils());
    body.bind_pattern(pattern);
    Eigen::VectorXd x(3);
    x << 0.06 + gap, 0.0, 0.7;
    Eigen::VectorXd values = Eigen::VectorXd::Zero(pattern.nnz());
    body.add_step_matrix(x, p, 1.0, values);
    Eigen::Vector3d grad;
    const double c = body.part_clearance(0, x, &grad);
    ASSERT_NEAR(c, gap, 1e-15);
    double b, db, d2b;
    barrier_derivatives(std::max(c, floor), kReach, b, db, d2b);
    const Eigen::Matrix3d expected = 1e-4 * d2b * grad * grad.transpose();
    EXPECT_LT((dense(pattern, values) - expected).norm(), 1e-12 * expected.norm()) << gap;
  }
  // a 2 cm chord across the leg, its middle `gap` off the surface (its ends sqrt(0.06^2 + 0.01^2) - 0.06 = 0.83 mm
  // off: in the vertices' reach, not pinched)
  double largest[2];
  int k = 0;
  for (const double gap : {1e-13, floor}) {
    RevolvedBodyContact body({leg(0.0)}, Eigen::VectorXd::Constant(2, 1e-4), kReach, {{0, 1}});
    const SparsePattern pattern(2, body.stencils());
    body.bind_pattern(pattern);
    Eigen::VectorXd x(6);
    x << 0.06 + gap, -0.01, 0.7, 0.06 + gap, 0.01, 0.7;
    ASSERT_NEAR(body.edge_clearance(x)[0], gap, 1e-15);
    Eigen::VectorXd values = Eigen::VectorXd::Zero(pattern.nnz());
    body.add_step_matrix(x, p, 1.0, values);
    const Eigen::MatrixXd K = dense(pattern, values);
    EXPECT_GT(Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd>(K).eigenvalues().minCoeff(), -1e-12 * K.norm());
    largest[k++] = K.cwiseAbs().maxCoeff();
  }
  EXPECT_LT(largest[0], 2.0 * largest[1]) << "pinched " << largest[0] << " against " << largest[1] << " at the floor";
  EXPECT_GT(largest[0], 0.5 * largest[1]);
}

}  // namespace
}  // namespace drapelab
