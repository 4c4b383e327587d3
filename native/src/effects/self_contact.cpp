// Effect "self_contact": the cloth cannot pass through itself. IPC barriers on every point-triangle and edge-edge
// pair of the specimen's own surface closer than the activation distance dhat = `thickness_m`, with continuous
// collision detection bounding every solver step (contact/pair_contact.hpp has the model, its stiffness and how
// the solvers handle couplings outside the model's sparsity pattern). Surfaces keep at least a fraction of their
// distance per step, never touch, and rest about a thickness apart where folds press together.
// Off value: thickness 0, no term (the base model bit for bit). The thickness is structural (physics/effect.hpp):
// it decides whether the model carries a contact term at all (a model built without one cannot learn one), so
// it is read when the model is built, fits hold it (at the fabric's thickness, or the registry's 1 mm when the
// effect is fitted), and the diagnosis treats self_contact as a switch judged by its refit. Its derivatives are
// still provided (checked against rebuilt models in tests/native/contact/test_self_contact.cpp). `friction`:
// Coulomb coefficient between layers (IPC's lagged smoothed friction per pair; none in a static drape), fitted.
#include "contact/diagnostics.hpp"
#include "contact/pair_contact.hpp"
#include "physics/effect.hpp"
#include "physics/model.hpp"

namespace drapelab {
namespace {

constexpr double kWeightScale = 1.0;  // barrier stiffness in units of the vertex's weight (disk_contact: 5, for the rim)

double built_thickness(const EffectContext& c) {
  const auto it = c.options.effects.find("self_contact");
  if (it != c.options.effects.end()) {
    const auto q = it->second.find("thickness_m");
    if (q != it->second.end()) return q->second;
  }
  return 0.0;
}

class SelfContactTerm : public PairContactTerm {
 public:
  SelfContactTerm(const EffectContext& c, ContactSurfaces s, std::vector<double> stiffness)
      : PairContactTerm(std::move(s), c.mesh.num_vertices(), std::move(stiffness), PairFilter::kSelf, c.mesh.positions),
        thickness_(c.layout.block(effect_block_name("self_contact", "thickness_m")).offset),
        friction_(c.layout.block(effect_block_name("self_contact", "friction")).offset) {}
  std::string name() const override { return "self_contact"; }

 protected:
  double dhat(const Eigen::VectorXd& p) const override { return p[thickness_]; }
  int dhat_index() const override { return thickness_; }
  double friction(const Eigen::VectorXd& p) const override { return p[friction_]; }
  int friction_index() const override { return friction_; }

 private:
  int thickness_, friction_;
};

}  // namespace

EffectSpec make_self_contact_effect() {
  EffectSpec s;
  s.name = "self_contact";
  s.explanation = "folds of the specimen press against each other and cannot pass through (cloth thickness)";
  s.signature = "deep folds stay a thickness apart: fewer, rounder nodes where the cloth would fold over itself";
  s.parameters = {
      // Structural: whether the model has a contact term (a switch for the diagnosis); 1 mm when fitted.
      {"thickness_m", "m", 0.0, 0.0, 0.01, 5e-4, 1e-3, "cloth thickness: distance at which layers repel", true},
      {"friction", "1", 0.0, 0.0, 2.0, 0.2, 0.3, "Coulomb friction coefficient between layers of the fabric"},
  };
  s.make_terms = [](const EffectContext& c) {
    std::vector<std::unique_ptr<Term>> terms;
    if (!(built_thickness(c) > 0)) return terms;  // off: the base model
    std::vector<double> stiffness(c.mesh.num_vertices());
    for (int i = 0; i < c.mesh.num_vertices(); ++i)
      stiffness[i] = kWeightScale * c.area_weights[i] * c.options.density * c.options.gravity;
    terms.push_back(std::make_unique<SelfContactTerm>(c, make_contact_surfaces(c.mesh.faces, c.mesh.num_vertices()),
                                                      std::move(stiffness)));
    return terms;
  };
  return s;
}

}  // namespace drapelab
