// Adam (Kingma & Ba 2015) on named parameter blocks, and the rule for the data gradient's clip norm.
#pragma once
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "infer/effect_block.hpp"
#include "infer/variational_family.hpp"

namespace drapelab::infer {

struct AdamSettings {
  double beta1 = 0.9, beta2 = 0.999, epsilon = 1e-8;
};

struct AdamState {
  Parameters m, v;  // first and second moments, blocks as theta's
};

// One step t (1-based) on every block of grads:
//   m = b1 m + (1 - b1) g,  v = b2 v + (1 - b2) g^2,
//   theta -= lr_scale lr m / (1 - b1^t) / (sqrt(v / (1 - b2^t)) + epsilon)
// learning_rates: per block, one value or one per entry. With effects, the block "effect_mu" is projected back
// into the effects' bounds after the step.
void adam_step(const AdamSettings& settings, Parameters& theta, const Parameters& grads, AdamState& state, int t,
               const Parameters& learning_rates, double lr_scale, const EffectBlock* effects = nullptr);

// The clip norm of the next epoch's data gradient: factor x the median of the first `window` of the accepted
// epochs' gradient norms (`norms`, in order); none while fewer than `min_epochs` are known, or when factor <= 0.
std::optional<double> clip_threshold(const std::vector<double>& norms, double factor, int window, int min_epochs);

}  // namespace drapelab::infer
