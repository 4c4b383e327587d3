#include "infer/gaussian.hpp"

#include <string>

#include "util/error.hpp"

namespace drapelab::infer {

GaussianKl kl_divergence(const Vector& mu, const Vector& sigma, const Vector& mu0, const Vector& sigma0) {
  const Eigen::Index n = mu.size();
  if (sigma.size() != n || mu0.size() != n || (sigma0.size() != n && sigma0.size() != 1))
    throw InputError("kl_divergence: mu, sigma and mu0 must have the same size (" + std::to_string(n) +
                     "), sigma0 that size or 1");
  GaussianKl out;
  out.d_mu.resize(n);
  out.d_sigma.resize(n);
  for (Eigen::Index i = 0; i < n; ++i) {
    const double s0 = sigma0.size() == 1 ? sigma0[0] : sigma0[i];
    const double s = sigma[i], dev = mu[i] - mu0[i];
    if (!(s > 0) || !(s0 > 0)) throw InputError("kl_divergence: standard deviations must be > 0");
    out.value += std::log(s0 / s) + (s * s + dev * dev) / (2 * s0 * s0) - 0.5;
    out.d_mu[i] = dev / (s0 * s0);
    out.d_sigma[i] = -1.0 / s + s / (s0 * s0);
  }
  return out;
}

}  // namespace drapelab::infer
