// Effect "heterogeneity_map": the bending stiffness varies smoothly over the specimen (uneven finishing,
// moisture, a batch gradient). Each bending edge's energy is multiplied by the field
//   m(X) = exp(radial rho + cos1 rho cos(t) + sin1 rho sin(t) + cos2 rho^2 cos(2 t) + sin2 rho^2 sin(2 t))
// at the edge's rest midpoint X = rho R (cos t, sin t) (R the specimen radius, the largest rest radius of the
// mesh; t from +x, the weft, towards +y, the warp): low-order harmonic polynomials, smooth over the whole disk,
// equal to the angular modes cos(k t), sin(k t) at the rim. Each coefficient is a natural-log amplitude [1]:
// at the rim, cos2 = 0.3 makes bending 35 % stiffer along x and y than at 45 degrees. m = 1 exactly at the off
// value (all coefficients 0), and m > 0 always (the bending step matrix stays PSD).
// Not an added energy: a multiplier inside the bend term (physics/base_term_changes.hpp), exact in positions,
// the bending table and the coefficients (E_w -> m_w E_w; dE_w/dc_k = phi_k(X_w) m_w E_w). Stretching is not
// modulated (the optional part).
#include <cmath>

#include "physics/effect.hpp"
#include "physics/model.hpp"

namespace drapelab {
namespace {

constexpr const char* kName = "heterogeneity_map";

// The modes' values at rest position (u, v) / R, in the order of the parameters.
double mode_value(int k, double x, double y) {
  switch (k) {
    case 0: return std::hypot(x, y);  // radial: rho
    case 1: return x;                  // cos1: rho cos t
    case 2: return y;                  // sin1: rho sin t
    case 3: return x * x - y * y;      // cos2: rho^2 cos 2t
    default: return 2.0 * x * y;       // sin2: rho^2 sin 2t
  }
}

}  // namespace

EffectSpec make_heterogeneity_map_effect() {
  EffectSpec s;
  s.name = kName;
  s.explanation =
      "the bending stiffness varies smoothly over the specimen: a log field of low-order angular (1- and 2-fold) "
      "and radial modes multiplies each bending edge's energy";
  s.signature =
      "radial > 0 (stiffer towards the rim): the drape coefficient rises, as with a stiffer material; angular "
      "modes: the drape coefficient stays, the folds move towards the softer side (1-fold) or axis (2-fold), a "
      "1- or 2-fold r(theta) residual";
  // Moderate strengths, measured on circle3 (Cotton Blue tables, 100 x 0.05 s rollout; re-drape noise floor 0.031
  // in drape coefficient): radial 0.4 moves DC by +0.055 (1.8x; -0.4: -0.078, 2.5x), pixel MSE 0.03-0.04 against
  // the base drape. The angular modes leave DC within 0.004 and at 0.5 move the silhouette by MSE 0.023 (cos1),
  // 0.022 (sin1), 0.015 (cos2), 0.019 (sin2) (at 0.7: 0.021-0.040, but all five at 0.5-1x their moderate at once,
  // as the FD suite draws them, then reach bending below 1/4 near the rim, where the base rollout's known
  // limp-fabric divergence starts: 3 of 10 draws diverged with 0.7, 2 of 14 with 0.5). All five at moderate
  // together: DC +0.048, MSE 0.033.
  // radial first: the primary parameter (`heterogeneity_map=VALUE`) is the mode a drape identifies best (it
  // moves the drape coefficient); the angular modes mostly move where the folds fall.
  s.parameters = {
      {"radial", "1", 0.0, -1.5, 1.5, 0.3, 0.4, "log bending factor growing linearly with the rest radius, rho"},
      {"cos1", "1", 0.0, -1.5, 1.5, 0.4, 0.5, "log bending factor at the rim along +x (weft), rho cos t"},
      {"sin1", "1", 0.0, -1.5, 1.5, 0.4, 0.5, "log bending factor at the rim along +y (warp), rho sin t"},
      {"cos2", "1", 0.0, -1.5, 1.5, 0.4, 0.5, "log bending factor at the rim on the x and y axes, rho^2 cos 2t"},
      {"sin2", "1", 0.0, -1.5, 1.5, 0.4, 0.5, "log bending factor at the rim on the diagonals, rho^2 sin 2t"},
  };
  s.make_terms = [](const EffectContext&) { return std::vector<std::unique_ptr<Term>>{}; };
  s.change_base_terms = [](const EffectContext& c, BaseTermChanges& changes) {
    double R = 0;
    for (int i = 0; i < c.mesh.num_vertices(); ++i) R = std::max(R, c.mesh.uv.row(i).norm());
    const char* names[5] = {"radial", "cos1", "sin1", "cos2", "sin2"};
    for (int k = 0; k < 5; ++k) {
      std::vector<double> phi;
      phi.reserve(c.bending_edges.size());
      for (const BendingEdge& be : c.bending_edges) {
        const Eigen::RowVector2d X = 0.5 * (c.mesh.uv.row(be.a) + c.mesh.uv.row(be.b)) / R;
        phi.push_back(mode_value(k, X[0], X[1]));
      }
      changes.bend.add(c.layout.block(effect_block_name(kName, names[k])).offset, std::move(phi));
    }
  };
  return s;
}

}  // namespace drapelab
