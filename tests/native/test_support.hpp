// Shared helpers for the C++ tests: small meshes, perturbed states, data paths.
#pragma once
#include <Eigen/Core>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <random>
#include <algorithm>
#include <string>
#include <vector>

#include "geometry/cusick.hpp"
#include "physics/effect.hpp"
#include "physics/model.hpp"
#include "physics/sparse_pattern.hpp"
#include "source_dir.hpp"

namespace drapelab::testing {

// The one locator of the shared Cusick dataset for the C++ tests (the same rule as drapelab.paths):
// $DRAPELAB_CUSICK_DIR when set (a folder without manifest.csv there means "hidden"), else
// ../shared/data/cusick beside the repository. "" when absent: tests that need it GTEST_SKIP with
// kNoDatasetReason.
inline std::string cusick_dataset_dir() {
  const char* env = std::getenv("DRAPELAB_CUSICK_DIR");
  const std::string dir = env ? std::string(env) : source_dir() + "/../shared/data/cusick";
  return !dir.empty() && std::ifstream(dir + "/manifest.csv").good() ? dir : std::string();
}
inline constexpr const char* kNoDatasetReason =
    "needs the full Cusick dataset: not found at $DRAPELAB_CUSICK_DIR or ../shared/data/cusick";

// The Cusick template meshes circle1..5 shipped in the repository (tests fail, not skip, when missing).
inline std::string template_dir() { return source_dir() + "/assets/cusick/template_meshes"; }

// A state near the draped regime: rest positions plus smooth out-of-plane sag and random noise (m).
inline Eigen::VectorXd perturbed_positions(const Model& model, double noise, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> n01(0.0, 1.0);
  Eigen::VectorXd x = model.rest_positions();
  for (int i = 0; i < model.num_vertices(); ++i) {
    const double r = x.segment<2>(3 * i).norm();
    x[3 * i + 2] -= 0.3 * std::max(0.0, r - 0.09);
    for (int k = 0; k < 3; ++k) x[3 * i + k] += noise * n01(rng);
  }
  return x;
}

// Values on a pattern (upper triangle, pattern order) as a dense symmetric matrix.
inline Eigen::MatrixXd dense_symmetric(const SparsePattern& pattern, const Eigen::VectorXd& values) {
  const int n = pattern.size();
  Eigen::MatrixXd M = Eigen::MatrixXd::Zero(n, n);
  for (int c = 0; c < n; ++c)
    for (int q = pattern.column_start()[c]; q < pattern.column_start()[c + 1]; ++q) {
      const int r = pattern.row_index()[q];
      M(r, c) = M(c, r) = values[q];
    }
  return M;
}

inline Eigen::VectorXd random_vector(int n, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> n01(0.0, 1.0);
  Eigen::VectorXd v(n);
  for (int i = 0; i < n; ++i) v[i] = n01(rng);
  return v;
}

// Heterogeneous parameters: the defaults with every entry scaled by a random factor in [0.7, 1.3].
inline Eigen::VectorXd jittered_parameters(const Model& model, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0.7, 1.3);
  Eigen::VectorXd p = model.default_parameters();
  for (int i = 0; i < p.size(); ++i) p[i] *= u(rng);
  return p;
}

// Strongly heterogeneous parameters, as a BDP draw makes them: every element's stretch and bending table
// scaled by its own log-normal factor exp(spread * N(0, 1)) (each table keeps its shape, so stays valid).
inline Eigen::VectorXd lognormal_element_parameters(const Model& model, double spread, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> n01(0.0, 1.0);
  Eigen::VectorXd p = model.default_parameters();
  for (const char* name : {"stretch", "bend"}) {
    const ParameterBlock& b = model.layout().block(name);
    for (int e = 0; e < b.size / b.entries_per_element; ++e)
      p.segment(b.offset + e * b.entries_per_element, b.entries_per_element) *= std::exp(spread * n01(rng));
  }
  return p;
}

// Names of the registered effects, in registry order (the per-effect suites are instantiated over them).
inline std::vector<std::string> registered_effect_names() {
  std::vector<std::string> names;
  for (const auto& e : effect_registry()) names.push_back(e.name);
  return names;
}

// The effect at a random strength: every parameter between 0.5x and 1x its moderate value, signs random where
// the bounds allow.
inline EffectValues moderate_effect_values(const EffectSpec& spec, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0.5, 1.0);
  std::bernoulli_distribution coin(0.5);
  EffectValues v;
  for (const auto& q : spec.parameters) {
    double value = q.off + u(rng) * (q.moderate - q.off);
    if (q.lower < q.off && coin(rng)) value = q.off - (value - q.off);
    v[spec.name][q.name] = std::min(q.upper, std::max(q.lower, value));
  }
  return v;
}

}  // namespace drapelab::testing
