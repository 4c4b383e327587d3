#include "infer/variational_family.hpp"

#include <cmath>

#include "util/error.hpp"

namespace drapelab::infer {

const Vector& VariationalFamily::block(const Parameters& theta, const char* name, Eigen::Index size) {
  auto it = theta.find(name);
  if (it == theta.end()) throw InputError(std::string("theta: missing parameter block '") + name + "'");
  if (size >= 0 && it->second.size() != size)
    throw InputError(std::string("theta.") + name + ": expected " + std::to_string(size) + " values, got " +
                     std::to_string(it->second.size()));
  return it->second;
}

namespace {

void check_log_table(const Vector& log_bend0) {
  if (log_bend0.size() != kBendEntries || !log_bend0.allFinite())
    throw InputError("log_bend0: expected 15 finite values (the 3 x 5 log bending table)");
}

void check_noise(const Tables* noise, int num_edges) {
  if (noise && (noise->rows() != num_edges || noise->cols() != kBendEntries))
    throw InputError("noise: expected " + std::to_string(num_edges) + " x 15 values, got " +
                     std::to_string(noise->rows()) + " x " + std::to_string(noise->cols()));
}

class Homo final : public VariationalFamily {
 public:
  std::string name() const override { return "homo"; }
  bool per_element() const override { return false; }
  bool stochastic() const override { return false; }
  Parameters initial(const Vector& log_bend0, int, double) const override {
    check_log_table(log_bend0);
    return {{"mu", log_bend0}};
  }
  Tables tables(const Parameters& theta, int, const Tables*) const override {
    return block(theta, "mu", kBendEntries).array().exp().matrix().transpose();
  }
  void add_log_table_gradient(const Parameters&, const Tables& g_log, const Tables*, Parameters& grads) const override {
    grads.at("mu") += g_log.row(0).transpose();
  }
  double add_prior(const Parameters& theta, const Vector& prior_mu, double prior_sigma, double weight,
                   Parameters& grads) const override {
    const Vector dev = (block(theta, "mu", kBendEntries) - prior_mu) / prior_sigma;
    grads.at("mu") += weight * dev / prior_sigma;
    return weight * 0.5 * dev.squaredNorm();
  }
  std::pair<Vector, Vector> posterior(const Parameters& theta) const override {
    return {block(theta, "mu", kBendEntries), Vector::Zero(kBendEntries)};
  }
};

class Heter final : public VariationalFamily {
 public:
  std::string name() const override { return "heter"; }
  bool per_element() const override { return true; }
  bool stochastic() const override { return false; }
  Parameters initial(const Vector& log_bend0, int num_edges, double) const override {
    check_log_table(log_bend0);
    return {{"mu", log_bend0.replicate(num_edges, 1)}};
  }
  Tables tables(const Parameters& theta, int num_edges, const Tables*) const override {
    const Vector& mu = block(theta, "mu", Eigen::Index(num_edges) * kBendEntries);
    return Eigen::Map<const Tables>(mu.data(), num_edges, kBendEntries).array().exp().matrix();
  }
  void add_log_table_gradient(const Parameters&, const Tables& g_log, const Tables*, Parameters& grads) const override {
    Vector& g = grads.at("mu");
    if (g.size() != g_log.size()) throw InputError("heter: table gradient does not match the parameters");
    g += Eigen::Map<const Vector>(g_log.data(), g_log.size());
  }
  double add_prior(const Parameters& theta, const Vector& prior_mu, double prior_sigma, double weight,
                   Parameters& grads) const override {
    const Vector& mu = block(theta, "mu", -1);
    const Eigen::Index edges = mu.size() / kBendEntries;
    const double per = 1.0 / double(edges);
    Vector dev = (mu - prior_mu.replicate(edges, 1)) / prior_sigma;
    grads.at("mu") += weight * dev / prior_sigma * per;
    return weight * 0.5 * dev.squaredNorm() * per;
  }
  std::pair<Vector, Vector> posterior(const Parameters& theta) const override {
    const Vector& mu = block(theta, "mu", -1);
    const Eigen::Index edges = mu.size() / kBendEntries;
    Eigen::Map<const Tables> rows(mu.data(), edges, kBendEntries);
    const Vector mean = rows.colwise().mean().transpose();
    const Vector sd = ((rows.rowwise() - mean.transpose()).array().square().colwise().mean()).sqrt().transpose();
    return {mean, sd};
  }
};

class Bdp final : public VariationalFamily {
 public:
  std::string name() const override { return "bdp"; }
  bool per_element() const override { return true; }
  bool stochastic() const override { return true; }
  Parameters initial(const Vector& log_bend0, int, double init_std) const override {
    check_log_table(log_bend0);
    if (!(init_std > 0)) throw InputError("init.bdp_std: must be > 0");
    return {{"mu", log_bend0}, {"eta", Vector::Constant(kBendEntries, inverse_softplus(init_std))}};
  }
  Tables tables(const Parameters& theta, int num_edges, const Tables* noise) const override {
    check_noise(noise, num_edges);
    const Vector& mu = block(theta, "mu", kBendEntries);
    const Vector sigma = softplus(block(theta, "eta", kBendEntries));
    Tables out(num_edges, kBendEntries);
    for (int w = 0; w < num_edges; ++w)
      for (int j = 0; j < kBendEntries; ++j) out(w, j) = std::exp(mu[j] + sigma[j] * (noise ? (*noise)(w, j) : 0.0));
    return out;
  }
  void add_log_table_gradient(const Parameters& theta, const Tables& g_log, const Tables* noise,
                              Parameters& grads) const override {
    check_noise(noise, int(g_log.rows()));
    // dL/dmu = sum_w g_w, dL/deta = sum_w g_w eps_w sigmoid(eta) (rows summed in order, as numpy does)
    Vector sum = Vector::Zero(kBendEntries), weighted = Vector::Zero(kBendEntries);
    for (Eigen::Index w = 0; w < g_log.rows(); ++w) {
      sum += g_log.row(w).transpose();
      if (noise) weighted += g_log.row(w).cwiseProduct(noise->row(w)).transpose();
    }
    grads.at("mu") += sum;
    grads.at("eta") += weighted.cwiseProduct(sigmoid(block(theta, "eta", kBendEntries)));
  }
  double add_prior(const Parameters& theta, const Vector& prior_mu, double prior_sigma, double weight,
                   Parameters& grads) const override {
    const Vector& eta = block(theta, "eta", kBendEntries);
    const GaussianKl kl = kl_divergence(block(theta, "mu", kBendEntries), softplus(eta), prior_mu,
                                        Vector::Constant(1, prior_sigma));
    grads.at("mu") += weight * kl.d_mu;
    grads.at("eta") += weight * kl.d_sigma.cwiseProduct(sigmoid(eta));
    return kl.value * weight;
  }
  std::pair<Vector, Vector> posterior(const Parameters& theta) const override {
    return {block(theta, "mu", kBendEntries), softplus(block(theta, "eta", kBendEntries))};
  }
};

}  // namespace

std::unique_ptr<VariationalFamily> make_family(const std::string& name) {
  if (name == "homo") return std::make_unique<Homo>();
  if (name == "heter") return std::make_unique<Heter>();
  if (name == "bdp") return std::make_unique<Bdp>();
  throw InputError("model: expected one of ('homo', 'heter', 'bdp'), got '" + name + "'");
}

}  // namespace drapelab::infer
