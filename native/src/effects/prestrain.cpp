// Effect "prestrain": relaxation shrinkage. The fabric's rest lengths are shorter than the cut specimen's by
// the strains s_weft = strain - warp_minus_weft / 2 (along u = x) and s_warp = strain + warp_minus_weft / 2
// (along v = y) [1]: the rest pattern is scaled, u -> (1 - s_weft) u, v -> (1 - s_warp) v, so the flat
// specimen the drape starts from is under tension (strain > 0) and contracts as it drapes. In the stretching
// energy (physics/stretch.hpp) this is
//   F = Ds Dm^-1 diag(1 / (1 - s_weft), 1 / (1 - s_warp)),   E_j = (1 - s_weft)(1 - s_warp) A_j W(eps(F))   [J]
// (the strain energy per rest area, over the shrunk rest area). The masses and the bending rest data keep the
// cut specimen's values: the mass is what the specimen weighs, and the bending term reads rest lengths through
// its scale L / (h1 + h2), which a uniform shrink leaves unchanged (an anisotropic one changes it by about
// |warp_minus_weft|), and through the curvature alpha = |sin(theta / 2)| / (h1 + h2) at which it reads its
// table, which a shrink by s moves by about s (a 3 % shift along the table's curvature axis; both neglected).
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
      "shrinkage (strain > 0): the whole skirt is smaller, so the drape coefficient falls (about -0.02 per 1 %, "
      "then a fold is lost near 3 %); warp_minus_weft: the fold pattern turns to the 2-fold anisotropy, a 2-fold "
      "r(theta) residual, shorter along the more shrunk direction";
  // Moderate strengths, measured on circle3 (Cotton Blue tables, 100 x 0.05 s rollout; re-drape noise floor 0.031
  // in drape coefficient, 0.042 in pixel MSE): strain 0.01 / 0.02 / 0.025 / 0.0275 / 0.03 move DC by -0.019 /
  // -0.038 / -0.047 / -0.054 / -0.118 (pixel MSE against the base drape 0.008 / 0.014 / 0.019 / 0.020 / 0.074:
  // between 2.75 and 3 % the drape changes its fold pattern); -0.02 / -0.03: +0.035 / +0.053. The moderate 0.03
  // lies past that jump (3.8x). warp_minus_weft changes the fold pattern at once and then saturates: 0.005 moves
  // DC by -0.020 (MSE 0.038), 0.015 / 0.02 / 0.03 by -0.044 / -0.044 / -0.046 (MSE 0.062-0.063, 1.5x the
  // re-drape MSE), either sign alike; moderate 0.02.
  s.parameters = {
      {"strain", "1", 0.0, -0.05, 0.1, 0.02, 0.03, "shrinkage common to warp and weft (positive: rest lengths shorter)"},
      {"warp_minus_weft", "1", 0.0, -0.1, 0.1, 0.02, 0.02, "shrinkage along the warp (y) minus along the weft (x)"},
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
