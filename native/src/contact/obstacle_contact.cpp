#include "contact/obstacle_contact.hpp"

#include <cmath>

#include "util/error.hpp"

namespace drapelab {

namespace {
// The obstacle, checked before anything indexes it.
const ObstacleMesh& validated(const ObstacleMesh& obstacle) {
  if (obstacle.faces.rows() == 0) throw InputError("obstacle contact: the obstacle mesh has no faces");
  if (!obstacle.positions.allFinite()) throw InputError("obstacle contact: obstacle positions are not finite");
  for (int f = 0; f < obstacle.faces.rows(); ++f)
    for (int k = 0; k < 3; ++k)
      if (obstacle.faces(f, k) < 0 || obstacle.faces(f, k) >= obstacle.positions.rows())
        throw InputError("obstacle contact: obstacle face " + std::to_string(f) + " indexes a missing vertex");
  return obstacle;
}
ContactPositions rest_positions(const TriangleMesh& cloth, const ObstacleMesh& obstacle) {
  ContactPositions P(cloth.num_vertices() + obstacle.positions.rows(), 3);
  P.topRows(cloth.num_vertices()) = cloth.positions;
  P.bottomRows(obstacle.positions.rows()) = obstacle.positions;
  return P;
}
std::vector<double> unit_stiffness(const Eigen::VectorXd& w, int num_vertices, double density, double gravity) {
  if (w.size() != num_vertices)
    throw InputError("obstacle contact: " + std::to_string(w.size()) + " area weights for " +
                     std::to_string(num_vertices) + " cloth vertices");
  std::vector<double> c(w.size());
  for (int i = 0; i < w.size(); ++i) c[i] = w[i] * density * gravity;
  return c;
}
}  // namespace

ObstacleContact::ObstacleContact(const TriangleMesh& cloth, const Eigen::VectorXd& area_weights, double density,
                                 double gravity, const ObstacleMesh& obstacle, double thickness, double friction)
    : PairContactTerm(make_contact_surfaces(cloth.faces, cloth.num_vertices(), &validated(obstacle)), cloth.num_vertices(),
                      unit_stiffness(area_weights, cloth.num_vertices(), density, gravity), PairFilter::kCross,
                      rest_positions(cloth, obstacle)),
      thickness_(thickness),
      friction_(friction) {
  if (!(thickness > 0) || !std::isfinite(thickness)) throw InputError("obstacle contact: thickness must be > 0 m");
  if (!(friction >= 0) || !std::isfinite(friction)) throw InputError("obstacle contact: friction must be >= 0");
  set_obstacle(obstacle.positions, obstacle.positions);
}

void ObstacleContact::set_obstacle(const MatrixX3d& at_t, const MatrixX3d& at_t1) {
  if (at_t.rows() != obstacle_.rows() || at_t1.rows() != obstacle_.rows())
    throw InputError("obstacle contact: obstacle positions have " + std::to_string(at_t1.rows()) + " rows, expected " +
                     std::to_string(obstacle_.rows()));
  if (!at_t.allFinite() || !at_t1.allFinite()) throw InputError("obstacle contact: obstacle positions are not finite");
  start_ = at_t;
  obstacle_start_ = at_t;
  obstacle_ = at_t1;
}

}  // namespace drapelab
