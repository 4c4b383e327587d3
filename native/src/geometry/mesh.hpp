// Triangle mesh with its rest (u,v) frame and bending topology.
//
// Units: metres. The rest (u,v) coordinates are the flat pattern of the cloth: u runs along the
// weft/course, v along the warp/wale. For a Cusick specimen (a flat disk) u = x, v = y.
#pragma once
#include <Eigen/Core>
#include <string>
#include <vector>

namespace drapelab {

using Index = int;
using MatrixX3d = Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor>;
using MatrixX2d = Eigen::Matrix<double, Eigen::Dynamic, 2, Eigen::RowMajor>;
using MatrixX3i = Eigen::Matrix<int, Eigen::Dynamic, 3, Eigen::RowMajor>;
using MatrixX4i = Eigen::Matrix<int, Eigen::Dynamic, 4, Eigen::RowMajor>;

// An interior edge shared by two faces: vertices (a, b) of the edge, c opposite in face0, d opposite in face1.
struct BendingEdge {
  Index a, b, c, d;
  Index face0, face1;
};

struct TriangleMesh {
  MatrixX3d positions;   // rest positions (V x 3), metres
  MatrixX2d uv;          // rest pattern coordinates (V x 2), metres: u = weft, v = warp
  MatrixX3i faces;       // (F x 3) vertex indices, counter-clockwise in (u,v)
  // Optional per-corner pattern coordinates (3F x 2, row 3 f + k = corner k of face f), metres. Empty: every
  // corner takes its vertex's uv. A sewn garment simulated as one mesh (its seams welded) has vertices on a seam
  // that lie on two pattern pieces, i.e. at two places of the pattern: its faces carry their own corners' uv.
  MatrixX2d corner_uv;

  Index num_vertices() const { return static_cast<Index>(positions.rows()); }
  Index num_faces() const { return static_cast<Index>(faces.rows()); }
  // The rest pattern coordinates of corner k of face f (corner_uv when given, else the vertex's uv).
  Eigen::Vector2d face_uv(Index f, int k) const {
    return corner_uv.rows() ? Eigen::Vector2d(corner_uv.row(3 * f + k).transpose())
                            : Eigen::Vector2d(uv.row(faces(f, k)).transpose());
  }
};

// Checks shapes (corner_uv: empty or 3F rows), index ranges, finiteness, degenerate faces (rest area <= min_area) and
// non-manifold edges (shared by more than two faces). Throws InputError naming the first problem.
void validate_mesh(const TriangleMesh& mesh, double min_area = 1e-14);

// Interior edges with their two opposite vertices, in a deterministic order.
std::vector<BendingEdge> bending_edges(const TriangleMesh& mesh);

// The bending edge a -> b in the rest pattern as face0 has it (with per-corner uv, a welded seam edge lies on two
// pattern pieces; face0's corners decide), metres.
Eigen::Vector2d pattern_edge(const TriangleMesh& mesh, const BendingEdge& be);

// Rest areas of faces in the (u,v) pattern (m^2), signed: positive for counter-clockwise faces.
Eigen::VectorXd rest_areas(const TriangleMesh& mesh);

// A mesh whose faces are oriented counter-clockwise in (u,v) (flips clockwise faces).
void orient_faces_ccw(TriangleMesh& mesh);

// Reorders vertices by `perm` (new index i holds old vertex perm[i]); used to test order independence.
TriangleMesh permute_vertices(const TriangleMesh& mesh, const std::vector<Index>& perm);

}  // namespace drapelab
