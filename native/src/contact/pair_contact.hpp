// A contact term over triangle-mesh pairs: IPC barriers on every point-triangle and edge-edge pair closer than
// the activation distance dhat, between the cloth and itself (self contact, effects/self_contact.cpp) and/or
// between the cloth and an obstacle mesh whose positions are data, not unknowns (contact/obstacle_contact.hpp).
//
// Energy: E(x) = sum over active pairs of kappa_k b(d_k(x)) (contact/pair_barrier.hpp), kappa_k = c_k dhat with
// c_k = kWeightScale * (mean area weight of the pair's cloth vertices) * rho * g: as in disk_contact, the
// barrier carries about a vertex's weight at half the activation distance. The active set is rebuilt from x in
// every call from candidate pairs (broad phase, contact/broad_phase.hpp, with the boxes inflated by 3 dhat, reused
// while no vertex has moved by more than dhat since they were found); the active set is cached per exact x, since
// a Newton iteration evaluates energy, gradient and Hessian at one state.
//
// The model's sparsity pattern is fixed when it is built, but pairs couple vertices far apart in the mesh. The
// term therefore assembles only each pair's diagonal 3x3 vertex blocks (of the exact Hessian in add_hessian, of
// the per-pair PSD projection in add_projected_hessian, of the Gauss-Newton step matrix in add_step_matrix; the diagonal blocks of a PSD
// matrix are PSD, so the assembled matrices stay definite) and gives the rest, the off-diagonal blocks, as a
// product (add_offpattern_hessian_product); add_hessian_product is the full exact product. Solvers combine them
// by conjugate gradients preconditioned with the assembled matrix's factor (solver/contact_linear_solve.hpp).
//
// max_step: the smallest additive-CCD time of impact (contact/ccd.hpp) over the pairs whose swept boxes overlap.
//
// Friction (coefficient mu from friction(p)): IPC's lagged smoothed Coulomb potential per pair, as disk_contact
// has it per vertex. At the start of each time step (begin_step, x_t; none when h = 0: a static drape has no
// friction) every active pair fixes its normal force lambda = kappa |b'(d)|, the barycentric weights of its
// closest points and its normal n; its relative tangential slip over the step is then the linear map
// u = (I - n n^T) Gamma (X - X_t), Gamma the closest points' weights (point minus triangle point, or edge point
// minus edge point), and D = mu lambda f0(|u|, eps_v h) [J]. An obstacle's vertices slip by their own motion over
// the step (set_obstacle's at_t1 - at_t), so a moving body drags the cloth. The lagging is IPC's approximation:
// within a step lambda, the weights and n are those of its start; the adjoint differentiates them in x_t
// (add_step_start_adjoint), not in the thickness (its gradient misses their part). The friction Hessian is
// PSD (f1 >= 0, f1' >= 0) and couples the pair's vertices like the barrier's (diagonal blocks assembled, the rest
// as products).
#pragma once
#include <array>
#include <memory>
#include <mutex>
#include <vector>

#include "contact/broad_phase.hpp"
#include "contact/pair_barrier.hpp"
#include "contact/stepped_contact.hpp"
#include "physics/term.hpp"

namespace drapelab {

struct ActivePair {
  PairKind kind;
  int type;
  std::array<int, 4> v;  // rows of the combined position array (cloth vertices first)
  double c;              // kappa / dhat [J/m]
  double mollifier_eps = 0;  // edge-edge: 1e-3 |e0_rest|^2 |e1_rest|^2 (contact/pair_barrier.hpp)
};

class PairContactTerm : public Term, public SteppedContact {
 public:
  // surfaces: cloth vertices are rows [0, num_cloth) of the combined array, obstacle vertices after them;
  // unit_stiffness: per cloth vertex, c_i = kWeightScale w_i rho g [J/m]; rest: the combined positions at rest
  // (the edge-edge mollifier's scale).
  PairContactTerm(ContactSurfaces surfaces, int num_cloth, std::vector<double> unit_stiffness, PairFilter filter,
                  const ContactPositions& rest);

  bool is_contact() const override { return true; }
  bool has_offpattern_hessian() const override { return true; }
  std::vector<std::vector<int>> stencils() const override { return {}; }  // diagonal blocks only
  void bind_pattern(const SparsePattern& pattern) override;

  double energy(const Eigen::VectorXd& x, const Eigen::VectorXd& p) const override;
  void add_gradient(const Eigen::VectorXd& x, const Eigen::VectorXd& p, Eigen::VectorXd& g) const override;
  void add_step_matrix(const Eigen::VectorXd& x, const Eigen::VectorXd& p, double scale,
                       Eigen::VectorXd& values) const override;
  void add_hessian(const Eigen::VectorXd& x, const Eigen::VectorXd& p, double scale,
                   Eigen::VectorXd& values) const override;
  void add_projected_hessian(const Eigen::VectorXd& x, const Eigen::VectorXd& p, double scale,
                             Eigen::VectorXd& values) const override;
  // The static solve's Newton matrix: the projected diagonal blocks (remainder: projected = true).
  void add_static_newton_matrix(const Eigen::VectorXd& x, const Eigen::VectorXd& p, double scale,
                                Eigen::VectorXd& values) const override {
    add_projected_hessian(x, p, scale, values);
  }
  void add_hessian_product(const Eigen::VectorXd& x, const Eigen::VectorXd& p, const Eigen::VectorXd& dir,
                           Eigen::VectorXd& out) const override;
  void add_offpattern_hessian_product(const Eigen::VectorXd& x, const Eigen::VectorXd& p, const Eigen::VectorXd& dir,
                                      bool projected, Eigen::VectorXd& out) const override;
  void add_energy_parameter_gradient(const Eigen::VectorXd& x, const Eigen::VectorXd& p,
                                     Eigen::VectorXd& gp) const override;
  void add_gradient_parameter_product(const Eigen::VectorXd& x, const Eigen::VectorXd& p,
                                      const Eigen::VectorXd& lambda, double scale, Eigen::VectorXd& gp) const override;
  // The step matrix K (linearised contact steps, solver/implicit_euler.hpp): per pair the barrier's Gauss-Newton
  // matrix s r r^T (contact/pair_barrier.hpp) plus the friction Hessian (PSD). add_step_matrix assembles its
  // diagonal blocks, add_offpattern_step_matrix_product gives the rest, add_step_matrix_derivatives the full
  // K's derivatives in x, dhat and friction (lagged friction quantities held constant).
  void add_offpattern_step_matrix_product(const Eigen::VectorXd& x, const Eigen::VectorXd& p,
                                          const Eigen::VectorXd& dir, Eigen::VectorXd& out) const override;
  void add_step_matrix_derivatives(const Eigen::VectorXd& x, const Eigen::VectorXd& p, const Eigen::VectorXd& lambda,
                                   const Eigen::VectorXd& w, double scale, Eigen::VectorXd& gx,
                                   Eigen::VectorXd& gp) const override;
  // The friction's slip starts at x_t: its part of the x_t-derivative (Term::add_step_start_adjoint).
  void add_step_start_adjoint(const Eigen::VectorXd& x, const Eigen::VectorXd& p, const Eigen::VectorXd& lambda,
                              const Eigen::VectorXd& w, double c, Eigen::VectorXd& gxt) const override;
  double max_step(const Eigen::VectorXd& x, const Eigen::VectorXd& dx, const Eigen::VectorXd& p) const override;
  // A state must start free of intersections: begin_step throws SolverError naming the first intersecting
  // triangle pair (contact/diagnostics.hpp), or the pair through which a moving obstacle's step sweeps.
  void begin_step(const Eigen::VectorXd& x, const Eigen::VectorXd& p, double h) override {
    start_step(x, p, h, true, true);
  }
  // The lagged friction state only (Term::resume_step: no intersection or sweep check).
  void resume_step(const Eigen::VectorXd& x, const Eigen::VectorXd& p, double h) override {
    start_step(x, p, h, false, false);
  }
  // SteppedContact (contact/stepped_contact.hpp): begin_step without the intersection check, unless a moving
  // obstacle may have carried the cloth (obstacle_carry in physics/term.hpp moves it outside the CCD bound); the
  // sweep check stays.
  void continue_step(const Eigen::VectorXd& x, const Eigen::VectorXd& p, double h) override {
    start_step(x, p, h, obstacle_moves(), true);
  }
  // The lagged friction pairs and the active pairs and candidates cached at the step's start.
  std::shared_ptr<const void> step_state() const override;
  void restore_step(const std::shared_ptr<const void>& state) override;
  // The active pairs at the iterate x (those its assembly found), without the candidates.
  std::shared_ptr<const void> iterate_state(const Eigen::VectorXd& x) const override;
  void restore_iterate(const std::shared_ptr<const void>& state, const Eigen::VectorXd& x) override;

  // The pairs closer than dhat at x (cached per x).
  std::vector<ActivePair> active_pairs(const Eigen::VectorXd& x, double dhat) const;
  const ContactSurfaces& surfaces() const { return surfaces_; }
  int num_cloth() const { return num_cloth_; }

 protected:
  // The activation distance from the parameters (self contact: the thickness parameter; obstacle: fixed).
  virtual double dhat(const Eigen::VectorXd& p) const = 0;
  // Where dhat lives in p (-1: not a parameter).
  virtual int dhat_index() const = 0;
  // The friction coefficient and where it lives in p (-1: not a parameter).
  virtual double friction(const Eigen::VectorXd& p) const = 0;
  virtual int friction_index() const = 0;
  // The combined positions: cloth from x, obstacle rows from obstacle_ (end-of-step positions).
  ContactPositions positions(const Eigen::VectorXd& x) const;
  ContactSurfaces surfaces_;
  int num_cloth_;
  ContactPositions obstacle_;        // (rows - num_cloth) x 3: positions within the step (its end)
  ContactPositions obstacle_start_;  // at the step's start (friction: the obstacle's slip over the step)
  std::vector<double> unit_stiffness_;
  std::vector<double> edge_rest_length2_;
  PairFilter filter_;

 private:
  void gather(const ActivePair& q, const ContactPositions& P, double* x12) const;
  [[noreturn]] void throw_intersection(const std::array<int, 2>& faces) const;
  // SolverError if the obstacle's move over the step (obstacle_start_ -> obstacle_) sweeps through the cloth at x.
  void check_obstacle_sweep(const Eigen::VectorXd& x) const;
  void start_step(const Eigen::VectorXd& x, const Eigen::VectorXd& p, double h, bool check_intersections,
                  bool check_sweep);
  bool obstacle_moves() const { return obstacle_.rows() > 0 && !(obstacle_start_ == obstacle_); }
  template <class F>
  void for_each_pair_gauss_newton(const Eigen::VectorXd& x, const Eigen::VectorXd& p, const F& f) const;
  template <class F>
  void for_each_pair_hessian(const Eigen::VectorXd& x, const Eigen::VectorXd& p, bool project, const F& f) const;
  void add_diagonal_blocks(const Eigen::VectorXd& x, const Eigen::VectorXd& p, bool project, double scale,
                           Eigen::VectorXd& values) const;
  struct FrictionPair {
    std::array<int, 4> v;
    Eigen::Matrix<double, 3, 12> T;  // (I - n n^T) Gamma
    Eigen::Matrix<double, 12, 1> start;  // X_t of the pair's vertices (obstacle rows: at the step's start)
    double normal_force;                 // lambda [N]
    // what lambda, n and Gamma were computed from (add_step_start_adjoint differentiates them in X_t)
    PairKind kind;
    int type;
    double c, dhat, mollifier_eps;
  };
  // Slip u = T (X - X_t) of a friction pair at x (obstacle rows at the end position).
  Eigen::Vector3d slip(const FrictionPair& f, const Eigen::VectorXd& x) const;
  // Per friction pair: D / (mu lambda), its gradient (12) and Hessian (12 x 12) in X.
  void friction_kernel(const FrictionPair& f, const Eigen::VectorXd& x, double* value, double* g, double* H) const;
  void add_friction_blocks(const Eigen::VectorXd& x, const Eigen::VectorXd& p, double scale, Eigen::VectorXd& values) const;
  void add_friction_product(const Eigen::VectorXd& x, const Eigen::VectorXd& p, const Eigen::VectorXd& dir,
                            bool offpattern_only, Eigen::VectorXd& out) const;
  // The friction part of add_step_matrix_derivatives (gp: none if null).
  void add_friction_step_matrix_derivatives(const Eigen::VectorXd& x, const Eigen::VectorXd& p,
                                            const Eigen::VectorXd& lambda, const Eigen::VectorXd& w, double scale,
                                            Eigen::VectorXd& gx, Eigen::VectorXd* gp) const;
  std::vector<FrictionPair> friction_pairs_;
  double eps_u_ = 0;
  std::vector<std::array<int, 6>> diagonal_index_;  // per cloth vertex: the upper-triangle entries of its block
  struct Cache {
    Eigen::VectorXd x;
    ContactPositions obstacle;
    double dhat = -1;
    std::vector<ActivePair> pairs;
    // broad-phase candidates, valid within candidate_margin dhat of the segment candidate_x + s candidate_dx,
    // s in [0, 1] (candidate_dx empty: the point candidate_x; active_pairs, max_step)
    std::shared_ptr<const CandidatePairs> candidates;
    Eigen::VectorXd candidate_x, candidate_dx;
    ContactPositions candidate_obstacle;
    double candidate_dhat = -1;
    double candidate_margin = 0;
  };
  // Whether c's candidates hold every pair closer than dh at x (under cache_mutex_).
  bool candidates_valid(const Cache& c, const Eigen::VectorXd& x, double dh) const;
  struct SavedStep;
  struct SavedIterate;
  mutable std::mutex cache_mutex_;
  mutable Cache cache_;
  // The active pairs' Hessians at one x (exact [0] and PSD-projected [1]), see pair_hessians.
  struct HessianCache {
    Eigen::VectorXd x;
    ContactPositions obstacle;
    double dhat = -1;
    std::vector<ActivePair> pairs;
    std::shared_ptr<const std::vector<double>> hessians;
  };
  std::shared_ptr<const std::vector<double>> pair_hessians(const Eigen::VectorXd& x, double dhat, bool project,
                                                           const std::vector<ActivePair>& pairs) const;
  mutable std::mutex hessian_mutex_;
  mutable HessianCache hessian_cache_[2];
};

}  // namespace drapelab
