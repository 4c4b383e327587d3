#include "physics/stretch.hpp"

#include <Eigen/Eigenvalues>
#include <cmath>

#include "util/error.hpp"

namespace drapelab {

std::array<double, 6> StretchWeightGrid::polar_weights(double guu, double gvv, double guv) {
  // Principal stretches: eigenvalues of C = 2G + I = F^T F.
  const double a = 2 * guu + 1, b = 2 * guv, d = 2 * gvv + 1;
  const double mean = 0.5 * (a + d), dev = std::sqrt(0.25 * (a - d) * (a - d) + b * b);
  const double lmax = mean + dev;
  const double lambda_max = std::sqrt(std::max(lmax, 0.0)) - 1.0;
  double s = lambda_max / kStretchSampleStrain;
  s = std::min(std::max(s, 0.0), 1.0);
  std::array<double, 6> w{};
  w[0] = 1.0 - s;
  if (dev < 1e-12) {  // isotropic: the direction is undefined, average the five directions
    for (int k = 0; k < 5; ++k) w[1 + k] = s / 5.0;
    return w;
  }
  // Eigenvector of lmax: (b, lmax - a) or (lmax - d, b); fold its angle to [0, pi/2].
  double vx = lmax - d, vy = b;
  if (std::abs(vx) + std::abs(vy) < 1e-14) {
    vx = b;
    vy = lmax - a;
  }
  const double phi = std::atan2(std::abs(vy), std::abs(vx));  // in [0, pi/2]
  double t = phi / (M_PI / 8.0);                               // 0..4
  int k = static_cast<int>(t);
  if (k > 3) k = 3;
  const double f = t - k;
  w[1 + k] += s * (1 - f);
  w[2 + k] += s * f;
  return w;
}

StretchWeightGrid::StretchWeightGrid() {
  node_weights.resize(static_cast<size_t>(kNormal) * kNormal * kShear);
  for (int i = 0; i < kNormal; ++i)
    for (int j = 0; j < kNormal; ++j)
      for (int k = 0; k < kShear; ++k)
        node_weights[(i * kNormal + j) * kShear + k] = polar_weights(kMin + i * kStep, kMin + j * kStep, k * kStep);
}

const StretchWeightGrid& stretch_weight_grid() {
  static const StretchWeightGrid grid;
  return grid;
}

StretchTerm::StretchTerm(const TriangleMesh& mesh, int parameter_offset, bool shared)
    : offset_(parameter_offset), shared_(shared) {
  const int nf = mesh.num_faces();
  faces_.resize(nf);
  dm_inv_.resize(nf);
  area_.resize(nf);
  for (int f = 0; f < nf; ++f) {
    faces_[f] = {mesh.faces(f, 0), mesh.faces(f, 1), mesh.faces(f, 2)};
    const Eigen::Vector2d u0 = mesh.uv.row(faces_[f][0]).transpose();
    Eigen::Matrix2d Dm;
    Dm.col(0) = mesh.uv.row(faces_[f][1]).transpose() - u0;
    Dm.col(1) = mesh.uv.row(faces_[f][2]).transpose() - u0;
    const double det = Dm.determinant();
    if (!(std::abs(det) > 0)) throw InputError("stretch: face " + std::to_string(f) + " has zero rest area");
    const Eigen::Matrix2d Di = Dm.inverse();
    dm_inv_[f] = {Di(0, 0), Di(0, 1), Di(1, 0), Di(1, 1)};
    area_[f] = 0.5 * std::abs(det);
  }
}

}  // namespace drapelab
