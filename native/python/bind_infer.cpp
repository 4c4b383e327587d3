// Bindings of infer/ as the submodule drapelab_native.infer: the variational families, the fitted effects'
// block, the ELBO assembly, Adam and the clip rule. Parameter blocks are dicts of flat float64 arrays; tables are
// (rows, 15) arrays. The facade addon/drapelab/variational.py reshapes to the fit's (3, 5) / (E, 3, 5) blocks.
#include <pybind11/eigen.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <memory>
#include <optional>

#include "infer/adam.hpp"
#include "infer/effect_block.hpp"
#include "infer/elbo.hpp"
#include "infer/variational_family.hpp"

namespace py = pybind11;
using namespace drapelab::infer;

namespace {

py::tuple clip_result(const EffectBlock::Draw& d) {
  return py::make_tuple(d.value, Eigen::Array<bool, Eigen::Dynamic, 1>(d.inside));
}

}  // namespace

void bind_infer(py::module_& root) {
  py::module_ m = root.def_submodule("infer", "The trainer's numerical core (native/src/infer)");
  m.attr("BEND_ENTRIES") = kBendEntries;

  py::class_<VariationalFamily, std::shared_ptr<VariationalFamily>>(
      m, "Family", "A variational family of the bending table: homo, heter or bdp (infer/variational_family.hpp).")
      .def(py::init([](const std::string& name) { return std::shared_ptr<VariationalFamily>(make_family(name)); }),
           py::arg("name"))
      .def_property_readonly("name", &VariationalFamily::name)
      .def_property_readonly("per_element", &VariationalFamily::per_element)
      .def_property_readonly("stochastic", &VariationalFamily::stochastic)
      .def("initial", &VariationalFamily::initial, py::arg("log_bend0"), py::arg("num_edges"), py::arg("init_std"))
      .def(
          "tables",
          [](const VariationalFamily& f, const Parameters& theta, int num_edges, std::optional<Tables> noise) {
            return f.tables(theta, num_edges, noise ? &*noise : nullptr);
          },
          py::arg("theta"), py::arg("num_edges"), py::arg("noise") = py::none())
      .def(
          "log_table_gradient",
          [](const VariationalFamily& f, const Parameters& theta, const Tables& g_log, std::optional<Tables> noise) {
            Parameters grads;
            for (const auto& [k, v] : theta) grads[k] = Vector::Zero(v.size());
            f.add_log_table_gradient(theta, g_log, noise ? &*noise : nullptr, grads);
            return grads;
          },
          py::arg("theta"), py::arg("g_log"), py::arg("noise") = py::none(),
          "dL/dtheta (dict) for dL/dlog B = g_log at this noise (the chain rule of the reparameterisation).")
      .def(
          "prior",
          [](const VariationalFamily& f, const Parameters& theta, const Vector& prior_mu, double prior_sigma,
             double weight) {
            Parameters grads;
            for (const auto& [k, v] : theta) grads[k] = Vector::Zero(v.size());
            const double value = f.add_prior(theta, prior_mu, prior_sigma, weight, grads);
            return py::make_tuple(value, grads);
          },
          py::arg("theta"), py::arg("prior_mu"), py::arg("prior_sigma"), py::arg("weight") = 1.0,
          "(weight x the KL or MAP prior term, its gradient dict).")
      .def("posterior", &VariationalFamily::posterior, py::arg("theta"),
           "(mean, sd) of the log table per entry (heter: across edges).");

  py::class_<EffectBlock>(m, "EffectBlock", "The fitted effect parameters: off values, bounds and prior scales.")
      .def(py::init<Vector, Vector, Vector, Vector>(), py::arg("off"), py::arg("lower"), py::arg("upper"),
           py::arg("prior_scale"))
      .def_property_readonly("size", &EffectBlock::size)
      .def("clip", [](const EffectBlock& b, const Vector& v) { return clip_result(b.clip(v)); }, py::arg("value"),
           "(value clipped to the bounds, mask of the entries inside them).")
      .def(
          "draw",
          [](const EffectBlock& b, const Parameters& theta, std::optional<Vector> eps) {
            return clip_result(b.draw(theta, eps ? &*eps : nullptr));
          },
          py::arg("theta"), py::arg("noise") = py::none(),
          "(clipped value, inside mask) of one draw: effect_mu (+ softplus(effect_eta) noise).");

  py::class_<Draw>(m, "Draw", "What one drape gives the ELBO (infer/elbo.hpp).")
      .def(py::init([](double data, Tables table_gradient, Tables tables, std::optional<Tables> noise,
                       std::optional<Vector> effect_gradient, std::optional<Vector> effect_noise) {
             Draw d;
             d.data = data;
             d.table_gradient = std::move(table_gradient);
             d.tables = std::move(tables);
             d.noise = std::move(noise);
             d.effect_gradient = effect_gradient ? *effect_gradient : Vector();
             d.effect_noise = std::move(effect_noise);
             return d;
           }),
           py::arg("data"), py::arg("table_gradient"), py::arg("tables"), py::arg("noise") = py::none(),
           py::arg("effect_gradient") = py::none(), py::arg("effect_noise") = py::none());

  m.def(
      "assemble_elbo",
      [](const VariationalFamily& family, const EffectBlock* effects, const Parameters& theta,
         const std::vector<Draw>& draws, std::optional<double> clip, const Vector& prior_mu, double prior_sigma,
         double kl_weight, double effect_prior_weight) {
        ElboSettings s{prior_mu, prior_sigma, kl_weight, effect_prior_weight};
        const ElboTerms t = assemble_elbo(family, effects, s, theta, draws, clip);
        py::dict terms;
        terms["loss"] = t.loss;
        terms["data"] = t.data;
        terms["kl"] = t.kl;
        terms["grad_norm"] = t.grad_norm;
        terms["clip"] = t.clip;
        return py::make_tuple(terms, t.gradient);
      },
      py::arg("family"), py::arg("effects"), py::arg("theta"), py::arg("draws"), py::arg("clip"),
      py::arg("prior_mu"), py::arg("prior_sigma"), py::arg("kl_weight"), py::arg("effect_prior_weight"),
      "(terms {loss, data, kl, grad_norm, clip}, gradient dict) of the negative ELBO over the draws.");

  m.def(
      "adam_step",
      [](Parameters theta, const Parameters& grads, Parameters m1, Parameters m2, int t,
         const Parameters& learning_rates, double lr_scale, double beta1, double beta2, double epsilon,
         const EffectBlock* effects) {
        AdamState state{std::move(m1), std::move(m2)};
        adam_step(AdamSettings{beta1, beta2, epsilon}, theta, grads, state, t, learning_rates, lr_scale, effects);
        return py::make_tuple(theta, state.m, state.v);
      },
      py::arg("theta"), py::arg("grads"), py::arg("m"), py::arg("v"), py::arg("t"), py::arg("learning_rates"),
      py::arg("lr_scale"), py::arg("beta1"), py::arg("beta2"), py::arg("epsilon"), py::arg("effects") = nullptr,
      "(theta, m, v) after one Adam step t (effect_mu projected into the effects' bounds).");

  m.def("clip_threshold", &clip_threshold, py::arg("norms"), py::arg("factor"), py::arg("window"),
        py::arg("min_epochs"), "factor x the median of the first `window` norms (None: fewer than min_epochs).");

  m.def(
      "kl_divergence",
      [](const Vector& mu, const Vector& sigma, const Vector& mu0, const Vector& sigma0) {
        const GaussianKl kl = kl_divergence(mu, sigma, mu0, sigma0);
        return py::make_tuple(kl.value, kl.d_mu, kl.d_sigma);
      },
      py::arg("mu"), py::arg("sigma"), py::arg("mu0"), py::arg("sigma0"),
      "(sum of KL(N(mu, sigma^2) || N(mu0, sigma0^2)), d/dmu, d/dsigma).");
}
