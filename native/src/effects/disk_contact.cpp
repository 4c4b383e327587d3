// Effect "disk_contact": the specimen lies on the Cusick support disk and bends over its rounded rim, with
// Coulomb friction, held only by a small centre clamp of radius `clamp_radius_m` instead of the base model's
// rigid handle over the whole 9 cm disk. Off value: a clamp as large as the support disk (the base model).
//
// Contact is the IPC barrier (contact/barrier.hpp) on the distance of each free vertex over the disk to the
// disk's surface (contact/distance.hpp SupportDisk: a plate whose rim is rounded with radius `rim_radius_m`):
//   E_i = kappa_i b(d_i),  kappa_i = kWeightScale * w_i * rho * g * dhat   [J]
// (w_i the vertex's area weight, rho the model's nominal density: with kWeightScale = 5 the barrier carries about
// five times the vertex's weight at d = dhat / 2, and a vertex resting on the face with its own weight only sits
// 0.38 mm above it). The disk's top face lies dhat below the flat rest state, so the rest state feels no force.
// Friction is IPC's lagged, smoothed Coulomb potential (Li et al. 2020, sec. 5): with the normal force
// lambda_i = |dE_i/dd| and the tangent projector P_i = I - n_i n_i^T taken at the start of each time step
// (x_t), D_i = mu lambda_i f0(|P_i (x_i - x_t,i)|, eps_v h) [J]; f0 smooths the stick-slip switch over a slip
// speed eps_v. The lagging is IPC's approximation: within a step the normal force and the tangent plane are
// those of its start. The adjoint differentiates them in x_t (add_step_start_adjoint), not in the rim radius
// (its gradient misses their part). A static drape has no friction.
// Every free vertex (rest radius outside the clamp, those beyond the rim too) has this barrier, and so has every
// edge between two free vertices (DiskEdgeBarrierTerm): E_e = kappa_e m b(d_e) with d_e the segment's clearance
// at an interior minimiser over the rounded rim (contact/disk_edge.hpp: exact gradient and Hessian through the
// implicit minimiser), kappa_e = kWeightScale (w_a + w_b) / 6 rho g dhat, and m a C2 smooth step of how far the
// edge dips below its ends' distances (0 when the minimum is at an end or level with it: the vertex barrier's
// case; 1 from a dip of kEdgeDip = 0.1 mm far from the disk, of the edge's own clearance near contact), so a cloth
// edge cannot cut the rim between two vertices however
// coarse the mesh. The edges have no friction (the vertices' friction acts on the same contact; an edge's
// lagged friction is not modelled). Collision detection bounds every step for vertices and edges alike
// (conservative advancement on each one's clearance, kCcdGapFraction).
#include <algorithm>
#include <array>
#include <cmath>

#include "contact/barrier.hpp"
#include "contact/disk_edge.hpp"
#include "contact/distance.hpp"
#include "physics/effect.hpp"
#include "physics/element_term.hpp"
#include "physics/model.hpp"

namespace drapelab {
namespace {

constexpr double kActivation = 5e-4;     // dhat [m]: the barrier acts within 0.5 mm of the disk
// Barrier stiffness in units of the vertex's weight (see header). The rim carries the hanging skirt's tension,
// tens of its edges' weights on circle3 (more on finer meshes), so this sets how far cloth wrapped over the rim
// stays from it: an edge carrying 50 of its weights sits at 61 um (11 um with a scale of 1, 36 um with 3). At a
// clearance far below a linearised move's second-order geometry (an edge tilting about its contact point on the
// 2 mm rim loses rho theta^2 / 2: 0.05-0.2 um per iteration while the drape lands) collision detection cuts
// the move, and the step iterates again: with a scale of 1, wrapped edges were pushed to 1e-8 m and 27-68 of
// circle3's 100 steps took extra iterations; with 5, 4 in steps 0-1, the skirt's first fall (lab/contact-speed.md,
// helper C19).
constexpr double kWeightScale = 5.0;
constexpr double kSlipSpeed = 1e-3;      // eps_v [m/s]: below this slip speed friction is smoothed (static)
constexpr double kCcdGapFraction = 0.1;  // a step may close at most 90 % of a vertex's (edge's) distance to the disk
constexpr double kEdgeDip = 1e-4;        // [m] the edge term fades in as its minimum dips below its ends' distances
                                         // (over min(0.1 mm, d_e) in effect: contact/disk_edge.hpp edge_dip_weight)

double clamp_radius(const EffectContext& c) {
  const auto it = c.options.effects.find("disk_contact");
  if (it != c.options.effects.end()) {
    const auto q = it->second.find("clamp_radius_m");
    if (q != it->second.end()) return q->second;
  }
  return find_effect("disk_contact").parameters[0].off;
}

// The free vertices and edges, the disk's geometry and their barrier stiffnesses (shared by the terms).
struct DiskSetup {
  std::vector<std::array<int, 1>> vertices;
  std::vector<double> kappa;
  std::vector<std::array<int, 2>> edges;
  std::vector<double> edge_kappa;
  SupportDisk disk;
  DiskSetup(const EffectContext& c) {
    const double clamp = clamp_radius(c), support = c.options.support_radius;
    double top = 0;
    for (int v : c.handle_vertices) top += c.mesh.positions(v, 2);
    top /= std::max<size_t>(1, c.handle_vertices.size());
    disk.radius = support;
    disk.top = top - kActivation;
    const double unit = kWeightScale * c.options.density * c.options.gravity * kActivation;
    // Every free vertex (rest radius outside the clamp; those beyond the rim too: a hanging vertex may swing
    // back under it). A vertex beyond the barrier's reach costs one distance evaluation.
    std::vector<char> free(c.mesh.num_vertices(), 0);
    for (int i = 0; i < c.mesh.num_vertices(); ++i) {
      if (c.mesh.uv.row(i).norm() >= clamp) {
        free[i] = 1;
        vertices.push_back({i});
        kappa.push_back(unit * c.area_weights[i]);
      }
    }
    if (vertices.empty()) return;
    // Every mesh edge between two free vertices, once; its stiffness is a third of its ends' mean weight
    // (a vertex has about six edges, each shared by two vertices: the edges around a vertex carry about its
    // weight, like its own vertex barrier).
    std::vector<std::array<int, 2>> all;
    all.reserve(3 * c.mesh.num_faces());
    for (int f = 0; f < c.mesh.num_faces(); ++f)
      for (int k = 0; k < 3; ++k) {
        int a = c.mesh.faces(f, k), b = c.mesh.faces(f, (k + 1) % 3);
        if (a > b) std::swap(a, b);
        if (free[a] && free[b]) all.push_back({a, b});
      }
    std::sort(all.begin(), all.end());
    all.erase(std::unique(all.begin(), all.end()), all.end());
    edges = std::move(all);
    for (const auto& e : edges) edge_kappa.push_back(unit * (c.area_weights[e[0]] + c.area_weights[e[1]]) / 6.0);
  }
  SupportDisk disk_with_rim(double rim) const {
    SupportDisk d = disk;
    d.rim_radius = rim;
    return d;
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

// d(lambda^T K w)/d(rim) of a barrier term K_e = J_r^T S J_r whose residuals r (M of them) depend on the rim
// radius (the torus normal turns with it): ElementTerm's generic version differentiates S only (element_term.hpp
// assumes residuals independent of p), so these terms add, over a, b, S_ab' (J_a.l)(J_b.w) +
// S_ab (J_a'.l)(J_b.w) + S_ab (J_a.l)(J_b'.w) themselves, with jets over (l, w) inside a jet over the rim.
template <class Term, int D, int M>
void add_rim_step_matrix_derivative(const Term& term, const std::vector<std::array<int, D / 3>>& elements,
                                    const Eigen::VectorXd& x, const Eigen::VectorXd& p, int rim,
                                    const Eigen::VectorXd& lambda, const Eigen::VectorXd& w, double scale,
                                    Eigen::VectorXd& gp) {
  using In = Jet<double, 2>;
  using U = Jet<In, 1>;
  U xe[D], pe[1], r[M], S[M * M];
  for (size_t e = 0; e < elements.size(); ++e) {
    for (int i = 0; i < D; ++i) {
      const int dof = 3 * elements[e][i / 3] + i % 3;
      In inner(x[dof]);
      inner.v[0] = lambda[dof];
      inner.v[1] = w[dof];
      xe[i] = U(0.0);
      xe[i].a = inner;
    }
    pe[0] = U(0.0);
    pe[0].a = In(p[rim]);
    pe[0].v[0] = In(1.0);
    term.template element_gauss_newton<U>(static_cast<int>(e), xe, pe, r, S);
    double sum = 0;
    for (int a = 0; a < M; ++a)
      for (int b = 0; b < M; ++b) {
        const double Jl = r[a].a.v[0], Jw = r[b].a.v[1], Sab = S[a * M + b].a.a;
        sum += S[a * M + b].v[0].a * Jl * Jw + Sab * (r[a].v[0].v[0] * Jw + Jl * r[b].v[0].v[1]);
      }
    gp[rim] += scale * sum;
  }
}

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

  void add_step_matrix_derivatives(const Eigen::VectorXd& x, const Eigen::VectorXd& p, const Eigen::VectorXd& lambda,
                                   const Eigen::VectorXd& w, double scale, Eigen::VectorXd& gx,
                                   Eigen::VectorXd& gp) const override {
    Eigen::VectorXd partial = Eigen::VectorXd::Zero(p.size());  // the generic p part (S only): replaced below
    ElementTerm::add_step_matrix_derivatives(x, p, lambda, w, scale, gx, partial);
    add_rim_step_matrix_derivative<DiskBarrierTerm, D, 1>(*this, setup_->vertices, x, p, rim_, lambda, w, scale, gp);
  }

  // The adjoint and the forward's gradient and K v visit only the vertices within the barrier's reach at x
  // (NearDiskVertices below: the same element functions, so the same values bit for bit; the others contribute
  // exact zeros); the step matrix still visits every vertex (its scatter map belongs to this term).
  bool add_step_adjoint(const Eigen::VectorXd& x, const Eigen::VectorXd& p, const Eigen::VectorXd& lambda,
                        const Eigen::VectorXd& w, double h, Eigen::VectorXd& gx, Eigen::VectorXd& gv,
                        Eigen::VectorXd& gp) const override;
  bool add_step_system(const Eigen::VectorXd& x, const Eigen::VectorXd& p, const Eigen::VectorXd& v, double scale,
                       Eigen::VectorXd& values, Eigen::VectorXd& Kv, Eigen::VectorXd& g) const override;
  // Indices of the vertices whose energy is not identically zero near x (distance below the reach).
  std::vector<int> near_vertices(const Eigen::VectorXd& x, const Eigen::VectorXd& p) const {
    std::vector<int> ids;
    const double rim = p[rim_];
    for (size_t e = 0; e < setup_->vertices.size(); ++e)
      if (!(setup_->distance(x.data() + 3 * setup_->vertices[e][0], rim) >= kActivation))
        ids.push_back(static_cast<int>(e));
    return ids;
  }

  double max_step(const Eigen::VectorXd& x, const Eigen::VectorXd& dx, const Eigen::VectorXd& p) const override {
    // Conservative advancement (contact/disk_edge.hpp support_disk_point_advance): the distance to the disk is
    // convex, so along x + t dx it falls no faster than the move's component against the normal; the move may
    // close at most (1 - kCcdGapFraction) of the start's distance, and each round certifies a further stretch
    // from where the last ended (as additive CCD does; Li et al. 2021).
    const SupportDisk disk = setup_->disk_with_rim(p[rim_]);
    double alpha = 1.0;
    for (const auto& v : setup_->vertices) {
      const int i = v[0];
      const double* d = dx.data() + 3 * i;
      if (d[0] == 0 && d[1] == 0 && d[2] == 0) continue;
      const double* xi = x.data() + 3 * i;
      const double d0 = support_disk_distance(disk, xi);
      alpha = std::min(alpha, support_disk_point_advance(disk, xi, d, alpha, kCcdGapFraction * d0));
    }
    return alpha;
  }

 private:
  std::shared_ptr<const DiskSetup> setup_;
  int rim_;
};

// The edge barrier: E_e = kappa_e m b(d_e), with d_e the clearance of the segment to the disk at an interior
// minimiser t* (contact/disk_edge.hpp) and m = q(dip_a / s) q(dip_b / s) with dip_a = d(x_a) - d_e,
// dip_b = d(x_b) - d_e, 1 / s = 1 / kEdgeDip + 1 / d_e (contact/disk_edge.hpp edge_dip_weight): an edge counts
// only as far as it dips below what its ends' vertex barriers already see, so a minimum moving to an end, or an
// edge lying level over the face (its minimum a plateau that reaches an end), hands over to the vertex term
// continuously (C1; C2 where the vertex distances are) without double counting. At contact (d_e -> 0 inside, the
// ends still apart) both dips are positive and s -> 0, so m -> 1 and E_e -> infinity: the barrier guarantee holds
// for the whole segment. (With a fixed scale s = kEdgeDip an edge pressed onto the rim near one end, dipping a few
// um below it, had m ~ 1e-5: its barrier balanced the load only at nanometre clearances, which the linearised
// steps marched it to, each move cut by collision detection.)
class DiskEdgeBarrierTerm : public ElementTerm<DiskEdgeBarrierTerm, 2, 1, 2> {
 public:
  DiskEdgeBarrierTerm(const EffectContext& c, std::shared_ptr<const DiskSetup> setup)
      : setup_(std::move(setup)), rim_(c.layout.block(effect_block_name("disk_contact", "rim_radius_m")).offset) {}
  std::string name() const override { return "disk_edge_contact"; }
  bool is_contact() const override { return true; }
  int num_elements() const { return static_cast<int>(setup_->edges.size()); }
  const std::array<int, 2>& element_vertices(int e) const { return setup_->edges[e]; }
  int parameter_offset(int) const { return rim_; }

  // The interior minimum when it may be within reach (cheap exclusion first: the distance is 1-Lipschitz, so
  // the segment is at least min(d(a), d(b)) - |b - a| / 2 away).
  template <class T>
  bool active(const T* x, const T& rim, SegmentDiskMinimum& m) const {
    double a[3], b[3];
    for (int k = 0; k < 3; ++k) {
      a[k] = value_of(x[k]);
      b[k] = value_of(x[3 + k]);
    }
    const SupportDisk disk = setup_->disk_with_rim(value_of(rim));
    // Both ends inside the cylinder r <= R - rho: so is the whole segment, over which f has no interior
    // minimum over the rim (segment_support_disk_minimum's `interior` is false).
    const double inner = disk.radius - disk.rim_radius;
    if (a[0] * a[0] + a[1] * a[1] <= inner * inner && b[0] * b[0] + b[1] * b[1] <= inner * inner) return false;
    const double half = 0.5 * std::sqrt((b[0] - a[0]) * (b[0] - a[0]) + (b[1] - a[1]) * (b[1] - a[1]) +
                                        (b[2] - a[2]) * (b[2] - a[2]));
    if (std::min(support_disk_distance(disk, a), support_disk_distance(disk, b)) - half >= kActivation) return false;
    m = segment_support_disk_minimum(disk, a, b);
    return m.interior && m.distance < kActivation;
  }

  template <class T>
  T element_energy(int e, const T* x, const T* p) const {
    SegmentDiskMinimum m;
    if (!active(x, p[0], m)) return T(0.0);
    return energy_at(e, x, p, m);
  }
  // The energy of an active edge (active() true) with its minimum m, found once by the caller.
  template <class T>
  T energy_at(int e, const T* x, const T* p, const SegmentDiskMinimum& m) const {
    if (!(m.distance > 0)) return T(std::numeric_limits<double>::infinity());
    T t;
    const T d = segment_support_disk_distance(setup_->disk, x, x + 3, p[0], m.t, t);
    if (!(value_of(d) > 0)) return T(std::numeric_limits<double>::infinity());
    return setup_->edge_kappa[e] * weight(x, p[0], d) * barrier(d, kActivation);
  }
  template <class T>
  T weight(const T* x, const T& rim, const T& d) const {
    return edge_dip_weight(setup_->distance(x, rim) - d, d, kEdgeDip) *
           edge_dip_weight(setup_->distance(x + 3, rim) - d, d, kEdgeDip);
  }
  // Step matrix: the energy's Hessian is kappa_e m [b''(d) grad d grad d^T + b'(d) Hess d_e] + the weight's
  // terms, with Hess d_e = f_xx - f_xt f_tt^-1 f_tx = f_xx - f_tt grad t* grad t*^T (contact/disk_edge.hpp; the
  // minimiser's gradient is grad t* = -f_tx / f_tt). As b' < 0 inside the reach, b' f_xx is negative
  // semidefinite (f_xx is the Hessian of a convex distance at fixed t) and -b' f_tt grad t* grad t*^T is positive
  // semidefinite. The step matrix keeps both PSD parts: residuals r = (d_e, t*),
  //   S = diag(kappa_e m b''(d_e), kappa_e m |b'(d_e)| f_tt) >= 0;
  // dropped: b' f_xx and the weight's derivative terms. The second part is the clearance's loss when the edge
  // tilts about its contact point (its minimiser slides along it: the chord cuts into the rounded rim at second
  // order, rho theta^2 / 2), which the first alone does not see: without it a linearised move tilts edges that
  // wrap the rim into it, and collision detection cuts the move.
  template <class T>
  void element_gauss_newton(int e, const T* x, const T* p, T* r, T* S) const {
    SegmentDiskMinimum m;
    for (int k = 0; k < 2; ++k) r[k] = T(0.0);
    for (int k = 0; k < 4; ++k) S[k] = T(0.0);
    if (!active(x, p[0], m)) return;
    gauss_newton_at(e, x, p, m, r, S);
  }
  // element_gauss_newton of an active edge with its minimum m, r and S zero on entry.
  template <class T>
  void gauss_newton_at(int e, const T* x, const T* p, const SegmentDiskMinimum& m, T* r, T* S) const {
    if (!(m.distance > 0)) return;
    T t, ftt;
    const T d = segment_support_disk_distance(setup_->disk, x, x + 3, p[0], m.t, t, &ftt);
    r[0] = d;
    r[1] = t;
    if (!(value_of(d) > 0) || value_of(d) >= kActivation) return;
    const T e1 = d - kActivation;
    const T l = log_of(d / kActivation);
    const T scale = setup_->edge_kappa[e] * weight(x, p[0], d) / (kActivation * kActivation);
    S[0] = scale * (-2.0 * l - 4.0 * e1 / d + e1 * e1 / (d * d));  // kappa_e m b''(d)
    S[3] = scale * (2.0 * e1 * l + e1 * e1 / d) * ftt;             // kappa_e m |b'(d)| f_tt
  }

  void add_step_matrix_derivatives(const Eigen::VectorXd& x, const Eigen::VectorXd& p, const Eigen::VectorXd& lambda,
                                   const Eigen::VectorXd& w, double scale, Eigen::VectorXd& gx,
                                   Eigen::VectorXd& gp) const override {
    Eigen::VectorXd partial = Eigen::VectorXd::Zero(p.size());  // the generic p part (S only): replaced below
    ElementTerm::add_step_matrix_derivatives(x, p, lambda, w, scale, gx, partial);
    add_rim_step_matrix_derivative<DiskEdgeBarrierTerm, D, 2>(*this, setup_->edges, x, p, rim_, lambda, w, scale, gp);
  }

  // The adjoint and the forward's gradient and K v visit only the edges active at x (NearDiskEdges below: the
  // same element functions, so the same values bit for bit; the others contribute exact zeros); the step
  // matrix still visits every edge (its scatter map belongs to this term).
  bool add_step_adjoint(const Eigen::VectorXd& x, const Eigen::VectorXd& p, const Eigen::VectorXd& lambda,
                        const Eigen::VectorXd& w, double h, Eigen::VectorXd& gx, Eigen::VectorXd& gv,
                        Eigen::VectorXd& gp) const override;
  bool add_step_system(const Eigen::VectorXd& x, const Eigen::VectorXd& p, const Eigen::VectorXd& v, double scale,
                       Eigen::VectorXd& values, Eigen::VectorXd& Kv, Eigen::VectorXd& g) const override;
  // Indices of the edges whose energy is not identically zero near x (active() on the values), and (if minima is
  // given) their minima.
  std::vector<int> active_edges(const Eigen::VectorXd& x, const Eigen::VectorXd& p,
                                std::vector<SegmentDiskMinimum>* minima = nullptr) const {
    std::vector<int> ids;
    const double rim = p[rim_];
    SegmentDiskMinimum m;
    double xe[6];
    for (size_t e = 0; e < setup_->edges.size(); ++e) {
      const auto& v = setup_->edges[e];
      for (int k = 0; k < 3; ++k) {
        xe[k] = x[3 * v[0] + k];
        xe[3 + k] = x[3 * v[1] + k];
      }
      if (active(xe, rim, m)) {
        ids.push_back(static_cast<int>(e));
        if (minima) minima->push_back(m);
      }
    }
    return ids;
  }
  const std::shared_ptr<const DiskSetup>& setup() const { return setup_; }

  double max_step(const Eigen::VectorXd& x, const Eigen::VectorXd& dx, const Eigen::VectorXd& p) const override {
    // Conservative advancement on the segment's clearance (ends included; contact/disk_edge.hpp
    // support_disk_segment_advance): every point of the segment moves on a line, along which the distance to the
    // disk is convex, so each point's clearance falls no faster than its move against its normal; bounded over
    // the segment by intervals of its parameter, this lets an edge sliding or rolling over the rim take the whole
    // move, while the clearance stays above kCcdGapFraction of its start.
    const SupportDisk disk = setup_->disk_with_rim(p[rim_]);
    const double inner = disk.radius - disk.rim_radius, zc = disk.top - disk.rim_radius;
    // Over the flat face (inside the cylinder r <= R - rho, above the plate's mid-plane) f is linear along a
    // segment, so its clearance is its ends' (the vertex barrier's, whose collision detection bounds them to
    // the same fraction of their start): an edge whose ends stay there for the whole move needs no check.
    auto over_face = [&](const Eigen::Vector3d& y) { return y[0] * y[0] + y[1] * y[1] <= inner * inner && y[2] >= zc; };
    double alpha = 1.0;
    for (const auto& v : setup_->edges) {
      const Eigen::Vector3d a = x.segment<3>(3 * v[0]), b = x.segment<3>(3 * v[1]);
      const Eigen::Vector3d da = dx.segment<3>(3 * v[0]), db = dx.segment<3>(3 * v[1]);
      const double len = std::max(da.norm(), db.norm());
      if (len == 0) continue;
      if (over_face(a) && over_face(b) && over_face(a + alpha * da) && over_face(b + alpha * db)) continue;
      // cheap: the lower bound min(d(a), d(b)) - |b - a| / 2 already allows the whole step
      const double lower =
          std::min(support_disk_distance(disk, a.data()), support_disk_distance(disk, b.data())) - 0.5 * (b - a).norm();
      if (lower > 0 && alpha * len <= (1.0 - kCcdGapFraction) * lower) continue;
      const double d0 = segment_support_disk_minimum(disk, a.data(), b.data()).distance;
      alpha = std::min(alpha, support_disk_segment_advance(disk, a.data(), b.data(), da.data(), db.data(), alpha,
                                                           kCcdGapFraction * d0));
    }
    return alpha;
  }

 private:
  std::shared_ptr<const DiskSetup> setup_;
  int rim_;
};

// A subset of a parent element term's elements (those active at some x), for the element loops that only scatter
// vectors: element e is the parent's element ids[e], evaluated by the parent's element functions. Derived is the
// concrete view (CRTP), which may add overrides.
template <class Derived, class Parent, int NV, int NP, int NQ>
class ElementSubset : public ElementTerm<Derived, NV, NP, NQ> {
 public:
  ElementSubset(const Parent& parent, std::vector<int> ids) : parent_(parent), ids_(std::move(ids)) {
    verts_.reserve(ids_.size());
    for (int e : ids_) verts_.push_back(parent_.element_vertices(e));
  }
  std::string name() const override { return parent_.name(); }
  bool is_contact() const override { return true; }
  int num_elements() const { return static_cast<int>(ids_.size()); }
  const std::array<int, NV>& element_vertices(int e) const { return verts_[e]; }
  int parameter_offset(int e) const { return parent_.parameter_offset(ids_[e]); }
  template <class T>
  T element_energy(int e, const T* x, const T* p) const {
    return parent_.template element_energy<T>(ids_[e], x, p);
  }
  template <class T>
  void element_gauss_newton(int e, const T* x, const T* p, T* r, T* S) const {
    parent_.template element_gauss_newton<T>(ids_[e], x, p, r, S);
  }

 protected:
  const Parent& parent_;
  std::vector<int> ids_;
  std::vector<std::array<int, NV>> verts_;
};

// The edge barrier's edges active at some x.
class NearDiskEdges : public ElementSubset<NearDiskEdges, DiskEdgeBarrierTerm, 2, 1, 2> {
 public:
  NearDiskEdges(const DiskEdgeBarrierTerm& parent, std::vector<int> ids, int rim)
      : ElementSubset(parent, std::move(ids)), rim_(rim) {}
  void add_step_matrix_derivatives(const Eigen::VectorXd& x, const Eigen::VectorXd& p, const Eigen::VectorXd& lambda,
                                   const Eigen::VectorXd& w, double scale, Eigen::VectorXd& gx,
                                   Eigen::VectorXd& gp) const override {  // as DiskEdgeBarrierTerm's
    Eigen::VectorXd partial = Eigen::VectorXd::Zero(p.size());
    ElementTerm::add_step_matrix_derivatives(x, p, lambda, w, scale, gx, partial);
    add_rim_step_matrix_derivative<NearDiskEdges, D, 2>(*this, verts_, x, p, rim_, lambda, w, scale, gp);
  }

 private:
  int rim_;
};

// The disk barrier's vertices within reach at some x.
class NearDiskVertices : public ElementSubset<NearDiskVertices, DiskBarrierTerm, 1, 1, 1> {
 public:
  NearDiskVertices(const DiskBarrierTerm& parent, std::vector<int> ids, int rim)
      : ElementSubset(parent, std::move(ids)), rim_(rim) {}
  void add_step_matrix_derivatives(const Eigen::VectorXd& x, const Eigen::VectorXd& p, const Eigen::VectorXd& lambda,
                                   const Eigen::VectorXd& w, double scale, Eigen::VectorXd& gx,
                                   Eigen::VectorXd& gp) const override {  // as DiskBarrierTerm's
    Eigen::VectorXd partial = Eigen::VectorXd::Zero(p.size());
    ElementTerm::add_step_matrix_derivatives(x, p, lambda, w, scale, gx, partial);
    add_rim_step_matrix_derivative<NearDiskVertices, D, 1>(*this, verts_, x, p, rim_, lambda, w, scale, gp);
  }

 private:
  int rim_;
};

bool DiskBarrierTerm::add_step_adjoint(const Eigen::VectorXd& x, const Eigen::VectorXd& p,
                                       const Eigen::VectorXd& lambda, const Eigen::VectorXd& w, double h,
                                       Eigen::VectorXd& gx, Eigen::VectorXd& gv, Eigen::VectorXd& gp) const {
  const NearDiskVertices near(*this, near_vertices(x, p), rim_);
  return near.Term::add_step_adjoint(x, p, lambda, w, h, gx, gv, gp);
}

bool DiskBarrierTerm::add_step_system(const Eigen::VectorXd& x, const Eigen::VectorXd& p, const Eigen::VectorXd& v,
                                      double scale, Eigen::VectorXd& values, Eigen::VectorXd& Kv,
                                      Eigen::VectorXd& g) const {
  add_step_matrix(x, p, scale, values);
  const NearDiskVertices near(*this, near_vertices(x, p), rim_);
  near.add_gradient(x, p, g);
  return near.add_step_matrix_product(x, p, v, scale, Kv);
}

// Term::add_step_adjoint's four products (and the rim radius part of the step matrix's derivative) in one pass over
// the active edges: each edge's minimiser is found once (by active_edges) and its functions are evaluated twice,
// the energy with jets over (x, rim) around a direction lambda (Hess E lambda and d(lambda . grad E)/drim) and
// the Gauss-Newton residuals and weight with jets over (x, rim) around the directions (lambda, w)
// (d(lambda^T K w)/d(x, rim), and K lambda from their first derivatives), instead of five passes (six
// minimisers) through ElementTerm's loops. Each jet component is computed by the same operations as in those
// loops, and the sums are accumulated in their order, so the result is theirs bit for bit
// (tests/native/contact/test_disk_edge.cpp).
bool DiskEdgeBarrierTerm::add_step_adjoint(const Eigen::VectorXd& x, const Eigen::VectorXd& p,
                                           const Eigen::VectorXd& lambda, const Eigen::VectorXd& w, double h,
                                           Eigen::VectorXd& gx, Eigen::VectorXd& gv, Eigen::VectorXd& gp) const {
  std::vector<SegmentDiskMinimum> minima;
  const std::vector<int> ids = active_edges(x, p, &minima);
  const int ne = static_cast<int>(ids.size());
  constexpr int M = 2;      // residuals
  constexpr int R = D;      // the rim radius's jet component (after the D position components)
  using E1 = Jet<double, 1>;
  using E2 = Jet<E1, D + 1>;
  using K1 = Jet<double, 2>;
  using K2 = Jet<K1, D + 1>;
  Eigen::VectorXd Hl = Eigen::VectorXd::Zero(x.size());
  std::vector<double> gxe(static_cast<size_t>(ne) * D), gp_energy(ne);
  const double c = -h * h;  // the scale of the step matrix's products
  E2 xe[D], pe[1];
  K2 xk[D], pk[1], r[M], S[M * M];
  for (int k = 0; k < ne; ++k) {
    const int e = ids[k];
    const auto& v = setup_->edges[e];
    for (int i = 0; i < D; ++i) {
      const int dof = 3 * v[i / 3] + i % 3;
      E1 inner(x[dof]);
      inner.v[0] = lambda[dof];
      xe[i] = E2(inner);
      xe[i].v[i] = E1(1.0);
      K1 inner2(x[dof]);
      inner2.v[0] = lambda[dof];
      inner2.v[1] = w[dof];
      xk[i] = K2(inner2);
      xk[i].v[i] = K1(1.0);
    }
    pe[0] = E2(p[rim_]);
    pe[0].v[R] = E1(1.0);
    pk[0] = K2(p[rim_]);
    pk[0].v[R] = K1(1.0);
    // Hess E lambda, d(lambda . grad E)/drim
    const E2 E = energy_at<E2>(e, xe, pe, minima[k]);
    for (int i = 0; i < D; ++i) Hl[3 * v[i / 3] + i % 3] += 1.0 * E.v[i].v[0];
    gp_energy[k] = E.v[R].v[0];
    // d(lambda^T K w)/dx as ElementTerm::add_step_matrix_derivatives, d/drim as add_rim_step_matrix_derivative
    for (int a = 0; a < M; ++a) r[a] = K2(0.0);
    for (int a = 0; a < M * M; ++a) S[a] = K2(0.0);
    gauss_newton_at<K2>(e, xk, pk, minima[k], r, S);
    double Jl[M], Jw[M];
    contract_step_matrix_derivative<M, D>(r, S, &gxe[static_cast<size_t>(k) * D], Jl, Jw);
    double sum = 0;
    for (int a = 0; a < M; ++a)
      for (int b = 0; b < M; ++b) {
        const double Sab = S[a * M + b].a.a;
        sum += S[a * M + b].v[R].a * Jl[a] * Jw[b] + Sab * (r[a].v[R].v[0] * Jw[b] + Jl[a] * r[b].v[R].v[1]);
      }
    gp[rim_] += c * sum;
    // K lambda = J_r^T S (J_r lambda), J_r from the residuals' first derivatives
    double Jd[M], SJd[M];
    for (int a = 0; a < M; ++a) {
      double s = 0;
      for (int j = 0; j < D; ++j) s += r[a].v[j].a * lambda[3 * v[j / 3] + j % 3];
      Jd[a] = s;
    }
    for (int a = 0; a < M; ++a) {
      double s = 0;
      for (int b = 0; b < M; ++b) s += S[a * M + b].a.a * Jd[b];
      SJd[a] = s;
    }
    for (int i = 0; i < D; ++i) {
      double s = 0;
      for (int a = 0; a < M; ++a) s += r[a].v[i].a * SJd[a];
      gv[3 * v[i / 3] + i % 3] += c * s;
    }
  }
  gx -= h * Hl;
  for (int k = 0; k < ne; ++k) {
    const auto& v = setup_->edges[ids[k]];
    for (int i = 0; i < D; ++i) gx[3 * v[i / 3] + i % 3] += c * gxe[static_cast<size_t>(k) * D + i];
  }
  for (int k = 0; k < ne; ++k) gp[rim_] += -h * gp_energy[k];
  return true;
}

bool DiskEdgeBarrierTerm::add_step_system(const Eigen::VectorXd& x, const Eigen::VectorXd& p, const Eigen::VectorXd& v,
                                          double scale, Eigen::VectorXd& values, Eigen::VectorXd& Kv,
                                          Eigen::VectorXd& g) const {
  add_step_matrix(x, p, scale, values);
  const NearDiskEdges near(*this, active_edges(x, p), rim_);
  near.add_gradient(x, p, g);
  return near.add_step_matrix_product(x, p, v, scale, Kv);
}

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
  // The adjoint, the start adjoint and the forward's gradient and K v visit only the vertices with a lagged
  // normal force (FrictionVertices below; the others' energy is identically zero within the step): the same
  // values bit for bit.
  bool add_step_adjoint(const Eigen::VectorXd& x, const Eigen::VectorXd& p, const Eigen::VectorXd& lambda,
                        const Eigen::VectorXd& w, double h, Eigen::VectorXd& gx, Eigen::VectorXd& gv,
                        Eigen::VectorXd& gp) const override;
  bool add_step_system(const Eigen::VectorXd& x, const Eigen::VectorXd& p, const Eigen::VectorXd& v, double scale,
                       Eigen::VectorXd& values, Eigen::VectorXd& Kv, Eigen::VectorXd& g) const override;
  const std::vector<int>& active() const { return active_; }
  bool is_contact() const override { return true; }
  int num_elements() const { return static_cast<int>(setup_->vertices.size()); }
  const std::array<int, 1>& element_vertices(int e) const { return setup_->vertices[e]; }
  int parameter_offset(int) const { return friction_; }

  void begin_step(const Eigen::VectorXd& x, const Eigen::VectorXd& p, double h) override {
    eps_u_ = kSlipSpeed * h;
    active_.clear();
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
      active_.push_back(static_cast<int>(e));
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
    add_active_products(x, p, lambda, w, c, d, unused);
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
    return p[0] * normal_force_[e] * friction_f0_of_squared(u2, eps_u_);
  }
  // r = P (x - x_t); S = mu lambda friction_curvature(r) (contact/barrier.hpp: PSD since f1 >= 0, f1' >= 0).
  template <class T>
  void element_gauss_newton(int e, const T* x, const T* p, T* r, T* S) const {
    for (int a = 0; a < 3; ++a) {
      r[a] = T(0.0);
      for (int b = 0; b < 3; ++b) r[a] += projector_[e](a, b) * (x[b] - start_[e][b]);
    }
    for (int k = 0; k < 9; ++k) S[k] = T(0.0);
    if (normal_force_[e] == 0) return;
    const T scale = p[0] * normal_force_[e];
    friction_curvature(r, eps_u_, S);
    for (int k = 0; k < 9; ++k) S[k] = scale * S[k];
  }

 private:
  std::shared_ptr<const DiskSetup> setup_;
  int friction_, rim_;
  double eps_u_ = 0;
  std::vector<Eigen::Vector3d> start_;
  std::vector<Eigen::Matrix3d> projector_;
  std::vector<double> normal_force_;
  std::vector<std::array<double, 13>> start_geometry_;  // d, grad d, Hess d at the step's start (normal force > 0)
  std::vector<int> active_;                             // elements with normal force > 0 this step
  // lambda^T Hess E (x) + c d(lambda^T K w)/dx over the active elements, into d
  void add_active_products(const Eigen::VectorXd& x, const Eigen::VectorXd& p, const Eigen::VectorXd& lambda,
                           const Eigen::VectorXd& w, double c, Eigen::VectorXd& d, Eigen::VectorXd& unused) const;
};

// The friction's vertices with a normal force this step.
class FrictionVertices : public ElementSubset<FrictionVertices, DiskFrictionTerm, 1, 1, 3> {
 public:
  explicit FrictionVertices(const DiskFrictionTerm& parent) : ElementSubset(parent, parent.active()) {}
};

void DiskFrictionTerm::add_active_products(const Eigen::VectorXd& x, const Eigen::VectorXd& p,
                                           const Eigen::VectorXd& lambda, const Eigen::VectorXd& w, double c,
                                           Eigen::VectorXd& d, Eigen::VectorXd& unused) const {
  const FrictionVertices active(*this);
  active.add_hessian_product(x, p, lambda, d);
  if (c != 0) active.add_step_matrix_derivatives(x, p, lambda, w, c, d, unused);
}

bool DiskFrictionTerm::add_step_adjoint(const Eigen::VectorXd& x, const Eigen::VectorXd& p,
                                        const Eigen::VectorXd& lambda, const Eigen::VectorXd& w, double h,
                                        Eigen::VectorXd& gx, Eigen::VectorXd& gv, Eigen::VectorXd& gp) const {
  const FrictionVertices active(*this);
  return active.Term::add_step_adjoint(x, p, lambda, w, h, gx, gv, gp);
}

bool DiskFrictionTerm::add_step_system(const Eigen::VectorXd& x, const Eigen::VectorXd& p, const Eigen::VectorXd& v,
                                       double scale, Eigen::VectorXd& values, Eigen::VectorXd& Kv,
                                       Eigen::VectorXd& g) const {
  add_step_matrix(x, p, scale, values);
  const FrictionVertices active(*this);
  active.add_gradient(x, p, g);
  return active.add_step_matrix_product(x, p, v, scale, Kv);
}

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
    if (clamp_radius(c) >= c.options.support_radius) return terms;  // the clamp covers the disk: the base model
    auto setup = std::make_shared<const DiskSetup>(c);
    if (setup->vertices.empty()) return terms;
    terms.push_back(std::make_unique<DiskBarrierTerm>(c, setup));
    if (!setup->edges.empty()) terms.push_back(std::make_unique<DiskEdgeBarrierTerm>(c, setup));
    terms.push_back(std::make_unique<DiskFrictionTerm>(c, setup));
    return terms;
  };
  return s;
}

}  // namespace drapelab
