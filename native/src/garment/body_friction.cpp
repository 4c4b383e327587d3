#include "garment/body_friction.hpp"

#include <cmath>
#include <string>

#include "util/error.hpp"

namespace drapelab {

namespace {
constexpr double kSlipSpeed = 1e-3;  // eps_v [m/s]: friction is smoothed below this slip speed (as disk_contact)
}

BodyFriction::BodyFriction(const RevolvedBodyContact& body, int num_vertices, double mu) : body_(body), mu_(mu) {
  if (!(mu >= 0 && std::isfinite(mu)))
    throw InputError("body friction: expected a coefficient >= 0, got " + std::to_string(mu));
  if (num_vertices != body.kappa().size())
    throw InputError("body friction: the body's barrier has " + std::to_string(body.kappa().size()) +
                     " vertices, the cloth " + std::to_string(num_vertices));
  const int parts = body.num_parts();
  vertices_.resize(static_cast<size_t>(num_vertices) * parts);
  for (int i = 0; i < num_vertices; ++i)
    for (int k = 0; k < parts; ++k) vertices_[static_cast<size_t>(i) * parts + k] = {i};
  lag_.assign(vertices_.size(), Lag{});
}

void BodyFriction::begin_step(const Eigen::VectorXd& x, const Eigen::VectorXd&, double h) {
  eps_u_ = kSlipSpeed * h;
  std::fill(lag_.begin(), lag_.end(), Lag{});
  if (h <= 0 || mu_ == 0) return;
  const int parts = body_.num_parts();
  const double dhat = body_.activation();
  for (int e = 0; e < num_elements(); ++e) {
    const int i = vertices_[e][0], k = e % parts;
    const Eigen::Vector3d q = x.segment<3>(3 * i);
    Eigen::Vector3d grad;
    const double g = body_.part_clearance_at(k, body_.start_pose(k), q, &grad);
    if (!(g > 0 && g < dhat)) continue;
    const double gn = grad.norm();
    if (!(gn > 0)) continue;
    double b, db, d2b;
    barrier_derivatives(g, dhat, b, db, d2b);
    Lag& l = lag_[e];
    l.normal_force = body_.kappa()[i] * std::abs(db) * gn;
    const Eigen::Vector3d n = grad / gn;
    l.projector = Eigen::Matrix3d::Identity() - n * n.transpose();
    const RigidPose &a = body_.start_pose(k), &z = body_.end_pose(k);
    l.origin = z.R * (a.R.transpose() * (q - a.c)) + z.c;  // the body's material point at q, carried to the end
  }
}

}  // namespace drapelab
