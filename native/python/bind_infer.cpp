// Bindings of infer/ as the submodule drapelab_native.infer: the variational families, the fitted effects'
// block, the ELBO assembly, Adam and the clip rule. Parameter blocks are dicts of flat float64 arrays; tables are
// (rows, 15) arrays. The facade addon/drapelab/variational.py reshapes to the fit's (3, 5) / (E, 3, 5) blocks.
// SampleLoop runs an epoch's drapes on native threads (GIL released, Progress polled).
#include <pybind11/eigen.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <map>
#include <memory>
#include <optional>

#include "infer/adam.hpp"
#include "infer/effect_block.hpp"
#include "infer/elbo.hpp"
#include "infer/sample_loop.hpp"
#include "infer/variational_family.hpp"
#include "py_progress.hpp"
#include "render/soft_rasterizer.hpp"
#include "util/error.hpp"

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
  py::class_<SilhouetteTarget>(m, "SilhouetteTarget", "A training silhouette: hard mask (H, W) and drape coefficient.")
      .def(py::init([](const drapelab::Image& mask, double dc) {
             if (!mask.allFinite()) throw drapelab::InputError("SilhouetteTarget: the mask has non-finite values");
             return SilhouetteTarget{mask, dc};
           }),
           py::arg("mask"), py::arg("drape_coefficient"))
      .def_readonly("mask", &SilhouetteTarget::mask)
      .def_readonly("drape_coefficient", &SilhouetteTarget::drape_coefficient);

  py::class_<DataTermSettings>(m, "DataTermSettings", "The data term's scales (infer/sample_loop.hpp).")
      .def(py::init([](double sigma_obs, double sigma_dc, double dc_bias, double px_per_m, double support_radius,
                       double specimen_radius) {
             return DataTermSettings{sigma_obs, sigma_dc, dc_bias, px_per_m, support_radius, specimen_radius};
           }),
           py::arg("sigma_obs"), py::arg("sigma_dc") = 0.0, py::arg("dc_bias") = 0.0, py::arg("px_per_m") = 720.0,
           py::arg("support_radius") = 0.09, py::arg("specimen_radius") = 0.15);

  m.def(
      "data_term",
      [](const drapelab::Image& image, const SilhouetteTarget& target, const DataTermSettings& settings) {
        if (!image.allFinite()) throw drapelab::InputError("data term: the image has non-finite values");
        drapelab::Image g;
        const double d = silhouette_data_term(image, target, settings, &g);
        return py::make_tuple(d, g);
      },
      py::arg("image"), py::arg("target"), py::arg("settings"),
      "(data term, its gradient per pixel) of a soft or hard silhouette against a target.");

  py::class_<SampleDraw>(m, "SampleDraw", "One Monte Carlo draw: parameters, placement velocities, target, slot.")
      .def(py::init([](Vector parameters, std::optional<Vector> velocities0, int target, int slot) {
             SampleDraw d;
             d.parameters = std::move(parameters);
             if (velocities0) d.velocities0 = std::move(*velocities0);
             d.target = target;
             d.slot = slot;
             return d;
           }),
           py::arg("parameters"), py::arg("velocities0") = py::none(), py::arg("target") = 0, py::arg("slot") = 0);

  py::class_<SampleLoop, std::shared_ptr<SampleLoop>>(
      m, "SampleLoop", "An epoch's draws on threads, one lane per model (infer/sample_loop.hpp).")
      .def(py::init([](std::vector<std::shared_ptr<drapelab::Model>> models, const drapelab::Camera& camera,
                       double render_sigma_px, bool static_mode, double time_step, int steps, double max_speed,
                       double force_tolerance, int max_iterations) {
             if (!(render_sigma_px > 0)) throw drapelab::InputError("SampleLoop: render_sigma_px must be > 0");
             if (steps < 1) throw drapelab::InputError("SampleLoop: steps must be >= 1");
             if (!(time_step > 0)) throw drapelab::InputError("SampleLoop: time_step must be > 0");
             if (max_iterations < 1) throw drapelab::InputError("SampleLoop: max_iterations must be >= 1");
             if (!(force_tolerance > 0)) throw drapelab::InputError("SampleLoop: force_tolerance must be > 0");
             std::vector<std::shared_ptr<const drapelab::Model>> lanes(models.begin(), models.end());
             drapelab::SoftRasterOptions render;
             render.sigma = render_sigma_px;
             DrapeSettings drape;
             drape.static_mode = static_mode;
             drape.rollout.time_step = time_step;
             drape.rollout.steps = steps;
             drape.rollout.max_speed = max_speed;
             drape.statics.force_tolerance = force_tolerance;
             drape.statics.max_iterations = max_iterations;
             return std::make_shared<SampleLoop>(std::move(lanes), camera, render, drape);
           }),
           py::arg("models"), py::arg("camera"), py::arg("render_sigma_px") = 1.0, py::arg("static") = false,
           py::arg("time_step") = 0.05, py::arg("steps") = 100, py::arg("max_speed") = 50.0,
           py::arg("force_tolerance") = 1e-6, py::arg("max_iterations") = 200)
      .def_property_readonly("lanes", &SampleLoop::lanes)
      .def_property("warm_starts", &SampleLoop::warm_starts, &SampleLoop::set_warm_starts,
                    "Static mode's warm starts: {slot: equilibrium (3V)}.")
      .def("forget_warm_starts", &SampleLoop::forget_warm_starts)
      .def(
          "run",
          [](SampleLoop& loop, const std::vector<SampleDraw>& draws, const std::vector<SilhouetteTarget>& targets,
             const DataTermSettings& data, std::shared_ptr<drapelab_bindings::PyProgress> progress) {
            std::vector<SampleOutcome> out;
            {
              py::gil_scoped_release no_gil;
              out = loop.run(draws, targets, data, drapelab_bindings::progress_sink_of(progress));
            }
            py::list results;
            for (auto& o : out) results.append(py::make_tuple(o.data, std::move(o.gradient), std::move(o.image)));
            return results;
          },
          py::arg("draws"), py::arg("targets"), py::arg("data"), py::arg("progress") = nullptr,
          "[(data term, dL/dparameters (flat), soft image)] per draw, in the draws' order.")
      .def(
          "score",
          [](SampleLoop& loop, const std::vector<SampleDraw>& draws, const std::vector<SilhouetteTarget>& targets,
             const DataTermSettings& data, std::shared_ptr<drapelab_bindings::PyProgress> progress) {
            std::vector<std::vector<double>> out;
            {
              py::gil_scoped_release no_gil;
              out = loop.score(draws, targets, data, drapelab_bindings::progress_sink_of(progress));
            }
            Eigen::MatrixXd m(static_cast<Eigen::Index>(out.size()), static_cast<Eigen::Index>(targets.size()));
            for (size_t i = 0; i < out.size(); ++i)
              for (size_t k = 0; k < targets.size(); ++k) m(i, k) = out[i][k];
            return m;
          },
          py::arg("draws"), py::arg("targets"), py::arg("data"), py::arg("progress") = nullptr,
          "(draws, targets) data terms of each draw's hard silhouette (unrecorded rollout from flat with its "
          "velocities) against every target; inf where the rollout fails.")
      .def(
          "predict",
          [](SampleLoop& loop, const std::vector<SampleDraw>& draws,
             std::shared_ptr<drapelab_bindings::PyProgress> progress) {
            std::vector<SampleLoop::Predicted> out;
            {
              py::gil_scoped_release no_gil;
              out = loop.predict(draws, drapelab_bindings::progress_sink_of(progress));
            }
            py::list results;
            for (auto& o : out) {
              if (!o.error.empty())
                results.append(py::make_tuple(py::none(), py::none(), o.error));
              else
                results.append(py::make_tuple(std::move(o.positions), std::move(o.image), py::none()));
            }
            return results;
          },
          py::arg("draws"), py::arg("progress") = nullptr,
          "[(positions (3V), hard silhouette, None) or (None, None, error message)] per draw: unrecorded rollouts "
          "from flat with the draws' velocities (static: equilibria from the flat rest state).");
}
