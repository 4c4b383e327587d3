// Effect "rest_curvature": a plastic set. The fabric's rest shape is not flat: storage folds left creases, a roll
// or a hanger left a uniform curvature. The bend term's rest dihedral angles (physics/bend.hpp, d = theta -
// theta_rest) become those of a set surface over the pattern, z(u, v) = -sum_k q_k phi_k(u, v), linearised in the
// strengths q_k (each rest angle is the angle's derivative along the surface at q = 0, times q):
//   crease_rad: two storage creases along the weft (v = 0) and warp (u = 0) diameters through the centre, each a
//     fold of total angle crease_rad smoothed over a Gaussian width sigma: phi = F(u) + F(v), F'' = the unit
//     Gaussian, so the slope across a crease turns by exactly 1 (the sum of the rest angles of the edges across
//     it is crease_rad). Positive: a ridge (the cloth falls away on both sides, like a folded-in-four specimen
//     laid with the fold up); negative: a valley.
//   dome_per_m: a uniform rest curvature [1/m], phi = (u^2 + v^2) / 2: positive is a cap (the centre up), a
//     specimen that keeps a bowl shape.
// Not an added energy: a change inside the bend term (physics/base_term_changes.hpp RestAngles), exactly the base
// term at the off values (every rest angle is 0 + sum of coefficient x 0), exact in positions, the bending table
// and these parameters (dE_w/dq_k = -a_wk E_w'(d), and the same through the gradient, the step matrix and the
// adjoints). The stretch term and the masses keep the flat pattern (a set is a bending memory, not a shrinkage).
#include <cmath>

#include "physics/bend.hpp"
#include "physics/effect.hpp"
#include "physics/model.hpp"
#include "util/jet.hpp"

namespace drapelab {
namespace {

constexpr const char* kName = "rest_curvature";
// The creases' Gaussian width: a storage fold is a few millimetres wide, but the width is at least one bending
// edge's mean rest length (so that a coarse mesh carries the fold over more than one row of edges).
constexpr double kCreaseWidth = 0.004;  // m

// F(t) with F(0) = F'(0) = 0 and F'' the Gaussian density of width sigma: F(t) = t G(t) + sigma^2 (g(t) - g(0)),
// G(t) = erf(t / (sigma sqrt 2)) / 2.
double crease_profile(double t, double sigma) {
  const double g0 = 1.0 / (sigma * std::sqrt(2.0 * M_PI));
  const double g = g0 * std::exp(-0.5 * t * t / (sigma * sigma));
  return t * 0.5 * std::erf(t / (sigma * std::sqrt(2.0))) + sigma * sigma * (g - g0);
}

// Each bending edge's rest-angle coefficient for the surface z = -phi (per unit strength): the derivative of its
// dihedral angle (BendTerm::dihedral_angle, the pattern laid flat at z = 0, counter-clockwise) at the flat pattern.
template <class Phi>
std::vector<double> rest_angle_coefficients(const EffectContext& c, Phi phi) {
  using J = Jet<double, 1>;
  std::vector<double> a;
  a.reserve(c.bending_edges.size());
  for (const BendingEdge& be : c.bending_edges) {
    const int vs[4] = {static_cast<int>(be.a), static_cast<int>(be.b), static_cast<int>(be.c),
                       static_cast<int>(be.d)};
    J x[12];
    for (int i = 0; i < 4; ++i) {
      const double u = c.mesh.uv(vs[i], 0), v = c.mesh.uv(vs[i], 1);
      x[3 * i] = J(u);
      x[3 * i + 1] = J(v);
      x[3 * i + 2] = J(0.0);
      x[3 * i + 2].v[0] = -phi(u, v);
    }
    a.push_back(BendTerm::dihedral_angle(x).v[0]);
  }
  return a;
}

}  // namespace

EffectSpec make_rest_curvature_effect() {
  EffectSpec s;
  s.name = kName;
  s.explanation =
      "a plastic set: the fabric remembers a non-flat rest shape, two storage creases along the warp and weft "
      "diameters and a uniform dome, as rest dihedral angles of the bending term";
  s.signature =
      "creases: the folds lock onto the creases' 4-fold pattern (a multiple of 4 nodes, 8 on circle3 where the "
      "material alone gives 6) and the drape coefficient rises (+0.04); a dome of either sign re-chooses the folds "
      "(more nodes) and raises the drape coefficient (+0.03 at 4 /m); both saturate once the folds have switched";
  // Moderate strengths, measured on circle3 (tools/effect_strength.py: Cotton Blue tables, 100 x 0.05 s rollout
  // from flat, no placement noise; re-drape noise floor 0.031 in drape coefficient, 0.042 in pixel MSE; the base
  // drape: DC 0.562, 6 nodes). Both parameters act by choosing the fold pattern, and the response saturates once
  // it has switched. crease_rad 0.01 / 0.02 move DC by +0.000 / -0.000 (MSE 0.004); from 0.05 the folds lock onto
  // the creases' 4-fold pattern (8 nodes): 0.05 / 0.1 / 0.25 / 0.3 / 0.5: DC +0.047 / +0.044 / +0.042 / +0.043 /
  // +0.036 (MSE 0.061-0.066); -0.1 / -0.5 (valleys): DC +0.003 / +0.032, MSE 0.091 / 0.072. Moderate 0.3 rad
  // (17 degrees, past the switch: 1.4x the DC floor, the most this effect moves DC). dome_per_m 0.5 / 1 / 2 / 3 /
  // 4 / 5: DC -0.002 / -0.007 / +0.017 / +0.014 / +0.036 / +0.033 (MSE 0.002 / 0.024 / 0.054 / 0.051 / 0.056 /
  // 0.057; 6, 6, 7, 7, 8, 8 nodes); -1 / -2 / -5: +0.001 / +0.028 / +0.016. Moderate 4 /m (a 25 cm radius).
  s.parameters = {
      {"crease_rad", "rad", 0.0, -1.5, 1.5, 0.3, 0.3,
       "rest fold angle of the two storage creases along the weft and warp diameters (positive: a ridge)"},
      {"dome_per_m", "1/m", 0.0, -20.0, 20.0, 3.0, 4.0, "uniform rest curvature (positive: a cap, the centre up)"},
  };
  s.make_terms = [](const EffectContext&) { return std::vector<std::unique_ptr<Term>>{}; };
  s.change_base_terms = [](const EffectContext& c, BaseTermChanges& changes) {
    double mean_length = 0;
    for (const BendingEdge& be : c.bending_edges) mean_length += (c.mesh.uv.row(be.a) - c.mesh.uv.row(be.b)).norm();
    mean_length /= std::max<size_t>(1, c.bending_edges.size());
    const double sigma = std::max(kCreaseWidth, mean_length);
    changes.bend_rest.add(c.layout.block(effect_block_name(kName, "crease_rad")).offset,
                          rest_angle_coefficients(c, [sigma](double u, double v) {
                            return crease_profile(u, sigma) + crease_profile(v, sigma);
                          }));
    changes.bend_rest.add(c.layout.block(effect_block_name(kName, "dome_per_m")).offset,
                          rest_angle_coefficients(c, [](double u, double v) { return 0.5 * (u * u + v * v); }));
  };
  return s;
}

}  // namespace drapelab
