// Effect "prestrain": relaxation shrinkage. The fabric's rest lengths are shorter than the cut specimen's by
// the strains s_weft = strain - warp_minus_weft / 2 (along u = x) and s_warp = strain + warp_minus_weft / 2
// (along v = y) [1]: the rest pattern is scaled, u -> (1 - s_weft) u, v -> (1 - s_warp) v, so the flat
// specimen the drape starts from is under tension (strain > 0) and contracts as it drapes. In the stretching
// energy (physics/stretch.hpp) this is
//   F = Ds Dm^-1 diag(1 / (1 - s_weft), 1 / (1 - s_warp)),   E_j = (1 - s_weft)(1 - s_warp) A_j W(eps(F))   [J]
// (the strain energy per rest area, over the shrunk rest area). The masses and the bending rest data keep the
// cut specimen's values: the mass is what the specimen weighs, and the bending term reads lengths only through
// its stiffness scale L / (h1 + h2), which a uniform shrink leaves unchanged (an anisotropic one changes it
// by less than |warp_minus_weft|, neglected).
// Not an added energy: a change inside the stretch term (physics/base_term_changes.hpp), exactly the base term
// at strain = warp_minus_weft = 0 (the scaling factors are exactly 1), with exact derivatives in the strains.
#include "physics/effect.hpp"
#include "physics/model.hpp"

namespace drapelab {

EffectSpec make_prestrain_effect() {
  EffectSpec s;
  s.name = "prestrain";
  s.explanation =
      "relaxation shrinkage: the rest lengths are shorter than the cut specimen by a strain common to warp and "
      "weft plus a warp-weft difference, so the flat specimen starts under tension";
  s.signature =
      "shrinkage (strain > 0): the skirt contracts towards the disk, the drape coefficient rises and folds become "
      "fewer and shallower; warp_minus_weft: a 2-fold r(theta) residual, shorter along the more shrunk direction";
  // Moderate strengths: see docs/physics.md (prestrain) for the measured silhouette change.
  s.parameters = {
      {"strain", "1", 0.0, -0.05, 0.1, 0.02, 0.03, "shrinkage common to warp and weft (positive: rest lengths shorter)"},
      {"warp_minus_weft", "1", 0.0, -0.1, 0.1, 0.02, 0.03, "shrinkage along the warp (y) minus along the weft (x)"},
  };
  s.make_terms = [](const EffectContext&) { return std::vector<std::unique_ptr<Term>>{}; };
  s.change_base_terms = [](const EffectContext& c, BaseTermChanges& changes) {
    const int strain = c.layout.block(effect_block_name("prestrain", "strain")).offset;
    const int difference = c.layout.block(effect_block_name("prestrain", "warp_minus_weft")).offset;
    changes.stretch_rest.add(strain, 1.0, 1.0);
    changes.stretch_rest.add(difference, -0.5, 0.5);
  };
  return s;
}

}  // namespace drapelab
