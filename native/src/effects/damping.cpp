// Effect "damping": air drag and internal damping over the finite settling time of the dynamic drape. Mass-
// proportional (Rayleigh) damping, a force -c m_i v_i on each vertex, taken implicitly (at the step's end
// velocity v' = (x - x_t) / h) as a dissipation potential of the step:
//   E_d(x) = c / (2 h) sum_i m_i |x_i - x_t,i|^2,   m_i = rho w_i,   grad E_d = c m_i (x_i - x_t,i) / h = c m_i v'_i
// with c = mass_per_s [1/s] (a velocity decays as exp(-c t) in free flight), rho the model's "density" and w_i the
// vertex area weights (the lumped mass matrix of solver/implicit_euler.cpp). In the implicit Euler step this is
// (1 + h c) m v' = m v + h f: exactly zero at c = 0 (the base model, bit for bit: the term adds 0 to every value).
// It depends on the step start x_t (Term::begin_step), like lagged friction: its x_t-derivative is
// Term::add_step_start_adjoint, so the rollout adjoints (contact-free, Newton and linearised contact steps) are
// exact. A static drape (h = 0, begin_step with h = 0) has no damping: the term is zero there, and the static
// solve's equilibrium does not depend on mass_per_s (its gradient is exactly 0; static_solve.hpp says so).
#include <array>
#include <cmath>

#include "physics/effect.hpp"
#include "physics/element_term.hpp"
#include "physics/model.hpp"

namespace drapelab {
namespace {

constexpr const char* kName = "damping";

class DampingTerm : public ElementTerm<DampingTerm, 1, 2, 3> {
 public:
  explicit DampingTerm(const EffectContext& c)
      : weights_(c.area_weights.data(), c.area_weights.data() + c.area_weights.size()),
        indices_{c.layout.block("density").offset, c.layout.block(effect_block_name(kName, "mass_per_s")).offset} {
    for (int i = 0; i < static_cast<int>(weights_.size()); ++i) verts_.push_back({i});
  }
  std::string name() const override { return kName; }
  int num_elements() const { return static_cast<int>(verts_.size()); }
  const std::array<int, 1>& element_vertices(int e) const { return verts_[e]; }
  const std::array<int, 2>& parameter_indices(int) const { return indices_; }

  // The step's start x_t and time step h; h = 0 (a static solve) switches the term off.
  void begin_step(const Eigen::VectorXd& x, const Eigen::VectorXd&, double h) override {
    start_ = x;
    inv_h_ = h > 0 ? 1.0 / h : 0.0;
  }

  // E_d is a function of x - x_t with a constant step matrix: its x_t-derivative of lambda . grad E_d is
  // -(c m_i / h) lambda_i; the step matrix's part is zero.
  void add_step_start_adjoint(const Eigen::VectorXd&, const Eigen::VectorXd& p, const Eigen::VectorXd& lambda,
                              const Eigen::VectorXd&, double, Eigen::VectorXd& gxt) const override {
    if (!active()) return;
    const double k = p[indices_[0]] * p[indices_[1]] * inv_h_;
    for (int i = 0; i < num_elements(); ++i) gxt.segment<3>(3 * i) -= (k * weights_[i]) * lambda.segment<3>(3 * i);
  }

  template <class T>
  T element_energy(int e, const T* x, const T* p) const {
    if (!active()) return T(0.0);
    T u2 = T(0.0);
    for (int a = 0; a < 3; ++a) {
      const T u = x[a] - start_[3 * e + a];
      u2 += u * u;
    }
    return (0.5 * weights_[e] * inv_h_) * (p[0] * p[1]) * u2;
  }
  // r = x - x_t, S = (c rho w / h) I: the exact (constant) Hessian.
  template <class T>
  void element_gauss_newton(int e, const T* x, const T* p, T* r, T* S) const {
    const T k = active() ? (weights_[e] * inv_h_) * (p[0] * p[1]) : T(0.0);
    for (int a = 0; a < 3; ++a) {
      r[a] = active() ? x[a] - start_[3 * e + a] : x[a];
      for (int b = 0; b < 3; ++b) S[3 * a + b] = a == b ? k : T(0.0);
    }
  }

 private:
  bool active() const { return inv_h_ > 0 && start_.size() == 3 * static_cast<Eigen::Index>(weights_.size()); }

  std::vector<double> weights_;
  std::array<int, 2> indices_;
  std::vector<std::array<int, 1>> verts_;
  Eigen::VectorXd start_;
  double inv_h_ = 0;
};

}  // namespace

EffectSpec make_damping_effect() {
  EffectSpec s;
  s.name = kName;
  s.explanation =
      "air drag and internal damping: a mass-proportional (Rayleigh) force -c m v slows the fall, so the dynamic "
      "drape has not settled as far at the end of the rollout (no effect on a static drape)";
  s.signature =
      "below about 8 /s none (the drape settles within the rollout either way); above, the slower fall chooses "
      "other folds (more nodes) and the drape coefficient rises (+0.05 at 10 /s on circle3); a static drape is "
      "unchanged";
  // Moderate strength, measured on circle3 (tools/effect_strength.py: Cotton Blue tables, 100 x 0.05 s rollout from
  // flat, no placement noise; re-drape floor 0.031 in DC, 0.042 in pixel MSE; base drape DC 0.562, 6 nodes).
  // Air drag on a 0.19 kg/m^2 cloth falling at 0.5 m/s is c ~ 2 /s, and that is below the noise: the drape has
  // settled within the 5 s either way. mass_per_s 0.5 / 1 / 2 / 4 / 6: DC -0.001 / -0.001 / +0.000 / +0.001 /
  // -0.003, MSE 0.002 / 0.003 / 0.003 / 0.012 / 0.024; from about 8 /s the slower fall chooses other folds:
  // 8 / 10 / 12 / 16 / 32: DC +0.023 / +0.047 / +0.050 / +0.025 / +0.023, MSE 0.060 / 0.062 / 0.065 / 0.063 /
  // 0.051 (7, 8, 8, 7, 7 nodes). Moderate 10 /s (1.5x the DC floor; what an under-settled drape looks like).
  s.parameters = {
      {"mass_per_s", "1/s", 0.0, 0.0, 50.0, 5.0, 10.0,
       "mass-proportional damping rate c (a free velocity decays as exp(-c t)); 0: undamped"},
  };
  s.dynamic_only = true;
  s.make_terms = [](const EffectContext& c) {
    std::vector<std::unique_ptr<Term>> terms;
    terms.push_back(std::make_unique<DampingTerm>(c));
    return terms;
  };
  return s;
}

}  // namespace drapelab
