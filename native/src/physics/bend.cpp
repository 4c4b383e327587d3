#include "physics/bend.hpp"

#include <cmath>

#include "util/error.hpp"

namespace drapelab {

BendTerm::BendTerm(const TriangleMesh& mesh, const std::vector<BendingEdge>& edges, int parameter_offset, bool shared)
    : offset_(parameter_offset), shared_(shared) {
  const Eigen::VectorXd areas = rest_areas(mesh);
  for (size_t i = 0; i < edges.size(); ++i) {
    const BendingEdge& be = edges[i];
    verts_.push_back({be.a, be.b, be.c, be.d});
    const Eigen::Vector2d du = (mesh.uv.row(be.b) - mesh.uv.row(be.a)).transpose();
    const double L = du.norm();
    if (!(L > 0)) throw InputError("bend: edge " + std::to_string(i) + " has zero rest length");
    rest_length_.push_back(L);
    height_sum_.push_back(2.0 * (std::abs(areas[be.face0]) + std::abs(areas[be.face1])) / L);
    rest_angle_.push_back(0.0);  // flat rest shape; rest curvature is an optional effect
    const double beta = std::atan2(std::abs(du.y()), std::abs(du.x()));  // [0, pi/2] from weft
    bias_.push_back(beta);
    const double t = beta / (M_PI / 4.0);  // 0..2 over rows 0, 45, 90 degrees
    int r0 = static_cast<int>(t);
    if (r0 > 1) r0 = 1;
    const double f = t - r0;
    row_index_.push_back({r0, r0 + 1});
    row_weights_.push_back({1.0 - f, f});
  }
}

}  // namespace drapelab
