// rest_curvature's physics: the set surface it describes is the bend term's rest shape. Laid on that surface
// (z = -q phi(u, v) over the pattern), the bending force is second order in q, while the flat sheet feels a force
// of first order; both the crease (the fold profile F with F'' a Gaussian of width sigma, written out here
// independently of the effect) and the dome, each sign.
#include <gtest/gtest.h>

#include <cmath>

#include "../test_support.hpp"
#include "physics/effect.hpp"

using namespace drapelab;
using namespace drapelab::testing;

namespace {

// The crease's fold profile: F(0) = F'(0) = 0, F'' the Gaussian density of width sigma (the slope turns by 1).
double fold(double t, double sigma) {
  const double g0 = 1.0 / (sigma * std::sqrt(2.0 * M_PI));
  return t * 0.5 * std::erf(t / (sigma * std::sqrt(2.0))) + sigma * sigma * (g0 * std::exp(-0.5 * t * t / (sigma * sigma)) - g0);
}

Eigen::VectorXd bend_force(const Model& model, const Eigen::VectorXd& x, const Eigen::VectorXd& p) {
  Eigen::VectorXd g = Eigen::VectorXd::Zero(x.size());
  for (const auto& t : model.terms())
    if (t->name() == "bend") t->add_gradient(x, p, g);
  return g;
}

}  // namespace

TEST(RestCurvature, TheSetSurfaceIsTheBendingRestShape) {
  const TriangleMesh mesh = make_cusick_specimen(60);
  // the crease width as the effect takes it: at least 4 mm, at least the mean bending edge's rest length
  const std::vector<BendingEdge> edges = bending_edges(mesh);
  double mean_length = 0;
  for (const auto& be : edges) mean_length += (mesh.uv.row(be.a) - mesh.uv.row(be.b)).norm();
  const double sigma = std::max(0.004, mean_length / edges.size());
  struct Case {
    const char* parameter;
    double value;
  };
  for (const Case c : {Case{"crease_rad", 2e-3}, Case{"crease_rad", -2e-3}, Case{"dome_per_m", 0.02},
                       Case{"dome_per_m", -0.02}}) {
    SCOPED_TRACE(std::string(c.parameter) + " " + std::to_string(c.value));
    ModelOptions o;
    o.effects["rest_curvature"][c.parameter] = c.value;
    const Model model(mesh, o);
    const Eigen::VectorXd p = model.default_parameters();
    Eigen::VectorXd flat = model.rest_positions(), set = flat;
    for (int i = 0; i < model.num_vertices(); ++i) {
      const double u = mesh.uv(i, 0), v = mesh.uv(i, 1);
      const double phi = std::string(c.parameter) == "crease_rad" ? fold(u, sigma) + fold(v, sigma) : 0.5 * (u * u + v * v);
      set[3 * i + 2] -= c.value * phi;
    }
    const double on_set = bend_force(model, set, p).norm(), on_flat = bend_force(model, flat, p).norm();
    EXPECT_GT(on_flat, 0.0);
    EXPECT_LT(on_set, 1e-3 * on_flat) << "bending force on the set surface " << on_set << ", flat " << on_flat;
  }
}

TEST(RestCurvature, TheCreaseFoldTurnsTheSlopeByItsAngle) {
  // F'(t) -> +-1/2 far from the crease: across it the set surface's slope turns by exactly the crease angle.
  const double sigma = 0.004, t = 10 * sigma, h = 1e-6;
  EXPECT_NEAR((fold(t + h, sigma) - fold(t - h, sigma)) / (2 * h), 0.5, 1e-8);
  EXPECT_NEAR((fold(-t + h, sigma) - fold(-t - h, sigma)) / (2 * h), -0.5, 1e-8);
}
