// Effect "bending_anisotropy": the fabric bends more stiffly along one direction of the weave than the preset's
// table says (a weave or finish whose warp and weft differ more than one photo can show; the real photos of
// fabrics 1 and 4 are 4.5-6.5 mm longer along one axis, where the presets drape round: docs/lab/orientation.md).
// Each bending edge's energy is multiplied by
//   m(beta) = exp(cos2 cos(2 beta) + sin2 sin(2 beta))
// where beta is the edge's angle in the rest pattern from +u (the weft) towards +v (the warp), signed (an edge
// and its reverse give the same factor). cos2 > 0: edges lying along the weft are stiffer, those along the warp
// softer, by exp(2 cos2) from one to the other; sin2 turns the stiff axis to the diagonals. A rotation-free pair:
// the stiff axis lies at atan2(sin2, cos2) / 2 from the weft and the warp/weft ratio is exp(2 |(cos2, sin2)|).
// The log factor averages to 0 over directions (the geometric mean of the stiffness over directions is kept).
// Not an added energy: a multiplier inside the bend term (physics/base_term_changes.hpp), exact in positions, the
// bending table and the coefficients, like heterogeneity_map's spatial field; m = 1 exactly at the off value.
#include <cmath>

#include "physics/effect.hpp"
#include "physics/model.hpp"

namespace drapelab {
namespace {

constexpr const char* kName = "bending_anisotropy";

}  // namespace

EffectSpec make_bending_anisotropy_effect() {
  EffectSpec s;
  s.name = kName;
  s.explanation =
      "the bending stiffness depends on the direction in the weave more than the preset's table says: a 2-fold "
      "log factor over the bending edges' directions multiplies their energy";
  s.signature =
      "a 2-fold r(theta) residual: the drape is longer across the stiff direction (cos2 > 0: longer along the "
      "warp, y), its axis set by sin2; the drape coefficient stays within noise";
  // Moderate strength measured on circle3 (docs/physics.md#bending_anisotropy).
  s.parameters = {
      {"cos2", "1", 0.0, -1.5, 1.5, 0.75, 0.75,
       "log bending factor of edges along the weft against the mean; along the warp its negative"},
      {"sin2", "1", 0.0, -1.5, 1.5, 0.75, 0.75, "log bending factor of edges along the +45 degree diagonal"},
  };
  // Near zero strength either parameter mainly turns the fold pattern (docs/lab/bending-anisotropy.md); the 2-fold
  // appears at a finite strength, along an axis set by both: the step test tries the four axes 0, 45, 90, 135 deg.
  s.step_parameters = {"cos2", "sin2"};
  s.make_terms = [](const EffectContext&) { return std::vector<std::unique_ptr<Term>>{}; };
  s.change_base_terms = [](const EffectContext& c, BaseTermChanges& changes) {
    std::vector<double> phi_c, phi_s;
    phi_c.reserve(c.bending_edges.size());
    phi_s.reserve(c.bending_edges.size());
    for (const BendingEdge& be : c.bending_edges) {
      const Eigen::Vector2d du = pattern_edge(c.mesh, be);  // as the bend term reads it
      const double L2 = du.squaredNorm();
      // cos(2 beta) = (du_x^2 - du_y^2) / L^2, sin(2 beta) = 2 du_x du_y / L^2: no angle, no branch.
      phi_c.push_back(L2 > 0 ? (du.x() * du.x() - du.y() * du.y()) / L2 : 0.0);
      phi_s.push_back(L2 > 0 ? 2.0 * du.x() * du.y() / L2 : 0.0);
    }
    changes.bend.add(c.layout.block(effect_block_name(kName, "cos2")).offset, std::move(phi_c));
    changes.bend.add(c.layout.block(effect_block_name(kName, "sin2")).offset, std::move(phi_s));
  };
  return s;
}

}  // namespace drapelab
