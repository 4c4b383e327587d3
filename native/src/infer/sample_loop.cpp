#include "infer/sample_loop.hpp"

#include <atomic>
#include <cmath>
#include <exception>
#include <limits>
#include <string>
#include <thread>

#include "measure/metrics.hpp"
#include "render/rasterizer.hpp"
#include "util/error.hpp"

namespace drapelab::infer {

namespace {

constexpr double kPi = 3.14159265358979323846;

void check_settings(const DataTermSettings& s) {
  if (!(s.sigma_obs > 0) || !std::isfinite(s.sigma_obs))
    throw InputError("data term: sigma_obs must be > 0, got " + std::to_string(s.sigma_obs));
  if (!(s.sigma_dc >= 0) || !std::isfinite(s.sigma_dc))
    throw InputError("data term: sigma_dc must be >= 0 (0: no drape-coefficient term), got " +
                     std::to_string(s.sigma_dc));
  if (!std::isfinite(s.dc_bias)) throw InputError("data term: dc_bias must be finite");
  if (!(s.px_per_m > 0) || !std::isfinite(s.px_per_m))
    throw InputError("data term: px_per_m must be > 0, got " + std::to_string(s.px_per_m));
  if (!(s.support_radius > 0) || !(s.specimen_radius > s.support_radius))
    throw InputError("data term: need 0 < support_radius < specimen_radius");
}

// A draw's parameters and velocities fit the lane's model (InputError naming what does not).
void check_draw(const Model& model, const SampleDraw& draw) {
  model.validate_parameters(draw.parameters);
  if (draw.velocities0.size() && draw.velocities0.size() != model.num_dofs())
    throw InputError("sample loop: velocities0 must have " + std::to_string(model.num_dofs()) + " values");
}

const Eigen::VectorXd* velocities_of(const SampleDraw& draw) {
  return draw.velocities0.size() ? &draw.velocities0 : nullptr;
}

// The positions the renderer sees: x through the active effects' measurement transforms.
Eigen::VectorXd observed(const Model& model, const Eigen::VectorXd& x, const Eigen::VectorXd& p) {
  return model.has_observation() ? model.observe(x, p) : x;
}

Eigen::Map<const MatrixX3d> as_rows(const Eigen::VectorXd& x) { return {x.data(), x.size() / 3, 3}; }

}  // namespace

double silhouette_data_term(const Image& image, const SilhouetteTarget& target, const DataTermSettings& s,
                            Image* grad_image) {
  check_settings(s);
  if (image.rows() != target.mask.rows() || image.cols() != target.mask.cols())
    throw InputError("data term: the image is " + std::to_string(image.rows()) + " x " + std::to_string(image.cols()) +
                     " pixels, the silhouette " + std::to_string(target.mask.rows()) + " x " +
                     std::to_string(target.mask.cols()));
  if (image.size() == 0) throw InputError("data term: empty image");
  const double n = static_cast<double>(image.size());
  const double s2 = s.sigma_obs * s.sigma_obs;
  Image diff = image - target.mask;
  double data = diff.square().sum() / n / (2 * s2);
  if (grad_image) *grad_image = diff / (s2 * n);
  if (s.sigma_dc > 0) {
    // the soft silhouette's shadow area is its summed coverage; d DC / d area = 1 / (specimen - disk area)
    const double span = kPi * s.specimen_radius * s.specimen_radius - kPi * s.support_radius * s.support_radius;
    const double px2 = s.px_per_m * s.px_per_m;
    const double dc = drape_coefficient(image.sum() / px2, CusickGeometry{s.specimen_radius, s.support_radius});
    const double r = dc - s.dc_bias - target.drape_coefficient;
    const double sd2 = s.sigma_dc * s.sigma_dc;
    data += r * r / (2 * sd2);
    if (grad_image) *grad_image += r / sd2 / (px2 * span);
  }
  return data;
}

struct SampleLoop::Lane {
  Lane(std::shared_ptr<const Model> m, const Camera& camera, SoftRasterOptions render)
      : model(std::move(m)), rollout(*model), statics(*model), renderer(camera, render) {}
  std::shared_ptr<const Model> model;
  ImplicitEuler rollout;
  StaticSolver statics;
  SoftRasterizer renderer;
};

SampleLoop::SampleLoop(std::vector<std::shared_ptr<const Model>> lane_models, const Camera& camera,
                       SoftRasterOptions render, DrapeSettings drape)
    : drape_(drape) {
  if (lane_models.empty()) throw InputError("sample loop: needs at least one lane (model)");
  for (const auto& m : lane_models) {
    if (!m) throw InputError("sample loop: a lane's model is missing");
    if (m->num_dofs() != lane_models[0]->num_dofs() || m->layout().size() != lane_models[0]->layout().size())
      throw InputError("sample loop: every lane's model must have the same mesh and parameter layout");
    lanes_.push_back(std::make_unique<Lane>(m, camera, render));
  }
}

SampleLoop::~SampleLoop() = default;

void SampleLoop::forget_warm_starts() {
  std::lock_guard<std::mutex> lock(warm_mutex_);
  warm_.clear();
}

std::map<int, Eigen::VectorXd> SampleLoop::warm_starts() const {
  std::lock_guard<std::mutex> lock(warm_mutex_);
  return warm_;
}

void SampleLoop::set_warm_starts(std::map<int, Eigen::VectorXd> warm) {
  const Eigen::Index n = lanes_.front()->model->num_dofs();
  for (const auto& [slot, x] : warm)
    if (x.size() != n || !x.allFinite())
      throw InputError("sample loop: warm start " + std::to_string(slot) + " must be " + std::to_string(n) +
                       " finite values");
  std::lock_guard<std::mutex> lock(warm_mutex_);
  warm_ = std::move(warm);
}

RolloutOptions SampleLoop::rollout_options(bool record) const {
  RolloutOptions o = drape_.rollout;
  o.record = record;
  return o;
}

Eigen::VectorXd SampleLoop::drape(Lane& lane, const SampleDraw& draw, ProgressSink* sink) {
  if (!drape_.static_mode)
    return lane.rollout.forward(draw.parameters, rollout_options(true), sink, nullptr, velocities_of(draw));
  const RolloutOptions settle = rollout_options(false);
  Eigen::VectorXd start;
  {
    std::lock_guard<std::mutex> lock(warm_mutex_);
    auto it = warm_.find(draw.slot);
    if (it != warm_.end()) start = it->second;
  }
  if (start.size() == 0)  // first solve of this slot: the paper's rollout from flat, then Newton to rest
    start = lane.rollout.forward(draw.parameters, settle, sink);
  Eigen::VectorXd x;
  try {
    x = lane.statics.solve(draw.parameters, drape_.statics, sink, &start).positions;
  } catch (const SolverError&) {
    // Folds rearranging: let the drape move for a while from the warm state, then retry with a larger
    // iteration allowance; a second failure is reported.
    const Eigen::VectorXd moved = lane.rollout.forward(draw.parameters, settle, sink, &start);
    StaticOptions more = drape_.statics;
    more.max_iterations *= 3;
    x = lane.statics.solve(draw.parameters, more, sink, &moved).positions;
  }
  std::lock_guard<std::mutex> lock(warm_mutex_);
  warm_[draw.slot] = x;
  return x;
}

SampleOutcome SampleLoop::run_draw(Lane& lane, const SampleDraw& draw, const SilhouetteTarget& target,
                                   const DataTermSettings& data, ProgressSink* sink) {
  const Model& model = *lane.model;
  check_draw(model, draw);
  const Eigen::VectorXd x = drape(lane, draw, sink);
  SampleOutcome out;
  out.image = lane.renderer.forward(as_rows(observed(model, x, draw.parameters)), model.mesh().faces);
  Image g_image;
  out.data = silhouette_data_term(out.image, target, data, &g_image);
  const MatrixX3d g_seen_m = lane.renderer.backward(g_image);
  const Eigen::VectorXd g_seen = Eigen::Map<const Eigen::VectorXd>(g_seen_m.data(), g_seen_m.size());
  Eigen::VectorXd g_x = g_seen, g_direct = Eigen::VectorXd::Zero(draw.parameters.size());
  if (model.has_observation()) {
    g_x.setZero();
    model.add_observe_vjp(x, draw.parameters, g_seen, g_x, g_direct);
  }
  out.gradient = drape_.static_mode ? lane.statics.adjoint(g_x) : lane.rollout.backward(g_x, nullptr, sink).parameters;
  out.gradient += g_direct;
  return out;
}

template <class F>
void SampleLoop::for_each_draw(int n, ProgressSink* progress, F&& f) {
  if (n == 0) return;
  if (progress && progress->cancelled()) throw Cancelled();
  std::atomic<bool> stop{false};
  std::atomic<int> done{0};
  std::mutex progress_mutex;
  // Polled at every solver step of every lane: another lane failed, or the caller cancelled.
  auto poll = [&](bool finished_draw) {
    if (stop.load()) throw Cancelled();
    if (!progress) return;
    std::lock_guard<std::mutex> lock(progress_mutex);
    const int d = finished_draw ? ++done : done.load();
    progress->step(d, n);
  };
  const int L = std::min(lanes(), n);
  std::vector<std::exception_ptr> errors(L);
  auto work = [&](int l) {
    try {
      ProgressSink sink([&](int, int) { poll(false); });
      for (int i = l; i < n; i += L) {
        poll(false);
        f(*lanes_[l], i, &sink);
        poll(true);
      }
    } catch (...) {
      errors[l] = std::current_exception();
      stop.store(true);
    }
  };
  std::vector<std::thread> threads;
  for (int l = 1; l < L; ++l) threads.emplace_back(work, l);
  work(0);
  for (auto& t : threads) t.join();
  // The first lane's own failure (not the Cancelled it caused in the others), else a cancellation.
  std::exception_ptr cancelled;
  for (const auto& e : errors) {
    if (!e) continue;
    try {
      std::rethrow_exception(e);
    } catch (const Cancelled&) {
      if (!cancelled) cancelled = e;
    } catch (...) {
      throw;
    }
  }
  if (cancelled) std::rethrow_exception(cancelled);
}

namespace {

void check_targets(const std::vector<SilhouetteTarget>& targets) {
  if (targets.empty()) throw InputError("sample loop: no target silhouettes");
}

}  // namespace

std::vector<SampleOutcome> SampleLoop::run(const std::vector<SampleDraw>& draws,
                                           const std::vector<SilhouetteTarget>& targets,
                                           const DataTermSettings& data, ProgressSink* progress) {
  check_settings(data);
  check_targets(targets);
  for (size_t i = 0; i < draws.size(); ++i)
    if (draws[i].target < 0 || draws[i].target >= static_cast<int>(targets.size()))
      throw InputError("sample loop: draw " + std::to_string(i) + " names silhouette " +
                       std::to_string(draws[i].target) + " of " + std::to_string(targets.size()));
  std::vector<SampleOutcome> out(draws.size());
  for_each_draw(static_cast<int>(draws.size()), progress, [&](Lane& lane, int i, ProgressSink* sink) {
    out[i] = run_draw(lane, draws[i], targets[draws[i].target], data, sink);
  });
  return out;
}

Image SampleLoop::hard_image(const Lane& lane, const Eigen::VectorXd& x, const Eigen::VectorXd& p) const {
  return hard_silhouette(lane.renderer.camera(), as_rows(observed(*lane.model, x, p)), lane.model->mesh().faces);
}

std::vector<double> SampleLoop::score_draw(Lane& lane, const SampleDraw& draw,
                                           const std::vector<SilhouetteTarget>& targets,
                                           const DataTermSettings& data, ProgressSink* sink) {
  const Model& model = *lane.model;
  check_draw(model, draw);
  Eigen::VectorXd x;
  try {
    x = lane.rollout.forward(draw.parameters, rollout_options(false), sink, nullptr, velocities_of(draw));
  } catch (const SolverError&) {
    return std::vector<double>(targets.size(), std::numeric_limits<double>::infinity());
  }
  const Image hard = hard_image(lane, x, draw.parameters);
  std::vector<double> out;
  for (const auto& t : targets) out.push_back(silhouette_data_term(hard, t, data));
  return out;
}

std::vector<std::vector<double>> SampleLoop::score(const std::vector<SampleDraw>& draws,
                                                   const std::vector<SilhouetteTarget>& targets,
                                                   const DataTermSettings& data, ProgressSink* progress) {
  check_settings(data);
  check_targets(targets);
  std::vector<std::vector<double>> out(draws.size());
  for_each_draw(static_cast<int>(draws.size()), progress, [&](Lane& lane, int i, ProgressSink* sink) {
    out[i] = score_draw(lane, draws[i], targets, data, sink);
  });
  return out;
}

std::vector<SampleLoop::Predicted> SampleLoop::predict(const std::vector<SampleDraw>& draws,
                                                       ProgressSink* progress) {
  std::vector<Predicted> out(draws.size());
  for_each_draw(static_cast<int>(draws.size()), progress, [&](Lane& lane, int i, ProgressSink* sink) {
    const SampleDraw& draw = draws[i];
    check_draw(*lane.model, draw);
    Eigen::VectorXd x;
    try {
      x = drape_.static_mode
              ? lane.statics.solve(draw.parameters, drape_.statics, sink).positions
              : lane.rollout.forward(draw.parameters, rollout_options(false), sink, nullptr, velocities_of(draw));
    } catch (const SolverError& e) {
      out[i].error = e.what();
      return;
    }
    out[i].image = hard_image(lane, x, draw.parameters);
    out[i].positions = std::move(x);
  });
  return out;
}

}  // namespace drapelab::infer
