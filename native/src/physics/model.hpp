// A cloth model: mesh, rest data, lumped masses, the active terms and the flat parameter layout.
//
// Parameter blocks (physics/parameters.hpp): "stretch" (6x4 table, N/m), "bend" (3x5 table, N m),
// "density" (kg/m^2), "handle_stiffness" (N/m), then one block "<effect>.<parameter>" per parameter of each
// active effect (physics/effect.hpp), in registry order. Homogeneous models share one table; heterogeneous models
// carry one table per face (stretch) and per bending edge (bend).
#pragma once
#include <array>
#include <memory>
#include <string>
#include <vector>

#include "geometry/mesh.hpp"
#include "physics/effect.hpp"
#include "physics/parameters.hpp"
#include "physics/sparse_pattern.hpp"
#include "physics/term.hpp"

namespace drapelab {

struct ModelOptions {
  bool heterogeneous = false;     // one table per element
  double support_radius = 0.09;   // m: vertices with rest radius below are held by the handle
  double gravity = 9.8;           // m/s^2, along -z
  double density = 0.192;         // kg/m^2 (Cotton Blue)
  double handle_stiffness = 1e3;  // N/m (paper)
  // Active optional effects with their starting values (physics/effect.hpp); empty: the base model.
  EffectValues effects;
  // Garments: the vertices the handle holds (a waistband), instead of those within support_radius of the
  // pattern's origin; their anchors follow a moving body through Model::set_handle_anchors.
  std::vector<int> held_vertices;
  // Garments: pairs of seam vertices (one per pattern piece) held together (physics/seam.hpp).
  std::vector<std::array<int, 2>> seams;
  double seam_stiffness = 1e3;  // N/m per seam pair
  // The images' calibration (px per metre at the support's plane): the `camera` effect converts its pixel
  // offsets with it. 720: the bundled Cusick data.
  double px_per_m = 720.0;
};

class HandleTerm;

using StretchTable = Eigen::Matrix<double, 6, 4, Eigen::RowMajor>;
using BendTable = Eigen::Matrix<double, 3, 5, Eigen::RowMajor>;

// The published Cotton Blue starting tables (paper's released scripts).
StretchTable cotton_blue_stretch_table();
BendTable cotton_blue_bend_table();

class Model {
 public:
  Model(const TriangleMesh& mesh, const ModelOptions& options = {});

  const TriangleMesh& mesh() const { return mesh_; }
  int num_vertices() const { return mesh_.num_vertices(); }
  int num_dofs() const { return 3 * mesh_.num_vertices(); }
  const std::vector<BendingEdge>& bending_edges() const { return edges_; }
  const ModelOptions& options() const { return options_; }
  const ParameterLayout& layout() const { return layout_; }
  const SparsePattern& pattern() const { return pattern_; }
  const std::vector<std::unique_ptr<Term>>& terms() const { return terms_; }
  const std::vector<int>& handle_vertices() const { return handle_vertices_; }
  // Moves the handle's anchors (H x 3, metres, in handle_vertices() order): a kinematic attachment (a garment's
  // waistband following the body). Not thread-safe against a running simulation of this model.
  void set_handle_anchors(const MatrixX3d& anchors);
  // Names of the active effects, in registry order.
  const std::vector<std::string>& active_effects() const { return active_effects_; }

  // The positions the silhouette renderer sees: x through the active effects' position transforms (offset:
  // the tester's frame; camera: the measurement model), in registry order; x itself when none is active.
  Eigen::VectorXd observe(const Eigen::VectorXd& x, const Eigen::VectorXd& p) const;
  // Adds g_y^T d observe/dx to gx and g_y^T d observe/dp to gp (gx: 3V, gp: the layout's size).
  void add_observe_vjp(const Eigen::VectorXd& x, const Eigen::VectorXd& p, const Eigen::VectorXd& gy,
                       Eigen::VectorXd& gx, Eigen::VectorXd& gp) const;
  bool has_observation() const { return !observations_.empty(); }

  // Rest positions, flattened (3V), metres.
  Eigen::VectorXd rest_positions() const;
  // Sum of A_f / 3 per vertex (m^2); masses = density * area_weights.
  const Eigen::VectorXd& area_weights() const { return area_weights_; }
  Eigen::VectorXd masses(const Eigen::VectorXd& p) const;  // per vertex, kg

  // Default parameters: the Cotton Blue tables on every element, options' density and k_h.
  const Eigen::VectorXd& default_parameters() const { return defaults_; }
  // Writes a table into every element of the block.
  void fill_stretch(Eigen::VectorXd& p, const StretchTable& table) const;
  void fill_bend(Eigen::VectorXd& p, const BendTable& table) const;
  // Throws InputError naming the block, element and entry for NaN/inf, negative stiffness,
  // density <= 0, or a wrong size.
  void validate_parameters(const Eigen::VectorXd& p) const;

  double energy(const Eigen::VectorXd& x, const Eigen::VectorXd& p) const;
  void add_gradient(const Eigen::VectorXd& x, const Eigen::VectorXd& p, Eigen::VectorXd& g) const;

  // Adds a term after construction whose assembled matrices need no new pattern entries: its stencils lie in the
  // model's sparsity pattern (single vertices always do: a garment's body contact, garment/revolved_body.hpp), or
  // it has none and gives its couplings outside the pattern as products (Term::has_offpattern_hessian: a moving
  // mesh obstacle, contact/obstacle_contact.hpp). The model keeps it. Returns it, for per-step updates.
  // InputError if a stencil couples vertices outside the pattern.
  template <class T>
  T* add_term(std::unique_ptr<T> term) {
    T* raw = term.get();
    add_term_impl(std::move(term));
    return raw;
  }

 private:
  void add_term_impl(std::unique_ptr<Term> term);
  TriangleMesh mesh_;
  ModelOptions options_;
  std::vector<BendingEdge> edges_;
  ParameterLayout layout_;
  Eigen::VectorXd area_weights_, defaults_;
  std::vector<int> handle_vertices_;
  std::vector<std::string> active_effects_;
  std::vector<std::unique_ptr<Term>> terms_;
  std::vector<std::unique_ptr<PositionTransform>> observations_;  // active effects' transforms, registry order
  HandleTerm* handle_ = nullptr;  // owned by terms_
  SparsePattern pattern_;
};

}  // namespace drapelab
