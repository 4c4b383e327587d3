// Scalar maps of the variational parameterisation and the Gaussian KL, shared by the families and the effect block.
// softplus and sigmoid use the same formulas as numpy's logaddexp(0, x) and 0.5 (1 + tanh(x / 2)), so that the
// trainer reproduces the Python trainer's numbers to round-off.
#pragma once
#include <Eigen/Core>
#include <cmath>

namespace drapelab::infer {

using Vector = Eigen::VectorXd;

// softplus(x) = log(1 + e^x): a posterior sd from an unconstrained parameter eta.
inline double softplus(double x) {
  if (x > 0) return x + std::log1p(std::exp(-x));
  if (x == 0) return M_LN2;
  return std::log1p(std::exp(x));
}

// d softplus / dx.
inline double sigmoid(double x) { return 0.5 * (1.0 + std::tanh(0.5 * x)); }

// The eta whose softplus is y (> 0).
inline double inverse_softplus(double y) { return std::log(std::expm1(y)); }

inline Vector softplus(const Vector& x) { return x.unaryExpr([](double v) { return softplus(v); }); }
inline Vector sigmoid(const Vector& x) { return x.unaryExpr([](double v) { return sigmoid(v); }); }

// KL(N(mu, sigma^2) || N(mu0, sigma0^2)) per entry:
//   log(sigma0 / sigma) + (sigma^2 + (mu - mu0)^2) / (2 sigma0^2) - 1/2,
// summed over entries, with its gradients d/dmu = (mu - mu0) / sigma0^2 and d/dsigma = -1/sigma + sigma/sigma0^2.
// sigma0 has one entry per entry of mu, or one for all.
struct GaussianKl {
  double value = 0.0;
  Vector d_mu, d_sigma;
};
GaussianKl kl_divergence(const Vector& mu, const Vector& sigma, const Vector& mu0, const Vector& sigma0);

}  // namespace drapelab::infer
