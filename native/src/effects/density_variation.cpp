// Effect "density_variation": the area density is not uniform over the specimen (uneven finishing, sizing or
// moisture). Over the rest position X = (u, v) (u = x, the weft; v = y, the warp; r = |X|) the density is
//   rho(X) = rho (1 + radial r / R + grad_x u / R + grad_y v / R),
// R the specimen radius (the largest rest radius of the mesh), each coefficient the fractional change of the
// density at the rim (r = R) [1]. With lumped masses m_i = rho w_i, the term adds the difference to the base
// gravity term (E = rho w_i g z_i):
//   dE = sum_i rho w_i g z_i (radial r_i / R + grad_x u_i / R + grad_y v_i / R)   [J]
// which is exactly zero at the off value (all coefficients 0). Parameters: the model's "density" (kg/m^2) and
// the three coefficients.
//
// Approximation: the effect changes the load (gravity's work) only. The inertia of the dynamic rollout keeps
// the base lumped masses rho w_i (the mass matrix is the solver's, built from the "density" block alone).
// A settled drape is an equilibrium of the load and the elastic forces, which inertia does not enter, so the
// static drape is exact and the rollout's end state differs only by how the transient settles. The bounds
// keep the multiplier above 0.1 everywhere on the disk: 1 + radial - |grad| >= 1 - 0.4 - 0.35 sqrt(2).
#include <array>
#include <cmath>

#include "physics/effect.hpp"
#include "physics/element_term.hpp"
#include "physics/model.hpp"

namespace drapelab {
namespace {

constexpr const char* kName = "density_variation";

class DensityVariationTerm : public ElementTerm<DensityVariationTerm, 1, 4, 0> {
 public:
  explicit DensityVariationTerm(const EffectContext& c)
      : gravity_(c.options.gravity),
        indices_{c.layout.block("density").offset, c.layout.block(effect_block_name(kName, "radial")).offset,
                 c.layout.block(effect_block_name(kName, "grad_x")).offset,
                 c.layout.block(effect_block_name(kName, "grad_y")).offset} {
    const int nv = c.mesh.num_vertices();
    double R = 0;
    for (int i = 0; i < nv; ++i) R = std::max(R, c.mesh.uv.row(i).norm());
    for (int i = 0; i < nv; ++i) {
      verts_.push_back({i});
      const double w = c.area_weights[i] * gravity_;
      // per vertex: rho w g times the three mode values (r/R, u/R, v/R)
      load_.push_back({w, c.mesh.uv.row(i).norm() / R, c.mesh.uv(i, 0) / R, c.mesh.uv(i, 1) / R});
    }
  }
  std::string name() const override { return kName; }
  int num_elements() const { return static_cast<int>(verts_.size()); }
  const std::array<int, 1>& element_vertices(int e) const { return verts_[e]; }
  const std::array<int, 4>& parameter_indices(int) const { return indices_; }

  template <class T>
  T element_energy(int e, const T* x, const T* p) const {
    const auto& l = load_[e];
    return (p[0] * l[0]) * x[2] * (p[1] * l[1] + p[2] * l[2] + p[3] * l[3]);
  }
  template <class T>
  void element_gauss_newton(int, const T*, const T*, T*, T*) const {}  // linear in positions

 private:
  double gravity_;
  std::array<int, 4> indices_;
  std::vector<std::array<int, 1>> verts_;
  std::vector<std::array<double, 4>> load_;  // w_i g [m^3/s^2], r_i / R, u_i / R, v_i / R
};

}  // namespace

EffectSpec make_density_variation_effect() {
  EffectSpec s;
  s.name = kName;
  s.explanation =
      "the area density is not uniform: it varies linearly with the rest radius and along x and y (changes the "
      "load only; the rollout's inertia keeps the base masses)";
  s.signature =
      "heavier rim (radial > 0): the skirt hangs closer to the disk and the drape coefficient falls, as with a "
      "denser fabric; a gradient: the drape coefficient stays, a 1-fold r(theta) residual, the heavier side "
      "hanging lower";
  // Moderate strengths, measured on circle3 (Cotton Blue tables, 100 x 0.05 s rollout; the re-drape noise floor
  // is 0.031 in drape coefficient): radial 0.3 moves DC by -0.074 (2.4x; -0.3: +0.095, 0.2: -0.051), pixel MSE
  // 0.026 against the base drape. A gradient leaves DC almost unchanged (+0.001 at 0.15, +0.003 at 0.3) and moves
  // the silhouette as much as radial 0.3 does at 0.25-0.3 (MSE 0.0125 at 0.15, 0.028 at 0.3).
  s.parameters = {
      {"radial", "1", 0.0, -0.4, 1.0, 0.2, 0.3, "fractional density change at the rim (r = R) from the centre"},
      {"grad_x", "1", 0.0, -0.35, 0.35, 0.15, 0.25, "fractional density change at x = R (weft direction)"},
      {"grad_y", "1", 0.0, -0.35, 0.35, 0.15, 0.25, "fractional density change at y = R (warp direction)"},
  };
  s.make_terms = [](const EffectContext& c) {
    std::vector<std::unique_ptr<Term>> terms;
    terms.push_back(std::make_unique<DensityVariationTerm>(c));
    return terms;
  };
  return s;
}

}  // namespace drapelab
