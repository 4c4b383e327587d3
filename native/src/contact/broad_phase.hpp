// Broad phase of contact detection: the point-triangle and edge-edge pairs that may come within a distance
// `inflation` of each other, found with a uniform spatial hash grid.
//
// Each primitive's axis-aligned bounding box (over its start and, for a swept query, end positions) is
// inflated by inflation / 2 on every side; two primitives are a candidate iff their inflated boxes overlap
// (then every per-axis gap is below `inflation`, which any pair within that distance satisfies). The grid's
// cell is about the mean edge length (at most 200 cells per axis), so a primitive covers a few cells; boxes are binned into every cell they
// touch and each query primitive looks only at the cells its box covers. The result is exactly the set of
// box-overlapping pairs (tests/native/contact/test_broad_phase.cpp compares it with brute force); pairs that
// share a vertex are left out (their distance is zero by construction).
//
// Vertices are rows of one position array; primitives carry a group (0 = cloth, 1 = obstacle) and a
// `PairFilter` keeps pairs within the cloth (self contact), across groups (obstacle contact) or both (never
// pairs within the obstacle: its own closeness, legs against legs, is not the cloth's business).
#pragma once
#include <Eigen/Core>
#include <array>
#include <vector>

namespace drapelab {

using ContactPositions = Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor>;

enum class PairFilter { kSelf, kCross, kAll };

// The surfaces: triangles and their unique edges over one vertex array, each vertex in a group.
struct ContactSurfaces {
  std::vector<std::array<int, 3>> faces;
  std::vector<std::array<int, 2>> edges;  // unique, (low, high) vertex index
  std::vector<int> vertex_group;          // per vertex: 0 cloth, 1 obstacle
  int num_vertices() const { return static_cast<int>(vertex_group.size()); }
  int face_group(int f) const { return vertex_group[faces[f][0]]; }
  int edge_group(int e) const { return vertex_group[edges[e][0]]; }
  // Mean edge length at positions x [m] (the hash cell size).
  double mean_edge_length(const ContactPositions& x) const;
};

// The unique edges of a triangle list, sorted.
std::vector<std::array<int, 2>> unique_edges(const std::vector<std::array<int, 3>>& faces);

struct CandidatePairs {
  std::vector<std::array<int, 2>> point_triangle;  // (vertex, face)
  std::vector<std::array<int, 2>> edge_edge;       // (edge, edge), first < second
};

// Candidates between x0 and (if x1 is given) the swept boxes from x0 to x1. cell_size <= 0: the mean edge
// length at x0. Deterministic order (sorted).
CandidatePairs broad_phase(const ContactSurfaces& s, const ContactPositions& x0, const ContactPositions* x1,
                           double inflation, PairFilter filter, double cell_size = 0);
// Triangle pairs (f < g) whose boxes (inflated by inflation / 2) overlap and that share no vertex: the
// candidates of intersection tests (contact/diagnostics.hpp).
std::vector<std::array<int, 2>> triangle_pairs(const ContactSurfaces& s, const ContactPositions& x, double inflation,
                                               PairFilter filter, double cell_size = 0);
// The same set by testing every pair (reference for tests; O(n^2)).
CandidatePairs broad_phase_brute_force(const ContactSurfaces& s, const ContactPositions& x0,
                                       const ContactPositions* x1, double inflation, PairFilter filter);

}  // namespace drapelab
