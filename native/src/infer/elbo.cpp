#include "infer/elbo.hpp"

#include <cmath>
#include <string>

#include "util/error.hpp"

namespace drapelab::infer {

ElboTerms assemble_elbo(const VariationalFamily& family, const EffectBlock* effects, const ElboSettings& settings,
                        const Parameters& theta, const std::vector<Draw>& draws, std::optional<double> clip) {
  if (draws.empty()) throw InputError("elbo: no draws");
  if (settings.prior_mu.size() != kBendEntries) throw InputError("elbo: prior_mu must have 15 entries");
  if (!(settings.prior_sigma > 0)) throw InputError("elbo: prior_sigma must be > 0");
  if (clip && !(*clip >= 0)) throw InputError("elbo: the clip norm must be >= 0");
  const bool fitted_effects = effects && effects->size() > 0;
  ElboTerms out;
  for (const auto& [name, values] : theta) out.gradient[name] = Vector::Zero(values.size());
  const double n = double(draws.size());
  for (const Draw& d : draws) {
    if (d.table_gradient.rows() != d.tables.rows() || d.table_gradient.cols() != d.tables.cols())
      throw InputError("elbo: a draw's table gradient is not shaped like its tables");
    if (!std::isfinite(d.data) || !d.table_gradient.allFinite())
      throw InputError("elbo: a draw's data term or gradient is not finite");
    out.data += d.data / n;
    const Tables g_log = (d.table_gradient.array() * d.tables.array() / n).matrix();  // dL/dlog B
    family.add_log_table_gradient(theta, g_log, d.noise ? &*d.noise : nullptr, out.gradient);
    if (fitted_effects) {
      const Vector* eps = d.effect_noise ? &*d.effect_noise : nullptr;
      const EffectBlock::Draw e = effects->draw(theta, eps);
      effects->add_gradient(theta, d.effect_gradient / n, e, eps, out.gradient);
    }
  }
  double sq = 0.0;
  for (const auto& [name, g] : out.gradient) sq += g.squaredNorm();
  out.grad_norm = std::sqrt(sq);
  if (clip && out.grad_norm > *clip) {
    out.clip = *clip / out.grad_norm;
    for (auto& [name, g] : out.gradient) g *= out.clip;
  }
  out.kl = family.add_prior(theta, settings.prior_mu, settings.prior_sigma, settings.kl_weight, out.gradient);
  if (fitted_effects)
    out.kl += effects->add_prior(theta, family.stochastic(), settings.kl_weight * settings.effect_prior_weight,
                                 out.gradient);
  out.loss = out.data + out.kl;
  return out;
}

}  // namespace drapelab::infer
