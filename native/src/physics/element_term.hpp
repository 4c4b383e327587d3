// Generic per-element machinery for terms whose energy is a sum over small elements (faces, bending
// edges, vertices). A term supplies, per element e:
//   template <class T> T element_energy(int e, const T* x, const T* p) const;        x: 3*kVertices, p: kParams
//   template <class T> void element_gauss_newton(int e, const T* x, const T* p, T* r, T* S) const;
//        residuals r (kResiduals, independent of p) and a PSD weight S (kResiduals^2, row-major) such that
//        the step matrix is K_e = J_r^T S J_r with J_r = dr/dx.
//   int num_elements(); const std::array<int, kVertices>& element_vertices(int e); and either
//   int parameter_offset(int e) (the element's kParams parameters are p[offset .. offset + kParams)) or
//   std::array<int, kParams> parameter_indices(int e) (parameters gathered from several blocks, as effects
//   that scale another term's energy or gravity need).
// Every derivative in Term is then derived with forward-mode jets (util/jet.hpp): exact by construction.
// These generic versions are slow (9- and 12-wide jets through the whole element); the hot terms (stretch,
// bend) override them with hand-written kernels and keep these as their `Reference`, which
// tests/native/physics/test_kernels.cpp compares them against (1e-12 relative) on random states. New terms
// get correct derivatives from here alone and can add kernels later.
#pragma once
#include <array>
#include <type_traits>
#include <utility>
#include <vector>

#include "physics/sparse_pattern.hpp"
#include "physics/term.hpp"
#include "util/jet.hpp"
#include "util/psd_projection.hpp"

namespace drapelab {

template <class T, class = void>
struct has_parameter_indices : std::false_type {};
template <class T>
struct has_parameter_indices<T, std::void_t<decltype(std::declval<const T&>().parameter_indices(0))>>
    : std::true_type {};

// d(lambda^T K w)/dx_j, j < D, of an element's K = J_r^T S J_r from its M residuals r and weights S evaluated on
// nested jets: outer derivatives in the element's D coordinates, inner ones along lambda (0) and w (1). Also gives
// J_r lambda and J_r w (Jl, Jw).
template <int M, int D, class U>
void contract_step_matrix_derivative(const U* r, const U* S, double* out, double* Jl, double* Jw) {
  for (int a = 0; a < M; ++a) {
    Jl[a] = r[a].a.v[0];
    Jw[a] = r[a].a.v[1];
  }
  for (int j = 0; j < D; ++j) {
    double s = 0;
    for (int a = 0; a < M; ++a)
      for (int b = 0; b < M; ++b) {
        const double Sab = S[a * M + b].a.a;
        s += r[a].v[j].v[0] * Sab * Jw[b] + Jl[a] * S[a * M + b].v[j].a * Jw[b] + Jl[a] * Sab * r[b].v[j].v[1];
      }
    out[j] = s;
  }
}

template <class Derived, int kVertices, int kParams, int kResiduals>
class ElementTerm : public Term {
 public:
  static constexpr int D = 3 * kVertices;

  // The element parameters (parameter_offset / parameter_indices) and, in terms that read more (the base
  // terms' changes: physics/base_term_changes.hpp), extra_parameter_indices().
  bool reads_parameters(const std::vector<char>& mask) const override {
    for (int i : self().extra_parameter_indices())
      if (mask[i]) return true;
    for (int e = 0; e < self().num_elements(); ++e)
      for (int k = 0; k < kParams; ++k)
        if (mask[parameter_index(e, k)]) return true;
    return false;
  }
  // Parameters read besides the elements' own: none unless a term says so.
  std::vector<int> extra_parameter_indices() const { return {}; }

  std::vector<std::vector<int>> stencils() const override {
    std::vector<std::vector<int>> s;
    s.reserve(self().num_elements());
    for (int e = 0; e < self().num_elements(); ++e) {
      const auto& v = self().element_vertices(e);
      s.emplace_back(v.begin(), v.end());
    }
    return s;
  }

  void bind_pattern(const SparsePattern& pattern) override {
    const int ne = self().num_elements();
    scatter_.assign(static_cast<size_t>(ne) * D * D, -1);
    for (int e = 0; e < ne; ++e) {
      const auto& v = self().element_vertices(e);
      for (int i = 0; i < D; ++i)
        for (int j = 0; j < D; ++j) {
          const int r = 3 * v[i / 3] + i % 3, c = 3 * v[j / 3] + j % 3;
          if (r <= c) scatter_[(static_cast<size_t>(e) * D + i) * D + j] = pattern.index(r, c);
        }
    }
  }

  double energy(const Eigen::VectorXd& x, const Eigen::VectorXd& p) const override {
    double E = 0;
    double xe[D];
    for (int e = 0; e < self().num_elements(); ++e) {
      gather(e, x, xe);
      double pe[kParams > 0 ? kParams : 1];
      gather_parameters(e, p, pe);
      E += self().template element_energy<double>(e, xe, pe);
    }
    return E;
  }

  void add_gradient(const Eigen::VectorXd& x, const Eigen::VectorXd& p, Eigen::VectorXd& g) const override {
    using J = Jet<double, D>;
    J xe[D], pe[kParams > 0 ? kParams : 1];
    for (int e = 0; e < self().num_elements(); ++e) {
      seed_x(e, x, xe);
      for (int k = 0; k < kParams; ++k) pe[k] = J(p[parameter_index(e, k)]);
      const J E = self().template element_energy<J>(e, xe, pe);
      scatter_vector(e, E.v.data(), 1.0, g);
    }
  }

  void add_step_matrix(const Eigen::VectorXd& x, const Eigen::VectorXd& p, double scale,
                       Eigen::VectorXd& values) const override {
    if constexpr (kResiduals > 0) {
      using J = Jet<double, D>;
      J xe[D], pe[kParams > 0 ? kParams : 1], r[kResiduals], S[kResiduals * kResiduals];
      double K[D * D];
      for (int e = 0; e < self().num_elements(); ++e) {
        seed_x(e, x, xe);
        for (int k = 0; k < kParams; ++k) pe[k] = J(p[parameter_index(e, k)]);
        self().template element_gauss_newton<J>(e, xe, pe, r, S);
        // K = J_r^T S J_r
        double SJ[kResiduals * D];
        for (int a = 0; a < kResiduals; ++a)
          for (int j = 0; j < D; ++j) {
            double s = 0;
            for (int b = 0; b < kResiduals; ++b) s += S[a * kResiduals + b].a * r[b].v[j];
            SJ[a * D + j] = s;
          }
        for (int i = 0; i < D; ++i)
          for (int j = 0; j < D; ++j) {
            double s = 0;
            for (int a = 0; a < kResiduals; ++a) s += r[a].v[i] * SJ[a * D + j];
            K[i * D + j] = s;
          }
        scatter_matrix(e, K, scale, values);
      }
    }
  }

  bool add_step_matrix_product(const Eigen::VectorXd& x, const Eigen::VectorXd& p, const Eigen::VectorXd& dir,
                               double scale, Eigen::VectorXd& out) const override {
    if constexpr (kResiduals > 0) {
      using J = Jet<double, D>;
      J xe[D], pe[kParams > 0 ? kParams : 1], r[kResiduals], S[kResiduals * kResiduals];
      double de[D], out_e[D];
      for (int e = 0; e < self().num_elements(); ++e) {
        seed_x(e, x, xe);
        gather(e, dir, de);
        for (int k = 0; k < kParams; ++k) pe[k] = J(p[parameter_index(e, k)]);
        self().template element_gauss_newton<J>(e, xe, pe, r, S);
        // K d = J_r^T S (J_r d)
        double Jd[kResiduals], SJd[kResiduals];
        for (int a = 0; a < kResiduals; ++a) {
          double s = 0;
          for (int j = 0; j < D; ++j) s += r[a].v[j] * de[j];
          Jd[a] = s;
        }
        for (int a = 0; a < kResiduals; ++a) {
          double s = 0;
          for (int b = 0; b < kResiduals; ++b) s += S[a * kResiduals + b].a * Jd[b];
          SJd[a] = s;
        }
        for (int i = 0; i < D; ++i) {
          double s = 0;
          for (int a = 0; a < kResiduals; ++a) s += r[a].v[i] * SJd[a];
          out_e[i] = s;
        }
        scatter_vector(e, out_e, scale, out);
      }
    }
    return true;
  }

  bool add_step_system(const Eigen::VectorXd& x, const Eigen::VectorXd& p, const Eigen::VectorXd& v, double scale,
                       Eigen::VectorXd& values, Eigen::VectorXd& Kv, Eigen::VectorXd& g) const override {
    this->add_step_matrix(x, p, scale, values);
    this->add_gradient(x, p, g);
    return this->add_step_matrix_product(x, p, v, scale, Kv);  // always provided here
  }

  void add_hessian(const Eigen::VectorXd& x, const Eigen::VectorXd& p, double scale,
                   Eigen::VectorXd& values) const override {
    add_element_hessians(x, p, scale, values, false);
  }

  void add_projected_hessian(const Eigen::VectorXd& x, const Eigen::VectorXd& p, double scale,
                             Eigen::VectorXd& values) const override {
    add_element_hessians(x, p, scale, values, true);
  }

  void add_hessian_product(const Eigen::VectorXd& x, const Eigen::VectorXd& p, const Eigen::VectorXd& dir,
                           Eigen::VectorXd& out) const override {
    using J1 = Jet<double, 1>;
    using J2 = Jet<J1, D>;
    J2 xe[D], pe[kParams > 0 ? kParams : 1];
    double Hd[D];
    for (int e = 0; e < self().num_elements(); ++e) {
      const auto& v = self().element_vertices(e);
      for (int i = 0; i < D; ++i) {
        const int dof = 3 * v[i / 3] + i % 3;
        J1 inner(x[dof]);
        inner.v[0] = dir[dof];
        xe[i] = J2(inner);
        xe[i].a = inner;
        xe[i].v[i] = J1(1.0);
      }
      for (int k = 0; k < kParams; ++k) pe[k] = J2(p[parameter_index(e, k)]);
      const J2 E = self().template element_energy<J2>(e, xe, pe);
      for (int i = 0; i < D; ++i) Hd[i] = E.v[i].v[0];
      scatter_vector(e, Hd, 1.0, out);
    }
  }

  void add_energy_parameter_gradient(const Eigen::VectorXd& x, const Eigen::VectorXd& p,
                                     Eigen::VectorXd& gp) const override {
    if constexpr (kParams > 0) {
      using J = Jet<double, kParams>;
      J xe[D], pe[kParams];
      for (int e = 0; e < self().num_elements(); ++e) {
        const auto& v = self().element_vertices(e);
        for (int i = 0; i < D; ++i) xe[i] = J(x[3 * v[i / 3] + i % 3]);
        for (int k = 0; k < kParams; ++k) pe[k] = J(p[parameter_index(e, k)], k);
        const J E = self().template element_energy<J>(e, xe, pe);
        for (int k = 0; k < kParams; ++k) gp[parameter_index(e, k)] += E.v[k];
      }
    }
  }

  void add_gradient_parameter_product(const Eigen::VectorXd& x, const Eigen::VectorXd& p,
                                      const Eigen::VectorXd& lambda, double scale,
                                      Eigen::VectorXd& gp) const override {
    if constexpr (kParams > 0) {
      using J1 = Jet<double, 1>;
      using J2 = Jet<J1, kParams>;
      J2 xe[D], pe[kParams];
      for (int e = 0; e < self().num_elements(); ++e) {
        const auto& v = self().element_vertices(e);
        for (int i = 0; i < D; ++i) {
          const int dof = 3 * v[i / 3] + i % 3;
          J1 inner(x[dof]);
          inner.v[0] = lambda[dof];
          xe[i] = J2(0.0);
          xe[i].a = inner;
        }
        for (int k = 0; k < kParams; ++k) {
          pe[k] = J2(p[parameter_index(e, k)]);
          pe[k].v[k] = J1(1.0);
        }
        const J2 E = self().template element_energy<J2>(e, xe, pe);
        for (int k = 0; k < kParams; ++k) gp[parameter_index(e, k)] += scale * E.v[k].v[0];
      }
    }
  }

  void add_step_matrix_derivatives(const Eigen::VectorXd& x, const Eigen::VectorXd& p, const Eigen::VectorXd& lambda,
                                   const Eigen::VectorXd& w, double scale, Eigen::VectorXd& gx,
                                   Eigen::VectorXd& gp) const override {
    if constexpr (kResiduals > 0) {
      using J1 = Jet<double, 2>;
      using U = Jet<J1, D>;
      constexpr int M = kResiduals;
      U xe[D], pe[kParams > 0 ? kParams : 1], r[M], S[M * M];
      using JP = Jet<double, kParams>;
      JP xp[D], pp[kParams > 0 ? kParams : 1], rp[M], Sp[M * M];
      double gxe[D];
      for (int e = 0; e < self().num_elements(); ++e) {
        const auto& v = self().element_vertices(e);
        for (int i = 0; i < D; ++i) {
          const int dof = 3 * v[i / 3] + i % 3;
          J1 inner(x[dof]);
          inner.v[0] = lambda[dof];
          inner.v[1] = w[dof];
          xe[i] = U(0.0);
          xe[i].a = inner;
          xe[i].v[i] = J1(1.0);
        }
        for (int k = 0; k < kParams; ++k) pe[k] = U(p[parameter_index(e, k)]);
        self().template element_gauss_newton<U>(e, xe, pe, r, S);
        double Jl[M], Jw[M];
        contract_step_matrix_derivative<M, D>(r, S, gxe, Jl, Jw);
        scatter_vector(e, gxe, scale, gx);
        if constexpr (kParams > 0) {
          for (int i = 0; i < D; ++i) xp[i] = JP(x[3 * v[i / 3] + i % 3]);
          for (int k = 0; k < kParams; ++k) pp[k] = JP(p[parameter_index(e, k)], k);
          self().template element_gauss_newton<JP>(e, xp, pp, rp, Sp);
          for (int k = 0; k < kParams; ++k) {
            double s = 0;
            for (int a = 0; a < M; ++a)
              for (int b = 0; b < M; ++b) s += Jl[a] * Sp[a * M + b].v[k] * Jw[b];
            gp[parameter_index(e, k)] += scale * s;
          }
        }
      }
    }
  }

 protected:
  const Derived& self() const { return static_cast<const Derived&>(*this); }

  // Index into p of element e's k-th parameter (see the header comment).
  int parameter_index(int e, int k) const {
    if constexpr (has_parameter_indices<Derived>::value) return self().parameter_indices(e)[k];
    else return self().parameter_offset(e) + k;
  }
  void gather_parameters(int e, const Eigen::VectorXd& p, double* pe) const {
    for (int k = 0; k < kParams; ++k) pe[k] = p[parameter_index(e, k)];
  }

  void gather(int e, const Eigen::VectorXd& x, double* xe) const {
    const auto& v = self().element_vertices(e);
    for (int i = 0; i < D; ++i) xe[i] = x[3 * v[i / 3] + i % 3];
  }
  template <class J>
  void seed_x(int e, const Eigen::VectorXd& x, J* xe) const {
    const auto& v = self().element_vertices(e);
    for (int i = 0; i < D; ++i) xe[i] = J(x[3 * v[i / 3] + i % 3], i);
  }
  void scatter_vector(int e, const double* ge, double scale, Eigen::VectorXd& g) const {
    const auto& v = self().element_vertices(e);
    for (int i = 0; i < D; ++i) g[3 * v[i / 3] + i % 3] += scale * ge[i];
  }
  // Exact element Hessians (second-order jets), each projected onto the PSD cone if `project`.
  void add_element_hessians(const Eigen::VectorXd& x, const Eigen::VectorXd& p, double scale,
                            Eigen::VectorXd& values, bool project) const {
    using J1 = Jet<double, D>;
    using J2 = Jet<J1, D>;
    J2 xe[D], pe[kParams > 0 ? kParams : 1];
    double H[D * D];
    for (int e = 0; e < self().num_elements(); ++e) {
      const auto& v = self().element_vertices(e);
      for (int i = 0; i < D; ++i) {
        xe[i] = J2(J1(x[3 * v[i / 3] + i % 3], i));
        xe[i].v[i] = J1(1.0);
      }
      for (int k = 0; k < kParams; ++k) pe[k] = J2(p[parameter_index(e, k)]);
      const J2 E = self().template element_energy<J2>(e, xe, pe);
      for (int i = 0; i < D; ++i)
        for (int j = 0; j < D; ++j) H[i * D + j] = E.v[i].v[j];
      if (project) project_psd<D>(H);
      scatter_matrix(e, H, scale, values);
    }
  }
  void scatter_matrix(int e, const double* K, double scale, Eigen::VectorXd& values) const {
    const int* map = scatter_.data() + static_cast<size_t>(e) * D * D;
    for (int k = 0; k < D * D; ++k)
      if (map[k] >= 0) values[map[k]] += scale * K[k];
  }

 private:
  std::vector<int> scatter_;
};

}  // namespace drapelab
