// Effect "disk_contact": the specimen lies on the Cusick support disk and bends over its rounded rim, with
// Coulomb friction, held only by a small centre clamp of radius `clamp_radius_m` instead of the base model's
// rigid handle over the whole 9 cm disk. Off value: a clamp as large as the support disk (the base model).
//
// Contact is the IPC barrier (contact/barrier.hpp) on the distance of each free vertex over the disk to the
// disk's surface (contact/distance.hpp SupportDisk: a plate whose rim is rounded with radius `rim_radius_m`):
//   E_i = kappa_i b(d_i),  kappa_i = kWeightScale * w_i * rho * g * dhat   [J]
// (w_i the vertex's area weight, rho the model's nominal density: the barrier carries about the vertex's weight
// at d = dhat / 2). The disk's top face lies dhat below the flat rest state, so the rest state feels no force.
// Friction is IPC's lagged, smoothed Coulomb potential (Li et al. 2020, sec. 5): with the normal force
// lambda_i = |dE_i/dd| and the tangent projector P_i = I - n_i n_i^T taken at the start of each time step
// (x_t), D_i = mu lambda_i f0(|P_i (x_i - x_t,i)|, eps_v h) [J]; f0 smooths the stick-slip switch over a slip
// speed eps_v. The lagging is IPC's approximation: within a step the normal force and the tangent plane are
// those of its start. The adjoint differentiates them in x_t (add_step_start_adjoint), not in the rim radius
// (its gradient misses their part). A static drape has no friction.
// Only the vertices whose rest radius lies between the clamp and the disk's edge touch the disk (the rest hang
// beyond its rim from the start); edges are not tested against the rim, so the rim radius should exceed the
// mesh's sag between two vertices over it (2 mm against 0.6 mm on circle3).
#include <algorithm>
#include <array>
#include <cmath>

#include "contact/barrier.hpp"
#include "contact/distance.hpp"
#include "physics/effect.hpp"
#include "physics/element_term.hpp"
#include "physics/model.hpp"

namespace drapelab {
namespace {

constexpr double kActivation = 5e-4;     // dhat [m]: the barrier acts within 0.5 mm of the disk
constexpr double kWeightScale = 1.0;     // barrier stiffness in units of the vertex's weight (see header)
constexpr double kSlipSpeed = 1e-3;      // eps_v [m/s]: below this slip speed friction is smoothed (static)
constexpr double kCcdGapFraction = 0.1;  // a step may close at most 90 % of a vertex's distance to the disk

double clamp_radius(const EffectContext& c) {
  const auto it = c.options.effects.find("disk_contact");
  if (it != c.options.effects.end()) {
    const auto q = it->second.find("clamp_radius_m");
    if (q != it->second.end()) return q->second;
  }
  return find_effect("disk_contact").parameters[0].off;
}

// The free vertices over the disk, its geometry and their barrier stiffnesses (shared by both terms).
struct DiskSetup {
  std::vector<std::array<int, 1>> vertices;
  std::vector<double> kappa;
  SupportDisk disk;
  DiskSetup(const EffectContext& c) {
    const double clamp = clamp_radius(c), support = c.options.support_radius;
    double top = 0;
    for (int v : c.handle_vertices) top += c.mesh.positions(v, 2);
    top /= std::max<size_t>(1, c.handle_vertices.size());
    disk.radius = support;
    disk.top = top - kActivation;
    for (int i = 0; i < c.mesh.num_vertices(); ++i) {
      const double r = c.mesh.uv.row(i).norm();
      if (r >= clamp && r < support) {
        vertices.push_back({i});
        kappa.push_back(kWeightScale * c.area_weights[i] * c.options.density * c.options.gravity * kActivation);
      }
    }
  }
  template <class T>
  T distance(const T* x, const T& rim) const {
    using std::abs;
    using std::sqrt;
    // support_disk_distance with the rim radius as a (differentiable) parameter
    const T inner = disk.radius - rim, zc = disk.top - rim;
    const T dz = x[2] - zc;
    const T r2 = x[0] * x[0] + x[1] * x[1];
    if (value_of(r2) <= value_of(inner) * value_of(inner))  // over (or under) the flat face
      return value_of(dz) >= 0 ? x[2] - disk.top : (disk.top - 2.0 * rim) - x[2];
    const T dr = sqrt(r2) - inner;
    return sqrt(dr * dr + dz * dz) - rim;
  }
};

class DiskBarrierTerm : public ElementTerm<DiskBarrierTerm, 1, 1, 1> {
 public:
  DiskBarrierTerm(const EffectContext& c, std::shared_ptr<const DiskSetup> setup)
      : setup_(std::move(setup)), rim_(c.layout.block(effect_block_name("disk_contact", "rim_radius_m")).offset) {}
  std::string name() const override { return "disk_contact"; }
  bool is_contact() const override { return true; }
  int num_elements() const { return static_cast<int>(setup_->vertices.size()); }
  const std::array<int, 1>& element_vertices(int e) const { return setup_->vertices[e]; }
  int parameter_offset(int) const { return rim_; }

  template <class T>
  T element_energy(int e, const T* x, const T* p) const {
    const T d = setup_->distance(x, p[0]);
    if (!(value_of(d) > 0)) return T(std::numeric_limits<double>::infinity());
    return setup_->kappa[e] * barrier(d, kActivation);
  }
  // Gauss-Newton: r = d(x), S = kappa b''(d) >= 0 (the dropped b'(d) Hess d is negative semidefinite: the disk
  // is convex, so its distance is convex and b' < 0).
  template <class T>
  void element_gauss_newton(int e, const T* x, const T* p, T* r, T* S) const {
    r[0] = setup_->distance(x, p[0]);
    // S as a function of x for the step-matrix derivatives: kappa b''(d(x)) through the jets.
    const T d = r[0];
    if (value_of(d) >= kActivation) {
      S[0] = T(0.0);
      return;
    }
    const T e1 = d - kActivation;
    const T l = log_of(d / kActivation);
    S[0] = setup_->kappa[e] * (-2.0 * l - 4.0 * e1 / d + e1 * e1 / (d * d)) / (kActivation * kActivation);
  }

  double max_step(const Eigen::VectorXd& x, const Eigen::VectorXd& dx, const Eigen::VectorXd& p) const override {
    // Conservative advancement: the distance is 1-Lipschitz in the vertex position, so along x + t dx it stays
    // above kCcdGapFraction of its start while t |dx_i| <= (1 - kCcdGapFraction) d_i(x) (and beyond that, the
    // advancement repeats from the new point, as additive CCD does; Li et al. 2021).
    const double rim = p[rim_];
    double alpha = 1.0;
    for (const auto& v : setup_->vertices) {
      const int i = v[0];
      const Eigen::Vector3d d = dx.segment<3>(3 * i);
      const double len = d.norm();
      if (len == 0) continue;
      Eigen::Vector3d xi = x.segment<3>(3 * i);
      const double d0 = setup_->distance(xi.data(), rim);
      double t = 0;
      for (int it = 0; it < 64 && t < alpha; ++it) {
        const Eigen::Vector3d y = xi + t * d;
        const double dist = setup_->distance(y.data(), rim);
        if (dist <= kCcdGapFraction * d0) break;
        t += (dist - kCcdGapFraction * d0) / len;
        if (t >= alpha) {
          t = alpha;
          break;
        }
      }
      alpha = std::min(alpha, t);
    }
    return alpha;
  }

 private:
  std::shared_ptr<const DiskSetup> setup_;
  int rim_;
};

class DiskFrictionTerm : public ElementTerm<DiskFrictionTerm, 1, 1, 3> {
 public:
  DiskFrictionTerm(const EffectContext& c, std::shared_ptr<const DiskSetup> setup)
      : setup_(std::move(setup)),
        friction_(c.layout.block(effect_block_name("disk_contact", "friction")).offset),
        rim_(c.layout.block(effect_block_name("disk_contact", "rim_radius_m")).offset) {
    const size_t n = setup_->vertices.size();
    start_.assign(n, Eigen::Vector3d::Zero());
    projector_.assign(n, Eigen::Matrix3d::Zero());
    normal_force_.assign(n, 0.0);
    start_geometry_.assign(n, {});
  }
  std::string name() const override { return "disk_friction"; }
  bool is_contact() const override { return true; }
  int num_elements() const { return static_cast<int>(setup_->vertices.size()); }
  const std::array<int, 1>& element_vertices(int e) const { return setup_->vertices[e]; }
  int parameter_offset(int) const { return friction_; }

  void begin_step(const Eigen::VectorXd& x, const Eigen::VectorXd& p, double h) override {
    eps_u_ = kSlipSpeed * h;
    const double rim = p[rim_];
    for (size_t e = 0; e < setup_->vertices.size(); ++e) {
      const int i = setup_->vertices[e][0];
      start_[e] = x.segment<3>(3 * i);
      normal_force_[e] = 0;
      projector_[e].setZero();
      if (h <= 0) continue;
      double d, g[3], H[9];
      distance_gradient_hessian<3>([&](const auto* y) { return setup_->distance(y, decltype(y[0])(rim)); },
                                   start_[e].data(), d, g, H);
      if (!(d > 0 && d < kActivation)) continue;
      start_geometry_[e][0] = d;  // for add_step_start_adjoint
      std::copy(g, g + 3, start_geometry_[e].begin() + 1);
      std::copy(H, H + 9, start_geometry_[e].begin() + 4);
      double b, db, d2b;
      barrier_derivatives(d, kActivation, b, db, d2b);
      normal_force_[e] = setup_->kappa[e] * std::abs(db);
      const Eigen::Vector3d n = Eigen::Vector3d(g[0], g[1], g[2]).normalized();
      projector_[e] = Eigen::Matrix3d::Identity() - n * n.transpose();
    }
  }

  // The energy is a function of x - x_t (the slip's start) and of the lagged normal force and projector, which
  // are functions of x_t too (lambda = kappa |b'(d(x_t))|, n = grad d(x_t) / |grad d(x_t)|): the x_t-derivative
  // of lambda . grad E + c lambda^T K w at fixed x is minus its x-derivatives (the slip's start) plus its
  // derivative through lambda and P (3-variable jets over x_t, with grad d and Hess d of the distance).
  void add_step_start_adjoint(const Eigen::VectorXd& x, const Eigen::VectorXd& p, const Eigen::VectorXd& lambda,
                              const Eigen::VectorXd& w, double c, Eigen::VectorXd& gxt) const override {
    const double mu = p[friction_];
    if (mu == 0) return;
    Eigen::VectorXd d = Eigen::VectorXd::Zero(gxt.size()), unused = Eigen::VectorXd::Zero(p.size());
    add_hessian_product(x, p, lambda, d);
    if (c != 0) add_step_matrix_derivatives(x, p, lambda, w, c, d, unused);
    gxt -= d;
    using J = Jet<double, 3>;
    for (size_t e = 0; e < setup_->vertices.size(); ++e) {
      if (normal_force_[e] == 0) continue;
      const int i = setup_->vertices[e][0];
      const double dist = start_geometry_[e][0];
      const double *g = start_geometry_[e].data() + 1, *H = start_geometry_[e].data() + 4;
      // d, grad d as jets in x_t
      J dj(dist), gj[3];
      for (int a = 0; a < 3; ++a) {
        dj.v[a] = g[a];
        gj[a] = J(g[a]);
        for (int b = 0; b < 3; ++b) gj[a].v[b] = H[3 * a + b];
      }
      // lambda = -kappa b'(d) (b' < 0 inside the reach), b' / dhat^2 as in barrier_derivatives
      const J ed = dj - kActivation;
      const J db = (-2.0 * ed * log_of(dj / kActivation) - ed * ed / dj) / (kActivation * kActivation);
      const J force = -setup_->kappa[e] * db;
      using std::sqrt;
      const J gn = sqrt(gj[0] * gj[0] + gj[1] * gj[1] + gj[2] * gj[2]);
      J nj[3], P[9];
      for (int a = 0; a < 3; ++a) nj[a] = gj[a] / gn;
      for (int a = 0; a < 3; ++a)
        for (int b = 0; b < 3; ++b) P[3 * a + b] = (a == b ? 1.0 : 0.0) - nj[a] * nj[b];
      const Eigen::Vector3d slip = x.segment<3>(3 * i) - start_[e];  // held: its x_t part is the term above
      J u[3], Pl[3], Pw[3];
      for (int a = 0; a < 3; ++a) {
        u[a] = J(0.0);
        Pl[a] = J(0.0);
        Pw[a] = J(0.0);
        for (int b = 0; b < 3; ++b) {
          u[a] = u[a] + P[3 * a + b] * slip[b];
          Pl[a] = Pl[a] + P[3 * a + b] * lambda[3 * i + b];
          Pw[a] = Pw[a] + P[3 * a + b] * w[3 * i + b];
        }
      }
      const J u2 = u[0] * u[0] + u[1] * u[1] + u[2] * u[2];
      J phi(0.0);
      if (u2.a < 1e-20 * eps_u_ * eps_u_) {
        for (int a = 0; a < 3; ++a) phi = phi + (2.0 / eps_u_) * Pl[a] * (u[a] + c * Pw[a]);
      } else {
        const J un = sqrt(u2);
        J f1_over_u, df1;
        if (un.a >= eps_u_) {
          f1_over_u = 1.0 / un;
          df1 = J(0.0);
        } else {
          f1_over_u = -un / (eps_u_ * eps_u_) + 2.0 / eps_u_;
          df1 = -2.0 * un / (eps_u_ * eps_u_) + 2.0 / eps_u_;
        }
        J lu(0.0), wu(0.0), lw(0.0);
        for (int a = 0; a < 3; ++a) {
          lu = lu + Pl[a] * u[a];
          wu = wu + Pw[a] * u[a];
          lw = lw + Pl[a] * Pw[a];
        }
        // (P l) . f1/u u + c (P l)^T [f1/u (I - u u^T/u^2) + f1' u u^T/u^2] (P w)
        phi = f1_over_u * lu + c * (f1_over_u * (lw - lu * wu / u2) + df1 * lu * wu / u2);
      }
      const J total = mu * force * phi;
      for (int a = 0; a < 3; ++a) gxt[3 * i + a] += total.v[a];
    }
  }

  template <class T>
  T element_energy(int e, const T* x, const T* p) const {
    if (normal_force_[e] == 0) return T(0.0);
    T u2 = T(0.0);
    for (int a = 0; a < 3; ++a) {
      T ua = T(0.0);
      for (int b = 0; b < 3; ++b) ua += projector_[e](a, b) * (x[b] - start_[e][b]);
      u2 += ua * ua;
    }
    // f0 smooth in u^2 near zero slip (its odd term u^3 / (3 eps^2) is below round-off there)
    if (value_of(u2) < 1e-20 * eps_u_ * eps_u_) return p[0] * normal_force_[e] * (eps_u_ / 3.0 + u2 / eps_u_);
    using std::sqrt;
    return p[0] * normal_force_[e] * friction_f0(sqrt(u2), eps_u_);
  }
  // r = P (x - x_t); S = mu lambda [f1(u)/u (I - r r^T/u^2) + f1'(u) r r^T/u^2], PSD since f1 >= 0, f1' >= 0.
  template <class T>
  void element_gauss_newton(int e, const T* x, const T* p, T* r, T* S) const {
    for (int a = 0; a < 3; ++a) {
      r[a] = T(0.0);
      for (int b = 0; b < 3; ++b) r[a] += projector_[e](a, b) * (x[b] - start_[e][b]);
    }
    for (int k = 0; k < 9; ++k) S[k] = T(0.0);
    if (normal_force_[e] == 0) return;
    const T scale = p[0] * normal_force_[e];
    const T u2 = r[0] * r[0] + r[1] * r[1] + r[2] * r[2];
    using std::sqrt;
    if (value_of(u2) < 1e-20 * eps_u_ * eps_u_) {
      for (int a = 0; a < 3; ++a) S[4 * a] = scale * (2.0 / eps_u_);
      return;
    }
    const T u = sqrt(u2);
    T f1_over_u, df1;
    if (value_of(u) >= eps_u_) {
      f1_over_u = 1.0 / u;
      df1 = T(0.0);
    } else {
      f1_over_u = -u / (eps_u_ * eps_u_) + 2.0 / eps_u_;
      df1 = -2.0 * u / (eps_u_ * eps_u_) + 2.0 / eps_u_;
    }
    for (int a = 0; a < 3; ++a)
      for (int b = 0; b < 3; ++b) {
        const T rr = r[a] * r[b] / u2;
        S[3 * a + b] = scale * (f1_over_u * ((a == b ? 1.0 : 0.0) - rr) + df1 * rr);
      }
  }

 private:
  std::shared_ptr<const DiskSetup> setup_;
  int friction_, rim_;
  double eps_u_ = 0;
  std::vector<Eigen::Vector3d> start_;
  std::vector<Eigen::Matrix3d> projector_;
  std::vector<double> normal_force_;
  std::vector<std::array<double, 13>> start_geometry_;  // d, grad d, Hess d at the step's start (normal force > 0)
};

}  // namespace

EffectSpec make_disk_contact_effect() {
  EffectSpec s;
  s.name = "disk_contact";
  s.explanation = "the specimen lies on the support disk with friction, held only by a small centre clamp";
  s.signature = "a wider, softer rim transition: folds start inside the disk edge and the drape coefficient falls";
  s.parameters = {
      // Structural (which vertices the clamp holds): a switch for the diagnosis; the default clamp is 2 cm.
      {"clamp_radius_m", "m", 0.09, 0.005, 0.09, 0.02, 0.02, "radius of the centre clamp holding the specimen", true},
      {"friction", "1", 0.3, 0.0, 2.0, 0.2, 0.6, "Coulomb friction coefficient between fabric and disk"},
      {"rim_radius_m", "m", 0.002, 0.0005, 0.01, 0.002, 0.004, "rounding radius of the support disk's edge"},
  };
  s.change_base_terms = [](const EffectContext& c, BaseTermChanges& changes) {
    const double clamp = clamp_radius(c);
    if (clamp < c.options.support_radius) changes.handle_radius = clamp;
  };
  s.make_terms = [](const EffectContext& c) {
    std::vector<std::unique_ptr<Term>> terms;
    auto setup = std::make_shared<const DiskSetup>(c);
    if (setup->vertices.empty()) return terms;  // the clamp covers the disk: the base model
    terms.push_back(std::make_unique<DiskBarrierTerm>(c, setup));
    terms.push_back(std::make_unique<DiskFrictionTerm>(c, setup));
    return terms;
  };
  return s;
}

}  // namespace drapelab
