#include "infer/adam.hpp"

#include <algorithm>
#include <cmath>

#include "util/error.hpp"

namespace drapelab::infer {

void adam_step(const AdamSettings& s, Parameters& theta, const Parameters& grads, AdamState& state, int t,
               const Parameters& learning_rates, double lr_scale, const EffectBlock* effects) {
  if (t < 1) throw InputError("adam: the step number must be >= 1");
  for (const auto& [name, g] : grads) {
    auto th = theta.find(name);
    auto lr = learning_rates.find(name);
    if (th == theta.end() || lr == learning_rates.end())
      throw InputError("adam: no parameter block or learning rate '" + name + "'");
    const Eigen::Index n = g.size();
    if (th->second.size() != n || (lr->second.size() != 1 && lr->second.size() != n))
      throw InputError("adam: block '" + name + "' sizes of parameters, gradient and learning rate differ");
    Vector& m = state.m[name];
    Vector& v = state.v[name];
    if (m.size() != n) m = Vector::Zero(n);
    if (v.size() != n) v = Vector::Zero(n);
    m = (s.beta1 * m.array() + (1 - s.beta1) * g.array()).matrix();
    v = (s.beta2 * v.array() + (1 - s.beta2) * g.array() * g.array()).matrix();
    const double c1 = 1 - std::pow(s.beta1, t), c2 = 1 - std::pow(s.beta2, t);
    for (Eigen::Index i = 0; i < n; ++i) {
      const double rate = lr->second.size() == 1 ? lr->second[0] : lr->second[i];
      th->second[i] = th->second[i] - lr_scale * rate * (m[i] / c1) / (std::sqrt(v[i] / c2) + s.epsilon);
    }
  }
  if (effects && effects->size() > 0) {
    auto it = theta.find("effect_mu");
    if (it != theta.end()) it->second = effects->project(it->second);
  }
}

std::optional<double> clip_threshold(const std::vector<double>& norms, double factor, int window, int min_epochs) {
  if (!(factor > 0)) return std::nullopt;
  std::vector<double> first(norms.begin(), norms.begin() + std::min<std::size_t>(norms.size(), std::max(window, 0)));
  if (first.empty() || int(first.size()) < min_epochs) return std::nullopt;
  std::sort(first.begin(), first.end());
  const std::size_t k = first.size();
  const double median = k % 2 ? first[k / 2] : 0.5 * (first[k / 2 - 1] + first[k / 2]);
  return factor * median;
}

}  // namespace drapelab::infer
