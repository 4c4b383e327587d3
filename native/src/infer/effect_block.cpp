#include "infer/effect_block.hpp"

#include <algorithm>
#include <string>

#include "util/error.hpp"

namespace drapelab::infer {

EffectBlock::EffectBlock(Vector off, Vector lower, Vector upper, Vector prior_scale)
    : off_(std::move(off)), lower_(std::move(lower)), upper_(std::move(upper)), prior_scale_(std::move(prior_scale)) {
  const Eigen::Index n = off_.size();
  if (lower_.size() != n || upper_.size() != n || prior_scale_.size() != n)
    throw InputError("effects: off, lower, upper and prior_scale must have one entry per fitted parameter");
  for (Eigen::Index i = 0; i < n; ++i) {
    if (!(lower_[i] <= off_[i] && off_[i] <= upper_[i]))
      throw InputError("effects: parameter " + std::to_string(i) + ": off value outside its bounds");
    if (!(prior_scale_[i] > 0) || !std::isfinite(prior_scale_[i]))
      throw InputError("effects: parameter " + std::to_string(i) + ": prior scale must be a finite number > 0");
  }
}

EffectBlock::Draw EffectBlock::clip(const Vector& value) const {
  if (value.size() != size())
    throw InputError("effects: expected " + std::to_string(size()) + " values, got " + std::to_string(value.size()));
  Draw d;
  d.inside = (value.array() >= lower_.array()) && (value.array() <= upper_.array());
  d.value = value.cwiseMax(lower_).cwiseMin(upper_);
  return d;
}

static const Vector& effect_block(const Parameters& theta, const char* name, Eigen::Index n) {
  auto it = theta.find(name);
  if (it == theta.end()) throw InputError(std::string("theta: missing parameter block '") + name + "'");
  if (it->second.size() != n)
    throw InputError(std::string("theta.") + name + ": expected " + std::to_string(n) + " values, got " +
                     std::to_string(it->second.size()));
  return it->second;
}

EffectBlock::Draw EffectBlock::draw(const Parameters& theta, const Vector* eps) const {
  const Vector& mu = effect_block(theta, "effect_mu", size());
  if (!eps) return clip(mu);
  if (eps->size() != size()) throw InputError("effect noise: expected " + std::to_string(size()) + " values");
  return clip(mu + softplus(effect_block(theta, "effect_eta", size())).cwiseProduct(*eps));
}

void EffectBlock::add_gradient(const Parameters& theta, const Vector& g, const Draw& draw, const Vector* eps,
                               Parameters& grads) const {
  if (g.size() != size()) throw InputError("effect gradient: expected " + std::to_string(size()) + " values");
  const Vector g_in = draw.inside.select(g, 0.0);
  grads.at("effect_mu") += g_in;
  if (eps)
    grads.at("effect_eta") +=
        g_in.cwiseProduct(*eps).cwiseProduct(sigmoid(effect_block(theta, "effect_eta", size())));
}

double EffectBlock::add_prior(const Parameters& theta, bool stochastic, double weight, Parameters& grads) const {
  const Vector& mu = effect_block(theta, "effect_mu", size());
  if (stochastic) {
    const Vector& eta = effect_block(theta, "effect_eta", size());
    const GaussianKl kl = kl_divergence(mu, softplus(eta), off_, prior_scale_);
    grads.at("effect_eta") += weight * kl.d_sigma.cwiseProduct(sigmoid(eta));
    grads.at("effect_mu") += weight * kl.d_mu;
    return weight * kl.value;
  }
  const Vector dev = (mu - off_).cwiseQuotient(prior_scale_);
  grads.at("effect_mu") += weight * dev.cwiseQuotient(prior_scale_);
  return weight * (0.5 * dev.squaredNorm());
}

}  // namespace drapelab::infer
