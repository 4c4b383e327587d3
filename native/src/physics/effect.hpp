// Optional physical effects as plug-ins: one registry that the model, the bindings, the Python facade,
// presets, the CLI and the finite-difference suite all read.
//
// An effect is one file in native/src/effects/ that defines `EffectSpec make_<name>_effect()` plus one line
// `DRAPELAB_EFFECT(<name>)` in native/src/effects/effect_list.hpp. Its spec names the effect, explains it in
// one line, says which signature it predicts on a drape, lists its parameters (name with unit suffix, unit,
// off value, bounds, prior scale for fitting, a moderate strength) and builds the term(s) it adds.
//
// Parameters live in the model's flat vector as one block per parameter, named "<effect>.<parameter>"
// (e.g. "tilt.angle_rad"), after the base blocks and in registry order. An effect that is not active adds
// no block and no term: the base model is bit-for-bit unchanged. An active effect at its off values adds
// exactly zero energy and force (checked for every registered effect by tests/native/physics/test_effects.cpp).
#pragma once
#include <functional>
#include <limits>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "geometry/mesh.hpp"
#include "physics/base_term_changes.hpp"
#include "physics/parameters.hpp"
#include "physics/term.hpp"

namespace drapelab {

struct ModelOptions;

struct EffectParameter {
  std::string name;  // carries its unit: angle_rad, azimuth_rad, dx_m, strain
  std::string unit;  // "rad", "m", "1" (a fraction), ...
  double off = 0;    // the value at which the effect reduces to the base model
  double lower = -std::numeric_limits<double>::infinity();  // inclusive bounds (infinite: signed, unbounded)
  double upper = std::numeric_limits<double>::infinity();
  double prior_scale = 1;  // prior standard deviation when fitted, in the unit
  double moderate = 0;     // a moderate strength (synth data and tests), in the unit
  std::string description;
  // Structural: the value chooses the model's structure (which vertices a clamp holds), so it is read from
  // ModelOptions::effects when the model is built; a parameter vector must carry that same value, and fits hold
  // it fixed (a genuine switch for the diagnosis: CONVENTIONS.md).
  bool structural = false;
};

// What an effect's factory may read of the model being built (rest state, topology, the layout with the
// effect's own blocks already added).
struct EffectContext {
  const TriangleMesh& mesh;
  const std::vector<BendingEdge>& bending_edges;
  const Eigen::VectorXd& area_weights;  // m^2 per vertex
  const std::vector<int>& handle_vertices;
  const ParameterLayout& layout;
  const ModelOptions& options;
};

// A transform of positions before the silhouette render (the measurement model: `camera`; the tester's frame:
// `offset`), y = T(x; p), vertex by vertex (3V -> 3V). Active effects' transforms compose in registry order
// (Model::observe). At the effect's off values T is the identity bit for bit. `add_vjp` adds the
// vector-Jacobian products g_y^T dT/dx to g_x and g_y^T dT/dp to g_p (exact; tests/native/physics/test_effects.cpp
// checks them against central differences for every effect that has one).
class PositionTransform {
 public:
  virtual ~PositionTransform() = default;
  virtual void apply(const Eigen::VectorXd& x, const Eigen::VectorXd& p, Eigen::VectorXd& y) const = 0;
  virtual void add_vjp(const Eigen::VectorXd& x, const Eigen::VectorXd& p, const Eigen::VectorXd& gy,
                       Eigen::VectorXd& gx, Eigen::VectorXd& gp) const = 0;
};

struct EffectSpec {
  std::string name;
  std::string explanation;  // one plain line: what physical cause it models
  std::string signature;    // what it does to a drape's silhouette (for the diagnosis)
  std::vector<EffectParameter> parameters;  // the first is the primary one
  std::function<std::vector<std::unique_ptr<Term>>(const EffectContext&)> make_terms;
  // Optional: changes inside the base terms (rest shape, a stiffness field; physics/base_term_changes.hpp) for
  // effects that are not an added energy. Called before the base terms are built; empty for most effects.
  std::function<void(const EffectContext&, BaseTermChanges&)> change_base_terms;
  // True for an effect that acts only over a dynamic rollout's time steps (damping): a static drape is the same
  // with or without it (its terms are zero at h = 0), and sim's static simulate says so.
  bool dynamic_only = false;
  // Optional: the transform of positions the effect applies before the silhouette render (see
  // PositionTransform); empty for effects that change only the physics.
  std::function<std::unique_ptr<PositionTransform>(const EffectContext&)> make_observation;
  // Optional: values of other (direction) parameters under which the diagnosis scores the primary parameter a
  // second time, for an effect whose direction has no gradient at the off values (a tilt's azimuth at zero
  // angle: scored at azimuth 0 and again at pi/2, so that every direction is seen). Still the base model, the
  // primary being off. Each value lies inside its parameter's bounds (tests/native/physics/test_effects.cpp).
  std::map<std::string, double> second_direction;
  // Optional: the parameters the diagnosis's step test steps (each at +- its moderate strength, the others off);
  // empty: the primary alone. An effect whose finite-strength signature has a direction set by several parameters
  // (bending_anisotropy's 2-fold axis, an offset's direction) names them all, so that the step test, and the
  // refit that starts at its best step, sees each axis (docs/diagnose.md, "Measured: directions").
  std::vector<std::string> step_parameters;
  // Optional, with two step_parameters: the step test also steps along the four diagonals of their plane (each
  // pair at +- moderate / sqrt 2), eight directions in all, for an effect whose drape changes a lot with the
  // direction (an offset 45 degrees from its nearest step was significant but not refitted: docs/diagnose.md,
  // "Measured: directions").
  bool step_diagonals = false;
  // Optional, with two step_parameters: the diagnosis's refit searches their plane on a square grid of this
  // spacing out to search_grid_reach from the off point (both in the parameters' unit) instead of a line search
  // along the best step, for an effect whose fit landscape is basins a few grid spacings wide with steps between
  // them (an offset: the hold's edge crosses vertices and the folds switch; a line search from the best step
  // missed the basin, docs/diagnose.md "Measured: the offset's grid search"). 0: the line search.
  double search_grid_spacing = 0.0;
  double search_grid_reach = 0.0;
};

// Effect name -> parameter name -> value; an effect present here is active (missing parameters take their
// off value).
using EffectValues = std::map<std::string, std::map<std::string, double>>;

// Every registered effect, in registration order.
const std::vector<EffectSpec>& effect_registry();
// The spec of `name`; InputError listing the registered names when unknown.
const EffectSpec& find_effect(const std::string& name);
// "<effect>.<parameter>": the name of the parameter's block in a model's layout.
std::string effect_block_name(const std::string& effect, const std::string& parameter);
// Throws InputError naming the effect, the parameter and the bounds when `value` is not finite or out of
// bounds, or when the parameter is unknown.
void check_effect_value(const EffectSpec& spec, const std::string& parameter, double value);

}  // namespace drapelab
