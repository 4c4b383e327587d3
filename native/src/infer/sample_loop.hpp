// The Monte Carlo draws of one fit epoch, on threads (DESIGN.md infer/: "Monte Carlo samples on threads").
//
// A draw is a parameter vector (the material tables and effect values the variational family sampled), the
// placement velocities of its rollout and the training silhouette it is compared with. For each draw a lane
// drapes the cloth (a recorded rollout, or a warm-started static solve), renders the soft silhouette of the
// observed positions (the active effects' measurement transforms), evaluates the data term against the
// silhouette and back-propagates it to the parameters:
//
//   data = mean_pixels (I - M)^2 / (2 sigma_obs^2) + (DC(I) - b - DC_M)^2 / (2 sigma_dc^2)
//
// (no DC term when sigma_dc = 0), DC(I) = (sum(I) / px^2 - pi r_s^2) / (pi R^2 - pi r_s^2) the soft drape
// coefficient (support radius r_s, specimen radius R), b the soft-minus-hard bias the fit holds constant.
// dL/dp = adjoint(dL/dx through the observation) + the observation's direct parameter gradient.
//
// Static mode: a slot (one Monte Carlo position of the epoch) keeps its last equilibrium as the next epoch's
// start, so results do not depend on which lane ran it; the first solve starts from an unrecorded rollout from
// flat, and a failed solve (folds rearranging) lets the drape move for one rollout from its start and retries
// with three times the iterations; a second failure is reported.
//
// Lanes run on threads (the first on the calling one); draws are dealt round-robin (draw i to lane i mod L).
// A lane's failure (SolverError, InputError) stops the other lanes at their next solver step and is rethrown;
// progress->step(draws done, draws) is called after every draw and polled at every solver step (cancel).
//
// score() is the start searches' forward-only variant: hard silhouettes of unrecorded rollouts, no gradient.
#pragma once
#include <Eigen/Core>

#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "physics/model.hpp"
#include "render/camera.hpp"
#include "render/soft_rasterizer.hpp"
#include "solver/implicit_euler.hpp"
#include "solver/static_solve.hpp"
#include "util/image.hpp"
#include "util/progress.hpp"

namespace drapelab::infer {

// One training silhouette: the hard mask (0/1) and its drape coefficient.
struct SilhouetteTarget {
  Image mask;
  double drape_coefficient = 0;
};

struct DataTermSettings {
  double sigma_obs = 0.1;         // pixel noise scale (> 0)
  double sigma_dc = 0;            // drape-coefficient noise scale (0: no DC term)
  double dc_bias = 0;             // soft minus hard drape coefficient, held constant
  double px_per_m = 720;          // the silhouettes' scale
  double support_radius = 0.09;   // m
  double specimen_radius = 0.15;  // m
};

// The data term of an image (soft or hard) against a target; its gradient per pixel in *grad_image when given.
double silhouette_data_term(const Image& image, const SilhouetteTarget& target, const DataTermSettings& settings,
                            Image* grad_image = nullptr);

struct DrapeSettings {
  bool static_mode = false;   // false: a recorded rollout (with the draw's velocities); true: warm-started statics
  RolloutOptions rollout;     // record is set by the loop
  StaticOptions statics;
};

struct SampleDraw {
  Eigen::VectorXd parameters;   // the model's layout
  Eigen::VectorXd velocities0;  // initial velocities (3V) of the rollout; empty: at rest
  int target = 0;               // index into the targets
  int slot = 0;                 // warm-start slot (static mode)
};

struct SampleOutcome {
  double data = 0;
  Eigen::VectorXd gradient;  // dL/dparameters (layout)
  Image image;               // the soft silhouette
};

class SampleLoop {
 public:
  // One lane per model (each with its own solvers and renderer); every model must have the same mesh and layout.
  SampleLoop(std::vector<std::shared_ptr<const Model>> lane_models, const Camera& camera, SoftRasterOptions render,
             DrapeSettings drape);
  ~SampleLoop();

  std::vector<SampleOutcome> run(const std::vector<SampleDraw>& draws, const std::vector<SilhouetteTarget>& targets,
                                 const DataTermSettings& data, ProgressSink* progress = nullptr);

  // The start searches' scores: per draw and target, the data term of the hard silhouette of the draw's unrecorded
  // rollout from flat (with its velocities; static mode too), seen through the observation; +inf for every target
  // when the rollout fails (SolverError). No gradient, no warm start.
  std::vector<std::vector<double>> score(const std::vector<SampleDraw>& draws,
                                         const std::vector<SilhouetteTarget>& targets, const DataTermSettings& data,
                                         ProgressSink* progress = nullptr);

  // Posterior-predictive drapes (evaluation, calibration): per draw, the positions and the hard silhouette (seen
  // through the observation) of its unrecorded rollout from flat with its velocities, or in static mode of the
  // equilibrium reached from the flat rest state (no warm start, no retry); a failed drape (SolverError) gives its
  // message in `error` and no positions.
  struct Predicted {
    Eigen::VectorXd positions;
    Image image;
    std::string error;
  };
  std::vector<Predicted> predict(const std::vector<SampleDraw>& draws, ProgressSink* progress = nullptr);

  // Drops the static warm starts (after a rejected step, whose equilibria belong to other tables).
  void forget_warm_starts();
  int lanes() const { return static_cast<int>(lanes_.size()); }
  // The warm starts (slot -> equilibrium, 3V) and their replacement (e.g. to repeat an epoch from the same
  // starts in a finite-difference check).
  std::map<int, Eigen::VectorXd> warm_starts() const;
  void set_warm_starts(std::map<int, Eigen::VectorXd> warm);

 private:
  struct Lane;
  SampleOutcome run_draw(Lane& lane, const SampleDraw& draw, const SilhouetteTarget& target,
                         const DataTermSettings& data, ProgressSink* sink);
  Eigen::VectorXd drape(Lane& lane, const SampleDraw& draw, ProgressSink* sink);
  RolloutOptions rollout_options(bool record) const;
  // The hard silhouette of positions x seen through the observation of parameters p.
  Image hard_image(const Lane& lane, const Eigen::VectorXd& x, const Eigen::VectorXd& p) const;
  std::vector<double> score_draw(Lane& lane, const SampleDraw& draw, const std::vector<SilhouetteTarget>& targets,
                                 const DataTermSettings& data, ProgressSink* sink);
  // f(lane, draw index, lane's sink) for every draw, dealt round-robin over the lanes on threads (see above).
  template <class F>
  void for_each_draw(int n, ProgressSink* progress, F&& f);

  std::vector<std::unique_ptr<Lane>> lanes_;
  DrapeSettings drape_;
  std::map<int, Eigen::VectorXd> warm_;
  mutable std::mutex warm_mutex_;
};

}  // namespace drapelab::infer
