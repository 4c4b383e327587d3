// The trainer's numerical core (native/src/infer): finite-difference checks of the KL, of each family's
// reparameterisation chain and of the ELBO gradient (each family, with and without fitted effects, clipping off),
// the clipping itself, Adam against a step computed by hand, and the clip-norm rule.
#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <ostream>
#include <random>

#include "infer/adam.hpp"
#include "infer/effect_block.hpp"
#include "infer/elbo.hpp"
#include "infer/variational_family.hpp"
#include "util/error.hpp"

namespace drapelab::infer {
namespace {

constexpr int kEdges = 4;  // bending edges of the synthetic fits (heter/bdp tables: 4 x 15)

Vector random_vector(std::mt19937& rng, Eigen::Index n, double lo, double hi) {
  std::uniform_real_distribution<double> u(lo, hi);
  Vector v(n);
  for (Eigen::Index i = 0; i < n; ++i) v[i] = u(rng);
  return v;
}

Tables random_noise(std::mt19937& rng, int rows) {
  std::normal_distribution<double> n01;
  Tables t(rows, kBendEntries);
  for (Eigen::Index i = 0; i < t.size(); ++i) t.data()[i] = n01(rng);
  return t;
}

// Central differences of f along every entry of every block of theta, against the analytic gradient.
void expect_gradient_matches(const std::function<double(const Parameters&)>& f, const Parameters& theta,
                             const Parameters& analytic, double h, double rtol, const std::string& what) {
  for (const auto& [name, values] : theta) {
    ASSERT_TRUE(analytic.count(name)) << what << ": no gradient for " << name;
    for (Eigen::Index i = 0; i < values.size(); ++i) {
      Parameters plus = theta, minus = theta;
      plus[name][i] += h;
      minus[name][i] -= h;
      const double fd = (f(plus) - f(minus)) / (2 * h);
      const double an = analytic.at(name)[i];
      EXPECT_NEAR(an, fd, rtol * std::max(1.0, std::abs(fd))) << what << ": d/d" << name << "[" << i << "]";
    }
  }
}

TEST(InferKl, GradientsMatchCentralDifferences) {
  std::mt19937 rng(1);
  const Vector mu = random_vector(rng, 6, -1, 1), sigma = random_vector(rng, 6, 0.1, 2);
  const Vector mu0 = random_vector(rng, 6, -1, 1), sigma0 = random_vector(rng, 6, 0.3, 1.5);
  const GaussianKl kl = kl_divergence(mu, sigma, mu0, sigma0);
  // closed form at one entry, against its definition
  double sum = 0;
  for (int i = 0; i < 6; ++i)
    sum += std::log(sigma0[i] / sigma[i]) + (sigma[i] * sigma[i] + std::pow(mu[i] - mu0[i], 2)) /
                                                (2 * sigma0[i] * sigma0[i]) - 0.5;
  EXPECT_NEAR(kl.value, sum, 1e-14);
  EXPECT_NEAR(kl_divergence(mu0, sigma0, mu0, sigma0).value, 0.0, 1e-14);  // KL(p || p) = 0
  EXPECT_GT(kl.value, 0.0);
  const double h = 1e-6;
  for (int i = 0; i < 6; ++i) {
    Vector a = mu, b = mu;
    a[i] += h;
    b[i] -= h;
    EXPECT_NEAR(kl.d_mu[i], (kl_divergence(a, sigma, mu0, sigma0).value - kl_divergence(b, sigma, mu0, sigma0).value) / (2 * h), 1e-7);
    a = sigma, b = sigma;
    a[i] += h;
    b[i] -= h;
    EXPECT_NEAR(kl.d_sigma[i], (kl_divergence(mu, a, mu0, sigma0).value - kl_divergence(mu, b, mu0, sigma0).value) / (2 * h), 1e-7);
  }
  EXPECT_THROW(kl_divergence(mu, -sigma, mu0, sigma0), InputError);
  EXPECT_THROW(kl_divergence(mu, sigma.head(3), mu0, sigma0), InputError);
}

TEST(InferFamily, UnknownNameIsRefusedNamingTheChoices) {
  try {
    make_family("gaussian");
    FAIL() << "no error";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("homo"), std::string::npos);
  }
}

Parameters perturbed_initial(const VariationalFamily& f, std::mt19937& rng) {
  const Vector log_bend0 = random_vector(rng, kBendEntries, std::log(1e-5), std::log(1e-4));
  Parameters theta = f.initial(log_bend0, kEdges, 0.3);
  for (auto& [name, v] : theta) v += random_vector(rng, v.size(), -0.2, 0.2);
  return theta;
}

class InferFamilies : public ::testing::TestWithParam<std::string> {};

TEST_P(InferFamilies, TablesFollowTheParameterisation) {
  auto f = make_family(GetParam());
  std::mt19937 rng(2);
  const Parameters theta = perturbed_initial(*f, rng);
  const Tables noise = random_noise(rng, kEdges);
  const Tables b = f->tables(theta, kEdges, &noise);
  ASSERT_EQ(b.rows(), f->per_element() ? kEdges : 1);
  for (int w = 0; w < b.rows(); ++w)
    for (int j = 0; j < kBendEntries; ++j) {
      double log_b = GetParam() == "heter" ? theta.at("mu")[w * kBendEntries + j] : theta.at("mu")[j];
      if (GetParam() == "bdp") log_b += softplus(theta.at("eta")[j]) * noise(w, j);
      EXPECT_NEAR(std::log(b(w, j)), log_b, 1e-12);
    }
}

TEST_P(InferFamilies, ReparameterisationChainMatchesCentralDifferences) {
  // f(theta) = sum c . B(theta, eps): dL/dB = c, so dL/dlog B = c . B.
  auto fam = make_family(GetParam());
  std::mt19937 rng(3);
  const Parameters theta = perturbed_initial(*fam, rng);
  const Tables noise = random_noise(rng, kEdges);
  const int rows = fam->per_element() ? kEdges : 1;
  Tables c = random_noise(rng, rows) * 1e5;  // B ~ 1e-5 N m
  auto f = [&](const Parameters& th) { return (fam->tables(th, kEdges, &noise).array() * c.array()).sum(); };
  Parameters grads;
  for (const auto& [k, v] : theta) grads[k] = Vector::Zero(v.size());
  const Tables g_log = (c.array() * fam->tables(theta, kEdges, &noise).array()).matrix();
  fam->add_log_table_gradient(theta, g_log, &noise, grads);
  expect_gradient_matches(f, theta, grads, 1e-6, 1e-6, GetParam() + " chain");
}

TEST_P(InferFamilies, PriorGradientMatchesCentralDifferences) {
  auto fam = make_family(GetParam());
  std::mt19937 rng(4);
  const Parameters theta = perturbed_initial(*fam, rng);
  const Vector prior_mu = random_vector(rng, kBendEntries, -11, -9);
  auto f = [&](const Parameters& th) {
    Parameters g;
    for (const auto& [k, v] : th) g[k] = Vector::Zero(v.size());
    return fam->add_prior(th, prior_mu, 0.7, 1.3, g);
  };
  Parameters grads;
  for (const auto& [k, v] : theta) grads[k] = Vector::Zero(v.size());
  const double value = fam->add_prior(theta, prior_mu, 0.7, 1.3, grads);
  EXPECT_GT(value, 0.0);
  expect_gradient_matches(f, theta, grads, 1e-6, 1e-6, GetParam() + " prior");
}

// A smooth synthetic data term standing in for a drape's: per draw s,
//   data_s = sum_wj a_wj (log B_wj - t_j)^2 + sum_i d_i (e_i - f_i)^2 + e_0 sum_wj log B_wj / 100
// with its exact dL/dB and dL/de.
struct SyntheticData {
  Tables a;
  Vector t, d, target;
  double operator()(const Tables& b, const Vector& e, Tables* g_b, Vector* g_e) const {
    const Tables lb = b.array().log().matrix();
    const Tables dev = lb.rowwise() - t.transpose();
    double value = (a.topRows(b.rows()).array() * dev.array().square()).sum();
    const double coupling = e.size() ? e[0] / 100 : 0.0;
    value += coupling * lb.sum();
    if (g_b) *g_b = ((2 * a.topRows(b.rows()).array() * dev.array() + coupling) / b.array()).matrix();
    if (e.size()) {
      value += (d.array() * (e - target).array().square()).sum();
      if (g_e) {
        *g_e = (2 * d.array() * (e - target).array()).matrix();
        (*g_e)[0] += lb.sum() / 100;
      }
    }
    return value;
  }
};

struct ElboCase {
  std::unique_ptr<VariationalFamily> family;
  std::optional<EffectBlock> effects;
  SyntheticData data;
  std::vector<Tables> noise;        // per draw
  std::vector<Vector> effect_noise;  // per draw
  ElboSettings settings;

  std::vector<Draw> draws(const Parameters& theta) const {
    std::vector<Draw> out;
    for (std::size_t s = 0; s < noise.size(); ++s) {
      Draw d;
      const bool stochastic = family->stochastic();
      d.tables = family->tables(theta, kEdges, stochastic ? &noise[s] : nullptr);
      if (stochastic) d.noise = noise[s];
      Vector e;
      if (effects) {
        if (stochastic) d.effect_noise = effect_noise[s];
        e = effects->draw(theta, stochastic ? &effect_noise[s] : nullptr).value;
      }
      d.data = data(d.tables, e, &d.table_gradient, &d.effect_gradient);
      out.push_back(std::move(d));
    }
    return out;
  }
  ElboTerms elbo(const Parameters& theta, std::optional<double> clip = std::nullopt) const {
    return assemble_elbo(*family, effects ? &*effects : nullptr, settings, theta, draws(theta), clip);
  }
};

ElboCase make_case(const std::string& name, bool with_effects, std::mt19937& rng, Parameters& theta) {
  ElboCase c;
  c.family = make_family(name);
  theta = perturbed_initial(*c.family, rng);
  const int draws = c.family->stochastic() ? 3 : 1;
  for (int s = 0; s < draws; ++s) c.noise.push_back(random_noise(rng, kEdges));
  c.data.a = random_vector(rng, kEdges * kBendEntries, 0.1, 1.0).reshaped<Eigen::RowMajor>(kEdges, kBendEntries);
  c.data.t = random_vector(rng, kBendEntries, -11, -9);
  c.settings.prior_mu = random_vector(rng, kBendEntries, -11, -9);
  c.settings.prior_sigma = 0.8;
  c.settings.kl_weight = 1.0;
  c.settings.effect_prior_weight = 0.1;
  if (with_effects) {
    // two parameters: one signed (a tilt angle), one with a lower bound at its off value (a fraction)
    c.effects = EffectBlock((Vector(2) << 0.0, 0.0).finished(), (Vector(2) << -0.5, 0.0).finished(),
                            (Vector(2) << 0.5, 1.0).finished(), (Vector(2) << 0.15, 0.2).finished());
    c.data.d = (Vector(2) << 3.0, 5.0).finished();
    c.data.target = (Vector(2) << 0.2, 0.4).finished();
    theta["effect_mu"] = (Vector(2) << 0.1, 0.3).finished();  // inside the bounds (gradient flows)
    if (c.family->stochastic()) {
      theta["effect_eta"] = (Vector(2) << inverse_softplus(0.02), inverse_softplus(0.03)).finished();
      for (int s = 0; s < draws; ++s) c.effect_noise.push_back(random_vector(rng, 2, -1, 1));
    }
  }
  return c;
}

struct ElboParam {
  std::string family;
  bool effects;
};
void PrintTo(const ElboParam& p, std::ostream* os) { *os << p.family << (p.effects ? " with effects" : ""); }

class InferElbo : public ::testing::TestWithParam<ElboParam> {};

TEST_P(InferElbo, GradientMatchesCentralDifferences) {
  std::mt19937 rng(5);
  Parameters theta;
  const ElboCase c = make_case(GetParam().family, GetParam().effects, rng, theta);
  const ElboTerms t = c.elbo(theta);
  EXPECT_EQ(t.clip, 1.0);
  EXPECT_NEAR(t.loss, t.data + t.kl, 1e-12 * std::abs(t.loss));
  // the data term is the mean over draws
  double mean = 0;
  for (const Draw& d : c.draws(theta)) mean += d.data;
  EXPECT_NEAR(t.data, mean / double(c.noise.size()), 1e-12 * std::abs(mean));
  expect_gradient_matches([&](const Parameters& th) { return c.elbo(th).loss; }, theta, t.gradient, 1e-6, 1e-6,
                          GetParam().family + (GetParam().effects ? " with effects" : ""));
}

TEST_P(InferElbo, ClippingScalesTheDataGradientOnly) {
  std::mt19937 rng(6);
  Parameters theta;
  ElboCase c = make_case(GetParam().family, GetParam().effects, rng, theta);
  const ElboTerms full = c.elbo(theta);
  const ElboTerms half = c.elbo(theta, 0.5 * full.grad_norm);
  EXPECT_NEAR(half.clip, 0.5, 1e-15);
  EXPECT_EQ(half.grad_norm, full.grad_norm);
  EXPECT_EQ(half.loss, full.loss);
  EXPECT_EQ(c.elbo(theta, 2.0 * full.grad_norm).clip, 1.0);  // below the norm: untouched
  // the prior's gradient alone, from a zero data term
  c.settings.kl_weight = 1.0;
  Parameters prior;
  for (const auto& [k, v] : theta) prior[k] = Vector::Zero(v.size());
  c.family->add_prior(theta, c.settings.prior_mu, c.settings.prior_sigma, c.settings.kl_weight, prior);
  if (c.effects) c.effects->add_prior(theta, c.family->stochastic(), c.settings.effect_prior_weight, prior);
  for (const auto& [k, g] : full.gradient) {
    const Vector expected = 0.5 * (g - prior.at(k)) + prior.at(k);
    EXPECT_LT((half.gradient.at(k) - expected).norm(), 1e-9 * (1 + expected.norm())) << k;
  }
}

INSTANTIATE_TEST_SUITE_P(Families, InferFamilies, ::testing::Values("homo", "heter", "bdp"));
INSTANTIATE_TEST_SUITE_P(Families, InferElbo,
                         ::testing::Values(ElboParam{"homo", false}, ElboParam{"heter", false},
                                           ElboParam{"bdp", false}, ElboParam{"homo", true},
                                           ElboParam{"heter", true}, ElboParam{"bdp", true}),
                         [](const auto& info) { return info.param.family + (info.param.effects ? "_effects" : ""); });

TEST(InferEffectBlock, DrawsAreClippedAndTheGradientStopsOutsideTheBounds) {
  const EffectBlock b((Vector(2) << 0.0, 0.0).finished(), (Vector(2) << -0.5, 0.0).finished(),
                      (Vector(2) << 0.5, 1.0).finished(), (Vector(2) << 0.15, 0.2).finished());
  Parameters theta{{"effect_mu", (Vector(2) << 0.45, 0.5).finished()},
                   {"effect_eta", (Vector(2) << inverse_softplus(0.1), inverse_softplus(0.1)).finished()}};
  const Vector eps = (Vector(2) << 1.0, -1.0).finished();
  const EffectBlock::Draw d = b.draw(theta, &eps);
  EXPECT_DOUBLE_EQ(d.value[0], 0.5);  // 0.55 clipped
  EXPECT_NEAR(d.value[1], 0.4, 1e-15);
  EXPECT_FALSE(d.inside[0]);
  EXPECT_TRUE(d.inside[1]);
  Parameters grads{{"effect_mu", Vector::Zero(2)}, {"effect_eta", Vector::Zero(2)}};
  b.add_gradient(theta, (Vector(2) << 2.0, 3.0).finished(), d, &eps, grads);
  EXPECT_EQ(grads["effect_mu"][0], 0.0);
  EXPECT_EQ(grads["effect_mu"][1], 3.0);
  EXPECT_NEAR(grads["effect_eta"][1], 3.0 * -1.0 * sigmoid(inverse_softplus(0.1)), 1e-15);
  EXPECT_THROW(EffectBlock(Vector::Zero(1), Vector::Ones(1), Vector::Ones(1) * 2, Vector::Ones(1)), InputError);
}

TEST(InferAdam, MatchesStepsComputedByHand) {
  // theta = 1, lr 0.1, gradients 2 then -1 (beta1 0.9, beta2 0.999, epsilon 1e-8):
  //   t = 1: m = 0.2, v = 0.004, m^ = 2, v^ = 4: theta = 1 - 0.1 * 2 / (2 + 1e-8) = 0.9000000005
  //   t = 2: m = 0.08, v = 0.004996, m^ = 0.08 / 0.19, v^ = 0.004996 / 0.001999:
  //          theta = 0.9000000005 - 0.1 * 0.4210526316 / (1.5809015228 + 1e-8) = 0.8733662967024...
  Parameters theta{{"mu", Vector::Constant(1, 1.0)}};
  Parameters lr{{"mu", Vector::Constant(1, 0.1)}};
  AdamState state;
  adam_step(AdamSettings{}, theta, {{"mu", Vector::Constant(1, 2.0)}}, state, 1, lr, 1.0);
  EXPECT_NEAR(theta["mu"][0], 0.9000000005, 1e-15);
  EXPECT_NEAR(state.m["mu"][0], 0.2, 1e-15);
  EXPECT_NEAR(state.v["mu"][0], 0.004, 1e-15);
  adam_step(AdamSettings{}, theta, {{"mu", Vector::Constant(1, -1.0)}}, state, 2, lr, 1.0);
  EXPECT_NEAR(theta["mu"][0], 0.8733662967024315, 1e-13);
  // lr_scale halves the step; a per-entry learning rate; the effect means are projected into their bounds
  const EffectBlock b(Vector::Zero(2), (Vector(2) << -0.5, 0.0).finished(), (Vector(2) << 0.5, 1.0).finished(),
                      Vector::Ones(2));
  Parameters e{{"effect_mu", (Vector(2) << 0.49, 0.5).finished()}};
  AdamState es;
  adam_step(AdamSettings{}, e, {{"effect_mu", (Vector(2) << -1.0, 1.0).finished()}}, es, 1,
            {{"effect_mu", (Vector(2) << 0.1, 0.2).finished()}}, 0.5, &b);
  EXPECT_DOUBLE_EQ(e["effect_mu"][0], 0.5);  // 0.49 + 0.05 projected
  EXPECT_NEAR(e["effect_mu"][1], 0.4, 1e-9);
  EXPECT_THROW(adam_step(AdamSettings{}, e, {{"mu", Vector::Ones(2)}}, es, 1, lr, 1.0), InputError);
}

TEST(InferClipThreshold, IsFactorTimesTheMedianOfTheFirstWindow) {
  EXPECT_FALSE(clip_threshold({4.0, 1.0}, 3.0, 3, 3).has_value());             // too few yet
  EXPECT_DOUBLE_EQ(*clip_threshold({4.0, 1.0, 2.0}, 3.0, 3, 3), 6.0);           // median 2
  EXPECT_DOUBLE_EQ(*clip_threshold({4.0, 1.0, 2.0, 100.0}, 3.0, 3, 3), 6.0);    // frozen after the window
  EXPECT_DOUBLE_EQ(*clip_threshold({4.0, 1.0, 2.0, 100.0}, 3.0, 4, 3), 9.0);    // even count: mean of the middle two
  EXPECT_FALSE(clip_threshold({4.0, 1.0, 2.0}, 0.0, 3, 3).has_value());         // switched off
}

}  // namespace
}  // namespace drapelab::infer
