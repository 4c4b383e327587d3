// The fitted effect parameters of a fit (the facade's fit_effects.EffectPlan builds it from the effect registry):
// a vector with, per parameter, its off value, bounds and prior scale. The prior is N(off, prior_scale^2); a
// draw is the mean (stochastic families: mu + softplus(eta) eps, the reparameterisation) clipped to the bounds,
// and the gradient flows only through the entries inside them (the `inside` mask). Adam's steps are projected
// back into the bounds (project()).
#pragma once
#include <Eigen/Core>

#include "infer/variational_family.hpp"

namespace drapelab::infer {

class EffectBlock {
 public:
  EffectBlock() = default;
  EffectBlock(Vector off, Vector lower, Vector upper, Vector prior_scale);

  Eigen::Index size() const { return off_.size(); }
  const Vector& off() const { return off_; }
  const Vector& lower() const { return lower_; }
  const Vector& upper() const { return upper_; }
  const Vector& prior_scale() const { return prior_scale_; }

  struct Draw {
    Vector value;                         // clipped to the bounds
    Eigen::Array<bool, Eigen::Dynamic, 1> inside;  // entries whose unclipped value is within the bounds
  };
  // value clipped to the bounds and the mask of entries inside them.
  Draw clip(const Vector& value) const;
  Vector project(const Vector& value) const { return clip(value).value; }
  // One draw: theta's effect_mu, plus softplus(effect_eta) * eps when eps is given (stochastic families).
  Draw draw(const Parameters& theta, const Vector* eps) const;
  // grads += dL/d(effect_mu, effect_eta) of one draw whose data gradient w.r.t. the effect values is g (already
  // divided by the number of draws): g where inside, times eps sigmoid(eta) for effect_eta.
  void add_gradient(const Parameters& theta, const Vector& g, const Draw& draw, const Vector* eps,
                    Parameters& grads) const;
  // weight x the prior term (stochastic: KL of N(mu, softplus(eta)^2); else -log p up to a constant), its gradient
  // added to grads.
  double add_prior(const Parameters& theta, bool stochastic, double weight, Parameters& grads) const;

 private:
  Vector off_, lower_, upper_, prior_scale_;
};

}  // namespace drapelab::infer
