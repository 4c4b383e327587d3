#include "geometry/mesh.hpp"

#include <algorithm>
#include <cmath>
#include <map>
#include <sstream>

#include "util/error.hpp"

namespace drapelab {

Eigen::VectorXd rest_areas(const TriangleMesh& mesh) {
  Eigen::VectorXd a(mesh.num_faces());
  for (Index f = 0; f < mesh.num_faces(); ++f) {
    const Eigen::Vector2d p0 = mesh.face_uv(f, 0);
    const Eigen::Vector2d e1 = mesh.face_uv(f, 1) - p0;
    const Eigen::Vector2d e2 = mesh.face_uv(f, 2) - p0;
    a[f] = 0.5 * (e1.x() * e2.y() - e1.y() * e2.x());
  }
  return a;
}

void validate_mesh(const TriangleMesh& mesh, double min_area) {
  const Index nv = mesh.num_vertices();
  if (nv < 3) throw InputError("mesh: needs at least 3 vertices, got " + std::to_string(nv));
  if (mesh.num_faces() < 1) throw InputError("mesh: has no faces");
  if (mesh.uv.rows() != nv)
    throw InputError("mesh: uv has " + std::to_string(mesh.uv.rows()) + " rows, expected one per vertex (" +
                     std::to_string(nv) + ")");
  if (!mesh.positions.allFinite()) throw InputError("mesh: positions contain NaN or infinity");
  if (!mesh.uv.allFinite()) throw InputError("mesh: uv contains NaN or infinity");
  if (mesh.corner_uv.rows() != 0 && mesh.corner_uv.rows() != 3 * mesh.num_faces())
    throw InputError("mesh: corner_uv has " + std::to_string(mesh.corner_uv.rows()) +
                     " rows, expected none or three per face (" + std::to_string(3 * mesh.num_faces()) + ")");
  if (!mesh.corner_uv.allFinite()) throw InputError("mesh: corner_uv contains NaN or infinity");
  for (Index f = 0; f < mesh.num_faces(); ++f) {
    for (int k = 0; k < 3; ++k) {
      const Index v = mesh.faces(f, k);
      if (v < 0 || v >= nv) {
        std::ostringstream s;
        s << "mesh: face " << f << " refers to vertex " << v << ", outside 0.." << nv - 1;
        throw InputError(s.str());
      }
    }
    if (mesh.faces(f, 0) == mesh.faces(f, 1) || mesh.faces(f, 1) == mesh.faces(f, 2) ||
        mesh.faces(f, 0) == mesh.faces(f, 2))
      throw InputError("mesh: face " + std::to_string(f) + " repeats a vertex (degenerate face)");
  }
  const Eigen::VectorXd a = rest_areas(mesh);
  for (Index f = 0; f < mesh.num_faces(); ++f) {
    if (std::abs(a[f]) <= min_area) {
      std::ostringstream s;
      s << "mesh: face " << f << " is degenerate (rest area " << std::abs(a[f]) << " m^2)";
      throw InputError(s.str());
    }
  }
  std::map<std::pair<Index, Index>, int> count;
  for (Index f = 0; f < mesh.num_faces(); ++f)
    for (int k = 0; k < 3; ++k) {
      Index i = mesh.faces(f, k), j = mesh.faces(f, (k + 1) % 3);
      if (i > j) std::swap(i, j);
      if (++count[{i, j}] > 2) {
        std::ostringstream s;
        s << "mesh: edge (" << i << ", " << j << ") is shared by more than two faces (non-manifold)";
        throw InputError(s.str());
      }
    }
}

Eigen::Vector2d pattern_edge(const TriangleMesh& mesh, const BendingEdge& be) {
  Eigen::Vector2d ua = mesh.uv.row(be.a).transpose(), ub = mesh.uv.row(be.b).transpose();
  if (mesh.corner_uv.rows())
    for (int k = 0; k < 3; ++k) {
      if (mesh.faces(be.face0, k) == be.a) ua = mesh.face_uv(be.face0, k);
      if (mesh.faces(be.face0, k) == be.b) ub = mesh.face_uv(be.face0, k);
    }
  return ub - ua;
}

std::vector<BendingEdge> bending_edges(const TriangleMesh& mesh) {
  // key (min, max) -> list of (face, opposite vertex)
  std::map<std::pair<Index, Index>, std::vector<std::pair<Index, Index>>> adj;
  for (Index f = 0; f < mesh.num_faces(); ++f)
    for (int k = 0; k < 3; ++k) {
      Index i = mesh.faces(f, k), j = mesh.faces(f, (k + 1) % 3), o = mesh.faces(f, (k + 2) % 3);
      adj[{std::min(i, j), std::max(i, j)}].push_back({f, o});
    }
  std::vector<BendingEdge> edges;
  for (const auto& [key, fs] : adj) {
    if (fs.size() != 2) continue;
    BendingEdge e;
    // Orient (a, b) as it appears in face0 so that face0 = (a, b, c) is counter-clockwise.
    const Index f0 = fs[0].first;
    Index a = key.first, b = key.second;
    for (int k = 0; k < 3; ++k) {
      const Index i = mesh.faces(f0, k), j = mesh.faces(f0, (k + 1) % 3);
      if ((i == key.first && j == key.second) || (i == key.second && j == key.first)) {
        a = i;
        b = j;
      }
    }
    e.a = a;
    e.b = b;
    e.c = fs[0].second;
    e.d = fs[1].second;
    e.face0 = f0;
    e.face1 = fs[1].first;
    edges.push_back(e);
  }
  return edges;
}

void orient_faces_ccw(TriangleMesh& mesh) {
  const Eigen::VectorXd a = rest_areas(mesh);
  for (Index f = 0; f < mesh.num_faces(); ++f)
    if (a[f] < 0) {
      std::swap(mesh.faces(f, 1), mesh.faces(f, 2));
      if (mesh.corner_uv.rows()) mesh.corner_uv.row(3 * f + 1).swap(mesh.corner_uv.row(3 * f + 2));
    }
}

TriangleMesh permute_vertices(const TriangleMesh& mesh, const std::vector<Index>& perm) {
  const Index nv = mesh.num_vertices();
  if (static_cast<Index>(perm.size()) != nv) throw InputError("permute_vertices: permutation size mismatch");
  std::vector<Index> inverse(nv, -1);
  for (Index i = 0; i < nv; ++i) inverse.at(perm[i]) = i;
  TriangleMesh out;
  out.positions.resize(nv, 3);
  out.uv.resize(nv, 2);
  for (Index i = 0; i < nv; ++i) {
    out.positions.row(i) = mesh.positions.row(perm[i]);
    out.uv.row(i) = mesh.uv.row(perm[i]);
  }
  out.faces = mesh.faces;
  out.corner_uv = mesh.corner_uv;  // per corner: faces keep their order
  for (Index f = 0; f < mesh.num_faces(); ++f)
    for (int k = 0; k < 3; ++k) out.faces(f, k) = inverse[mesh.faces(f, k)];
  return out;
}

}  // namespace drapelab
