// Effect "high_curvature_bending": the fabric bends more easily (or more stiffly) in sharp folds than the preset's
// bending table says. The table holds the stiffness at curvatures 0..10 /m (physics/bend.hpp: five columns
// kBendSampleCurvature apart) and keeps its last column beyond; the real drapes' fold crests reach 27-34 /m
// (docs/lab/fold-depth.md, "In 3D"), where a woven fabric's yarns slip and its bending stiffness falls
// (the friction couple of Grosberg's bending model: a stiff start, then a softer slope). Each bending edge's
// energy is multiplied by
//   M = exp(log_factor s(alpha)),  s = smoothstep(ln(alpha / 10 /m) / ln(80 /m / 10 /m)) clamped to [0, 1]
// where alpha is the edge's curvature measure as the table reads it: M = 1 inside the table's range and
// exp(log_factor) from 80 /m on. log_factor < 0: softer crests, the folds can sharpen and deepen. The lower bound
// -0.9 keeps the energy convex in the angle (E'' > 0: the moment rises with curvature, a softer slope and never a
// snap that would kink the cloth; base_term_changes.hpp): how fast the factor may fall is bounded by the ramp's
// length in log curvature, so the ramp is long (a factor 8) and reaches about 0.2 of log_factor at 17 /m and 0.7 at
// 38 /m, the drapes' crests.
// Not an added energy: a factor inside the bend term (physics/base_term_changes.hpp, CurvatureFactor), exact in
// positions, the table, and log_factor in every kernel; M = 1 exactly at the off value.
#include "physics/bend.hpp"
#include "physics/effect.hpp"
#include "physics/model.hpp"

namespace drapelab {
namespace {

constexpr const char* kName = "high_curvature_bending";
constexpr double kStartCurvature = 4 * kBendSampleCurvature;  // 1/m: the table's last column
constexpr double kFullCurvature = 80.0;                       // 1/m: the change complete (convexity, above)

}  // namespace

EffectSpec make_high_curvature_bending_effect() {
  EffectSpec s;
  s.name = kName;
  s.explanation =
      "the bending stiffness changes in sharp folds, beyond the curvatures the preset's table holds (yarns slip "
      "in a tight fold): a factor exp(log_factor) on the bending energy from 80 /m, ramped from none at 10 /m";
  s.signature =
      "softer (log_factor < 0): sharper fold crests and deeper folds, the nodes' amplitude grows at about the "
      "same node count; the drape coefficient changes little";
  // Moderate strength: docs/physics.md#high_curvature_bending.
  s.parameters = {
      {"log_factor", "1", 0.0, -0.9, 1.5, 0.5, -0.6,
       "log of the bending stiffness factor at curvatures of 80 /m and more (0 below 10 /m)"},
  };
  s.make_terms = [](const EffectContext&) { return std::vector<std::unique_ptr<Term>>{}; };
  s.change_base_terms = [](const EffectContext& c, BaseTermChanges& changes) {
    changes.bend_curvature.indices.push_back(c.layout.block(effect_block_name(kName, "log_factor")).offset);
    changes.bend_curvature.start = kStartCurvature;
    changes.bend_curvature.full = kFullCurvature;
  };
  return s;
}

}  // namespace drapelab
