// The negative ELBO of one epoch from its Monte Carlo draws' data terms (DESIGN.md "Data flow of one fit"):
//   L = mean_s data_s + kl_weight KL(q || p) [+ kl_weight effect_prior_weight KL_effects]
// The data gradient is carried from each draw's dL/dB (per table entry) through B = exp(log B) and the family's
// reparameterisation to theta, averaged over the draws; its norm is reported, and with a clip norm it is scaled
// down to at most that norm (the factor is reported) before the prior's gradient, which is exact, is added.
#pragma once
#include <optional>
#include <vector>

#include "infer/effect_block.hpp"
#include "infer/variational_family.hpp"

namespace drapelab::infer {

// What one drape (one sample against one observation) gives the ELBO.
struct Draw {
  double data = 0.0;         // the data term
  Tables table_gradient;     // dL_data/dB, shaped like tables
  Tables tables;             // the bending tables it was draped with (N m)
  std::optional<Tables> noise;  // the family's noise (stochastic families)
  Vector effect_gradient;    // dL_data/d(effect values) (fitted effects; empty without)
  std::optional<Vector> effect_noise;  // the effect posterior's noise (stochastic families)
};

struct ElboSettings {
  Vector prior_mu;            // the log table the prior is centred on (15)
  double prior_sigma = 1.0;   // its sd (log units)
  double kl_weight = 1.0;
  double effect_prior_weight = 1.0;  // times kl_weight for the fitted effects' prior
};

struct ElboTerms {
  double loss = 0.0, data = 0.0, kl = 0.0;
  double grad_norm = 0.0;  // norm of the data term's gradient before clipping (all blocks)
  double clip = 1.0;       // the factor the data gradient was scaled by
  Parameters gradient;     // dL/dtheta, blocks as theta's
};

// effects may be nullptr (no fitted effects); clip: the norm the data gradient is capped at (none: unclipped).
ElboTerms assemble_elbo(const VariationalFamily& family, const EffectBlock* effects, const ElboSettings& settings,
                        const Parameters& theta, const std::vector<Draw>& draws, std::optional<double> clip);

}  // namespace drapelab::infer
