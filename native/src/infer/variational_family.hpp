// The variational families of the bending table (the paper's models), learned in log space:
//   homo   one deterministic table:          log B_w = mu                     for every bending edge w
//   heter  one deterministic table per edge:  log B_w = mu_w
//   bdp    mean-field Gaussian, per element:  log B_w = mu + softplus(eta) * eps_w,  eps_w ~ N(0, I)
// A family names its parameter blocks, draws bending tables from standard-normal noise (the
// reparameterisation), carries dL/dlog B back to its parameters (the chain rule), and holds its prior term:
// the KL to N(mu0, s0^2) for bdp, the MAP term -log p (up to a constant) for homo and heter (averaged over
// elements for heter, like the bdp term, which is a sum over the 15 table entries).
//
// Layouts: a table is kBendEntries = 3 bias angles x 5 curvature samples, row-major (numpy's (3, 5)); tables
// are a row-major matrix with one row per bending edge (homo: one row for all); parameter blocks are flat vectors
// (heter's mu: edges x 15, row-major).
#pragma once
#include <Eigen/Core>
#include <map>
#include <memory>
#include <string>
#include <utility>

#include "infer/gaussian.hpp"

namespace drapelab::infer {

inline constexpr int kBendEntries = 15;  // 3 x 5 bending table
using Parameters = std::map<std::string, Vector>;  // parameter block name -> flat values
using Tables = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

class VariationalFamily {
 public:
  virtual ~VariationalFamily() = default;
  virtual std::string name() const = 0;
  // One table per bending edge (the model is built heterogeneous).
  virtual bool per_element() const = 0;
  // Draws use noise: several Monte Carlo samples per epoch, placement noise, a posterior over fitted effects.
  virtual bool stochastic() const = 0;
  // The parameters at the starting log table (15 entries); init_std: bdp's starting posterior sd.
  virtual Parameters initial(const Vector& log_bend0, int num_edges, double init_std) const = 0;
  // Rows of tables (N m): homo one, else num_edges. noise: num_edges x 15 standard normals (bdp; nullptr: zero).
  virtual Tables tables(const Parameters& theta, int num_edges, const Tables* noise) const = 0;
  // grads += dL/dtheta for g_log = dL/dlog B (shaped like tables()) at this draw's noise.
  virtual void add_log_table_gradient(const Parameters& theta, const Tables& g_log, const Tables* noise,
                                      Parameters& grads) const = 0;
  // weight x the prior term (KL or -log p) around the log table prior_mu (15) with sd prior_sigma; adds its
  // gradient to grads.
  virtual double add_prior(const Parameters& theta, const Vector& prior_mu, double prior_sigma, double weight,
                           Parameters& grads) const = 0;
  // Posterior summary of the log table: mean and sd per entry (heter: across edges).
  virtual std::pair<Vector, Vector> posterior(const Parameters& theta) const = 0;

 protected:
  static const Vector& block(const Parameters& theta, const char* name, Eigen::Index size);
};

// "homo", "heter" or "bdp"; InputError naming the choices otherwise.
std::unique_ptr<VariationalFamily> make_family(const std::string& name);

}  // namespace drapelab::infer
