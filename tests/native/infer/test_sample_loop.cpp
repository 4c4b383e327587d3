// The fit's sample loop (native/src/infer/sample_loop.hpp): the data term against central differences per pixel;
// the loop's parameter gradient (drape, render, data term, observation, adjoint) against central differences of
// its own data term, in both forward modes and with a measurement transform (offset) active; results independent
// of the lane count; static warm starts kept per slot; cancellation and a lane's failure reported as themselves.
#include <gtest/gtest.h>

#include <atomic>
#include <cmath>
#include <random>

#include "infer/sample_loop.hpp"
#include "physics/effect.hpp"
#include "render/rasterizer.hpp"
#include "../test_support.hpp"
#include "util/error.hpp"

namespace drapelab::infer {
namespace {

constexpr double kPxPerM = 200.0;  // 80 x 80 pixels over 0.4 m
constexpr int kSize = 80;

OrthographicCamera camera() { return OrthographicCamera(kPxPerM, 40.0, 40.0, kSize, kSize); }

std::shared_ptr<const Model> small_model() {
  ModelOptions o;
  o.effects = {{"offset", {{"dx_m", 0.0}, {"dy_m", 0.0}}}};
  return std::make_shared<const Model>(make_cusick_specimen(60), o);
}

Eigen::VectorXd parameters(const Model& m, double bend_scale, double dx) {
  Eigen::VectorXd p = m.default_parameters();
  m.fill_bend(p, cotton_blue_bend_table() * bend_scale);
  p[m.layout().block(effect_block_name("offset", "dx_m")).offset] = dx;
  return p;
}

DrapeSettings drape_settings(bool static_mode) {
  DrapeSettings d;
  d.static_mode = static_mode;
  d.rollout.steps = 20;
  d.rollout.time_step = 0.05;
  d.statics.force_tolerance = 1e-11;
  d.statics.max_iterations = 300;
  return d;
}

// The target: the hard silhouette of a stiffer drape, shifted 1 cm.
SilhouetteTarget target(const Model& m) {
  ImplicitEuler rollout(m);
  RolloutOptions o = drape_settings(false).rollout;
  o.record = false;
  const Eigen::VectorXd p = parameters(m, 3.0, 0.01);
  const Eigen::VectorXd x = m.observe(rollout.forward(p, o), p);
  SilhouetteTarget t;
  t.mask = hard_silhouette(camera(), Eigen::Map<const MatrixX3d>(x.data(), x.size() / 3, 3), m.mesh().faces);
  t.drape_coefficient = 0.7;
  return t;
}

DataTermSettings data_settings() {
  DataTermSettings s;
  s.sigma_obs = 0.1;
  s.sigma_dc = 0.05;
  s.dc_bias = 0.01;
  s.px_per_m = kPxPerM;
  return s;
}

TEST(SampleLoopDataTerm, MatchesTheFormulaAndCentralDifferencesPerPixel) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  SilhouetteTarget t;
  t.mask = Image::Zero(12, 10);
  Image image(12, 10);
  for (Eigen::Index i = 0; i < image.size(); ++i) {
    image.data()[i] = u(rng);
    t.mask.data()[i] = u(rng) < 0.5 ? 0.0 : 1.0;
  }
  t.drape_coefficient = 0.4;
  DataTermSettings s = data_settings();
  s.px_per_m = 30.0;  // 12 x 10 pixels cover about a specimen's area
  Image g;
  const double value = silhouette_data_term(image, t, s, &g);
  const double pi = 3.14159265358979323846, disk = pi * 0.09 * 0.09, span = pi * 0.15 * 0.15 - disk;
  const double dc = (image.sum() / (30.0 * 30.0) - disk) / span;
  const double expected = (image - t.mask).square().mean() / (2 * 0.01) +
                          std::pow(dc - 0.01 - 0.4, 2) / (2 * 0.05 * 0.05);
  EXPECT_NEAR(value, expected, 1e-12 * std::abs(expected));
  for (Eigen::Index i = 0; i < image.size(); i += 7) {
    Image plus = image, minus = image;
    plus.data()[i] += 1e-6;
    minus.data()[i] -= 1e-6;
    const double fd = (silhouette_data_term(plus, t, s) - silhouette_data_term(minus, t, s)) / 2e-6;
    EXPECT_NEAR(g.data()[i], fd, 1e-6 * std::max(1.0, std::abs(fd))) << "pixel " << i;
  }
  s.sigma_dc = 0;  // pixel term only
  EXPECT_NEAR(silhouette_data_term(image, t, s), (image - t.mask).square().mean() / (2 * 0.01), 1e-12);
}

TEST(SampleLoopDataTerm, BadInputIsAClearError) {
  SilhouetteTarget t;
  t.mask = Image::Zero(4, 4);
  DataTermSettings s = data_settings();
  EXPECT_THROW(silhouette_data_term(Image::Zero(4, 5), t, s), InputError);
  s.sigma_obs = 0;
  EXPECT_THROW(silhouette_data_term(Image::Zero(4, 4), t, s), InputError);
}

// Central differences of the loop's data term along a random direction of the bend block and the offset, against
// the gradient the loop returns.
void expect_loop_gradient(bool static_mode) {
  const auto model = small_model();
  const std::vector<SilhouetteTarget> targets{target(*model)};
  SampleLoop loop({model}, camera(), SoftRasterOptions{}, drape_settings(static_mode));
  SampleDraw draw;
  draw.parameters = parameters(*model, 1.0, 0.004);
  if (!static_mode) {  // a placement velocity field
    draw.velocities0 = Eigen::VectorXd::Zero(model->num_dofs());
    const Eigen::VectorXd rest = model->rest_positions();
    for (int i = 0; i < model->num_vertices(); ++i)
      draw.velocities0[3 * i + 2] = 0.05 * std::max(0.0, rest.segment<2>(3 * i).norm() - 0.09) / 0.06 *
                                    std::cos(2 * std::atan2(rest[3 * i + 1], rest[3 * i]));
  }
  const auto warm0 = loop.run({draw}, targets, data_settings());  // settles the warm start (static)
  const auto warm = loop.warm_starts();
  EXPECT_EQ(static_cast<int>(warm.size()), static_mode ? 1 : 0);
  const auto base = loop.run({draw}, targets, data_settings());
  ASSERT_EQ(base.size(), 1u);
  EXPECT_GT(base[0].data, 0.0);
  EXPECT_EQ(base[0].image.rows(), kSize);

  std::mt19937 rng(11);
  std::normal_distribution<double> n01;
  Eigen::VectorXd dir = Eigen::VectorXd::Zero(draw.parameters.size());
  const auto& bend = model->layout().block("bend");
  for (int k = 0; k < bend.size; ++k) dir[bend.offset + k] = n01(rng) * draw.parameters[bend.offset + k];
  dir[model->layout().block(effect_block_name("offset", "dx_m")).offset] = 0.01;
  const double analytic = base[0].gradient.dot(dir);
  auto at = [&](double h) {
    SampleDraw d = draw;
    d.parameters += h * dir;
    loop.set_warm_starts(warm);
    return loop.run({d}, targets, data_settings())[0].data;
  };
  const double h = 1e-6;
  const double fd = (at(h) - at(-h)) / (2 * h);
  EXPECT_NEAR(analytic, fd, 1e-4 * std::abs(fd)) << (static_mode ? "static" : "dynamic");
  EXPECT_GT(std::abs(fd), 1e-3);
}

TEST(SampleLoop, GradientMatchesCentralDifferencesOnARolloutWithPlacementVelocities) { expect_loop_gradient(false); }

TEST(SampleLoop, GradientMatchesCentralDifferencesOnAWarmStartedStaticSolve) { expect_loop_gradient(true); }

TEST(SampleLoop, ResultsDoNotDependOnTheLaneCount) {
  for (const bool static_mode : {false, true}) {
    const auto model = small_model();
    const std::vector<SilhouetteTarget> targets{target(*model), target(*model)};
    std::vector<SampleDraw> draws;
    for (int i = 0; i < 5; ++i) {
      SampleDraw d;
      d.parameters = parameters(*model, 0.6 + 0.2 * i, 0.002 * i);
      d.target = i % 2;
      d.slot = i;
      draws.push_back(d);
    }
    SampleLoop one({model}, camera(), SoftRasterOptions{}, drape_settings(static_mode));
    SampleLoop two({model, small_model()}, camera(), SoftRasterOptions{}, drape_settings(static_mode));
    for (int epoch = 0; epoch < 2; ++epoch) {  // the second epoch starts from each slot's warm start
      const auto a = one.run(draws, targets, data_settings());
      const auto b = two.run(draws, targets, data_settings());
      for (size_t i = 0; i < draws.size(); ++i) {
        EXPECT_EQ(a[i].data, b[i].data) << i;
        EXPECT_TRUE(a[i].gradient == b[i].gradient) << i;
        EXPECT_TRUE((a[i].image == b[i].image).all()) << i;
      }
    }
    EXPECT_EQ(static_cast<int>(two.warm_starts().size()), static_mode ? 5 : 0);
    two.forget_warm_starts();
    EXPECT_TRUE(two.warm_starts().empty());
  }
}

TEST(SampleLoop, CancelStopsEveryLaneAndAFailureIsReportedAsItself) {
  const auto model = small_model();
  const std::vector<SilhouetteTarget> targets{target(*model)};
  SampleLoop loop({model, small_model()}, camera(), SoftRasterOptions{}, drape_settings(false));
  std::vector<SampleDraw> draws(4);
  for (auto& d : draws) d.parameters = parameters(*model, 1.0, 0.0);

  std::atomic<int> calls{0};
  ProgressSink cancelling([&](int, int) {
    if (++calls == 5) cancelling.cancel();
  });
  EXPECT_THROW(loop.run(draws, targets, data_settings(), &cancelling), Cancelled);
  EXPECT_LT(calls.load(), 4 * 20 * 3);  // stopped long before every draw's rollout and adjoint

  int reports = 0, last = 0;
  ProgressSink counting([&](int done, int total) {
    ++reports;
    last = done;
    EXPECT_EQ(total, 4);
  });
  loop.run(draws, targets, data_settings(), &counting);
  EXPECT_EQ(last, 4);
  EXPECT_GT(reports, 4);

  draws[3].parameters[0] = std::nan("");  // lane 1's second draw: its own error, not the Cancelled of lane 0
  EXPECT_THROW(loop.run(draws, targets, data_settings()), InputError);
  draws[3].target = 1;
  EXPECT_THROW(loop.run(draws, targets, data_settings()), InputError);
  EXPECT_THROW(SampleLoop({}, camera(), SoftRasterOptions{}, drape_settings(false)), InputError);
}

TEST(SampleLoop, ScoreIsTheHardSilhouettesDataTermAndInfWhereTheRolloutFails) {
  const auto model = small_model();
  const std::vector<SilhouetteTarget> targets{target(*model), target(*model)};
  std::vector<SampleDraw> draws(3);
  for (int i = 0; i < 3; ++i) draws[i].parameters = parameters(*model, 0.5 + i, 0.003 * i);
  DataTermSettings data = data_settings();
  data.dc_bias = 0;
  SampleLoop two({model, small_model()}, camera(), SoftRasterOptions{}, drape_settings(true));
  const auto scores = two.score(draws, targets, data);
  ASSERT_EQ(scores.size(), 3u);
  for (int i = 0; i < 3; ++i) {
    ImplicitEuler rollout(*model);
    RolloutOptions o = drape_settings(false).rollout;
    o.record = false;
    const Eigen::VectorXd x = model->observe(rollout.forward(draws[i].parameters, o), draws[i].parameters);
    const Image hard = hard_silhouette(camera(), Eigen::Map<const MatrixX3d>(x.data(), x.size() / 3, 3), model->mesh().faces);
    ASSERT_EQ(scores[i].size(), 2u);
    EXPECT_EQ(scores[i][0], silhouette_data_term(hard, targets[0], data)) << i;
    EXPECT_EQ(scores[i][1], scores[i][0]) << i;
  }
  SampleLoop one({model}, camera(), SoftRasterOptions{}, drape_settings(false));
  EXPECT_EQ(one.score(draws, targets, data), scores);
  EXPECT_TRUE(two.warm_starts().empty());  // scores keep no warm start

  DrapeSettings diverging = drape_settings(false);
  diverging.rollout.max_speed = 1e-6;  // every rollout "diverges" at its first step
  SampleLoop failing({model}, camera(), SoftRasterOptions{}, diverging);
  const auto inf = failing.score(draws, targets, data);
  EXPECT_TRUE(std::isinf(inf[1][0]) && std::isinf(inf[1][1]));
  EXPECT_THROW(failing.run(draws, targets, data), SolverError);
}

TEST(SampleLoop, PredictGivesTheDrapesAndTheirHardSilhouettesOrTheFailure) {
  const auto model = small_model();
  std::vector<SampleDraw> draws(3);
  for (int i = 0; i < 3; ++i) draws[i].parameters = parameters(*model, 0.5 + i, 0.003 * i);
  draws[1].velocities0 = Eigen::VectorXd::Constant(model->num_dofs(), 0.01);
  for (const bool static_mode : {false, true}) {
    SampleLoop two({model, small_model()}, camera(), SoftRasterOptions{}, drape_settings(static_mode));
    const auto out = two.predict(draws);
    ASSERT_EQ(out.size(), 3u);
    for (int i = 0; i < 3; ++i) {
      Eigen::VectorXd x;
      if (static_mode) {
        StaticSolver statics(*model);
        x = statics.solve(draws[i].parameters, drape_settings(true).statics).positions;
      } else {
        ImplicitEuler rollout(*model);
        RolloutOptions o = drape_settings(false).rollout;
        o.record = false;
        x = rollout.forward(draws[i].parameters, o, nullptr, nullptr,
                            draws[i].velocities0.size() ? &draws[i].velocities0 : nullptr);
      }
      EXPECT_TRUE(out[i].error.empty()) << out[i].error;
      EXPECT_TRUE(out[i].positions == x) << i << (static_mode ? " static" : " dynamic");
      const Eigen::VectorXd seen = model->observe(x, draws[i].parameters);
      const Image hard = hard_silhouette(camera(), Eigen::Map<const MatrixX3d>(seen.data(), seen.size() / 3, 3),
                                         model->mesh().faces);
      EXPECT_TRUE((out[i].image == hard).all()) << i;
    }
    SampleLoop one({model}, camera(), SoftRasterOptions{}, drape_settings(static_mode));
    const auto serial = one.predict(draws);
    for (int i = 0; i < 3; ++i) EXPECT_TRUE(serial[i].positions == out[i].positions) << i;
    EXPECT_TRUE(two.warm_starts().empty());
  }
  DrapeSettings diverging = drape_settings(false);
  diverging.rollout.max_speed = 1e-6;
  SampleLoop failing({model}, camera(), SoftRasterOptions{}, diverging);
  const auto failed = failing.predict(draws);
  EXPECT_NE(failed[2].error.find("rollout"), std::string::npos) << failed[2].error;
  EXPECT_EQ(failed[2].positions.size(), 0);
}

}  // namespace
}  // namespace drapelab::infer
