// Physics sanity: no gravity keeps the flat specimen in place; the Cotton Blue drape settles to a
// plausible drape coefficient; the result does not depend on vertex order; bad input fails clearly.
#include <gtest/gtest.h>

#include <numeric>
#include <random>

#include "../test_support.hpp"
#include "geometry/obj.hpp"
#include "measure/metrics.hpp"
#include "render/camera.hpp"
#include "render/rasterizer.hpp"
#include "solver/implicit_euler.hpp"
#include "solver/static_solve.hpp"
#include "util/error.hpp"

using namespace drapelab;
using namespace drapelab::testing;

namespace {
MatrixX3d as_rows(const Eigen::VectorXd& x) {
  return Eigen::Map<const MatrixX3d>(x.data(), x.size() / 3, 3);
}
double max_speed(const Eigen::VectorXd& v) {
  double s = 0;
  for (int i = 0; i < v.size() / 3; ++i) s = std::max(s, v.segment<3>(3 * i).norm());
  return s;
}
double drape_coefficient_of(const Model& model, const Eigen::VectorXd& x) {
  OrthographicCamera cam;
  const Image mask = hard_silhouette(cam, as_rows(x), model.mesh().faces);
  return drape_coefficient(mask, 720.0);
}
}  // namespace

TEST(PhysicsSanity, WithoutGravityTheFlatSpecimenStaysPut) {
  ModelOptions o;
  o.gravity = 0.0;
  Model model(load_cusick_template(1, template_dir()), o);
  ImplicitEuler sim(model);
  const Eigen::VectorXd x = sim.forward(model.default_parameters(), RolloutOptions{});
  EXPECT_LT((x - model.rest_positions()).cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_LT(max_speed(sim.velocities()), 1e-12);
  StaticSolver st(model);
  EXPECT_EQ(st.solve(model.default_parameters()).iterations, 0);
}

TEST(PhysicsSanity, CottonBlueDrapeSettlesDynamicAndStatic) {
  Model model(load_cusick_template(3, template_dir()));
  const Eigen::VectorXd p = model.default_parameters();
  ImplicitEuler sim(model);
  RolloutOptions ro;
  ro.record = false;
  const Eigen::VectorXd xd = sim.forward(p, ro);
  EXPECT_LT(max_speed(sim.velocities()), 0.05) << "dynamic drape still moving after 5 s";
  const double dc_dynamic = drape_coefficient_of(model, xd);
  EXPECT_GT(dc_dynamic, 0.3);
  EXPECT_LT(dc_dynamic, 0.9);
  StaticSolver st(model);
  StaticOptions so;
  so.max_iterations = 400;
  const StaticResult r = st.solve(p, so);
  RolloutOptions one;
  one.steps = 1;
  Eigen::VectorXd v0 = Eigen::VectorXd::Zero(model.num_dofs());
  sim.forward(p, one, nullptr, &r.positions, &v0);
  EXPECT_LT(max_speed(sim.velocities()), 1e-3);
  const double dc_static = drape_coefficient_of(model, r.positions);
  EXPECT_GT(dc_static, 0.3);
  EXPECT_LT(dc_static, 0.9);
  RecordProperty("drape_coefficient_dynamic", std::to_string(dc_dynamic));
  RecordProperty("drape_coefficient_static", std::to_string(dc_static));
}

TEST(PhysicsSanity, ResultDoesNotDependOnVertexOrder) {
  const TriangleMesh mesh = load_cusick_template(1, template_dir());
  std::vector<Index> perm(mesh.num_vertices());
  std::iota(perm.begin(), perm.end(), 0);
  std::shuffle(perm.begin(), perm.end(), std::mt19937(4));
  const TriangleMesh shuffled = permute_vertices(mesh, perm);
  Model a(mesh), b(shuffled);
  ImplicitEuler sa(a), sb(b);
  RolloutOptions ro;
  ro.steps = 40;
  ro.record = false;
  const Eigen::VectorXd xa = sa.forward(a.default_parameters(), ro);
  const Eigen::VectorXd xb = sb.forward(b.default_parameters(), ro);
  double err = 0;
  for (int i = 0; i < mesh.num_vertices(); ++i) err = std::max(err, (xb.segment<3>(3 * i) - xa.segment<3>(3 * perm[i])).norm());
  EXPECT_LT(err, 1e-8);
}

TEST(PhysicsBadInput, DegenerateAndNonManifoldMeshes) {
  TriangleMesh m = make_cusick_specimen(40);
  TriangleMesh degenerate = m;
  degenerate.positions.row(degenerate.faces(5, 1)) = degenerate.positions.row(degenerate.faces(5, 0));
  degenerate.uv.row(degenerate.faces(5, 1)) = degenerate.uv.row(degenerate.faces(5, 0));
  EXPECT_THROW({ try { Model x(degenerate); } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("degenerate"), std::string::npos) << e.what(); throw; } }, InputError);
  TriangleMesh nonmanifold = m;
  const int nf = nonmanifold.num_faces();
  nonmanifold.faces.conservativeResize(nf + 1, 3);
  nonmanifold.positions.conservativeResize(nonmanifold.num_vertices() + 1, 3);
  nonmanifold.uv.conservativeResize(nonmanifold.uv.rows() + 1, 2);
  nonmanifold.positions.bottomRows<1>() << 0.01, 0.02, 0.05;
  nonmanifold.uv.bottomRows<1>() << 0.01, 0.02;
  nonmanifold.faces.row(nf) << nonmanifold.faces(0, 0), nonmanifold.faces(0, 1), nonmanifold.num_vertices() - 1;
  // A third face on an edge already shared by two faces.
  int shared_face = -1;
  for (int f = 1; f < nf && shared_face < 0; ++f)
    for (int k = 0; k < 3; ++k) {
      const int i = m.faces(f, k), j = m.faces(f, (k + 1) % 3);
      if ((i == m.faces(0, 0) && j == m.faces(0, 1)) || (j == m.faces(0, 0) && i == m.faces(0, 1))) shared_face = f;
    }
  ASSERT_GE(shared_face, 0);
  EXPECT_THROW({ try { Model x(nonmanifold); } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("non-manifold"), std::string::npos) << e.what(); throw; } }, InputError);
}

TEST(PhysicsBadInput, ParametersNaNNegativeWrongSize) {
  Model model(make_cusick_specimen(60));
  Eigen::VectorXd p = model.default_parameters();
  Eigen::VectorXd bad = p;
  bad[3] = std::nan("");
  ImplicitEuler sim(model);
  auto expect_message = [&](const Eigen::VectorXd& q, const std::string& needle) {
    try {
      sim.forward(q, RolloutOptions{});
      ADD_FAILURE() << "expected InputError containing '" << needle << "'";
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
    }
  };
  expect_message(bad, "not finite");
  bad = p;
  bad[model.layout().block("bend").offset + 2] = -1e-5;
  expect_message(bad, "negative");
  bad = p;
  bad[model.layout().block("density").offset] = 0;
  expect_message(bad, "density");
  expect_message(p.head(p.size() - 1), "expected");
}

TEST(PhysicsBadInput, DivergingStepIsReported) {
  Model model(load_cusick_template(1, template_dir()));
  ImplicitEuler sim(model);
  RolloutOptions ro;
  ro.time_step = 5.0;  // absurd step: the linearised step overshoots
  ro.max_speed = 1.0;
  try {
    sim.forward(model.default_parameters(), ro);
    FAIL() << "expected SolverError";
  } catch (const SolverError& e) {
    EXPECT_NE(std::string(e.what()).find("diverged"), std::string::npos) << e.what();
  }
}
