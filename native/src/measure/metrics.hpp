// Metrics comparing and describing drape silhouettes and meshes. Each states its formula and unit.
//
// Angles: theta is measured counter-clockwise from +x on the table (image: to the right), with +y up
// (image: towards row 0), so an image point is (col, row) = (cx + r px_per_m cos theta,
// cy - r px_per_m sin theta). Curves r(theta) are sampled at theta_k = 2 pi k / N, k = 0..N-1.
#pragma once
#include <Eigen/Core>
#include <vector>

#include "geometry/cusick.hpp"
#include "geometry/mesh.hpp"
#include "measure/calibration.hpp"
#include "util/image.hpp"

namespace drapelab {

// Pixel MSE = (1 / (H W)) sum_ij (a_ij - b_ij)^2 over all pixels; unitless (for silhouettes in [0, 1]).
// Throws InputError when the shapes differ or an image is empty.
double pixel_mse(const Image& a, const Image& b);

// Intersection over union of the binary masks A = {a > 0.5}, B = {b > 0.5}: |A n B| / |A u B|, in [0, 1].
// Throws InputError when the shapes differ or both masks are empty.
double iou(const Image& a, const Image& b);

// Shadow area (m^2) of a binary mask under an orthographic calibration: count(mask > 0.5) / px_per_m^2.
double shadow_area(const Image& mask, double px_per_m);

// Drape coefficient (BS EN ISO 9073-9 / BS 5058), unitless:
//   DC = (A_shadow - A_disk) / (A_specimen - A_disk),  A_disk = pi r_support^2, A_specimen = pi r_specimen^2
// 1 = the specimen hangs flat (no drape), 0 = it hangs straight down along the support disk's edge.
double drape_coefficient(double shadow_area_m2, const CusickGeometry& geometry = {});
double drape_coefficient(const Image& mask, double px_per_m, const CusickGeometry& geometry = {});

// Radius-angle curve r(theta) in metres about the calibrated centre: for each of `samples` angles, the
// largest radius along the ray from the centre at which the ray (marched in steps of `step_px` pixels up
// to the image edge) is inside a mask pixel (> 0.5), plus half a step; 0 when the ray meets no cloth.
// The outermost boundary is taken, so a fold that overhangs itself does not create a dip.
Eigen::VectorXd radius_angle_curve(const Image& mask, const Calibration& calibration, int samples = 360,
                                   double step_px = 0.1);

struct NodeOptions {
  double smoothing_deg = 2.0;            // sigma of the circular Gaussian smoothing of r(theta)
  double min_prominence_m = 0.002;       // absolute prominence floor (about 1.4 px at 720 px/m)
  double min_relative_prominence = 0.1;  // ... and at least this fraction of max(r) - min(r) (smoothed)
};

struct NodeAnalysis {
  int count = 0;                 // node count: number of maxima of the smoothed r(theta) that pass
  double amplitude_m = 0.0;      // node amplitude (m), see analyse_nodes
  std::vector<double> angles_rad;      // node (peak) angles
  std::vector<double> prominences_m;   // their prominences
  Eigen::VectorXd smoothed;            // the smoothed curve (m)
};

// Nodes (folds) of a drape from r(theta): r is smoothed with a circular Gaussian, then each strict local
// maximum is kept when its topographic prominence (its height above the higher of the two minima that
// separate it, going either way round the circle, from a higher point) is at least
// max(min_prominence_m, min_relative_prominence (max r - min r)).
// Node amplitude (m) = (mean smoothed r at the nodes - mean smoothed r at the deepest point between each
// pair of consecutive nodes) / 2; for r = R + a cos(n theta) it is a (times the smoothing's attenuation
// exp(-(n sigma)^2 / 2), 0.96 for n = 8). 0 nodes: count 0, amplitude 0.
NodeAnalysis analyse_nodes(const Eigen::VectorXd& r_theta, const NodeOptions& options = {});
int node_count(const Eigen::VectorXd& r_theta, const NodeOptions& options = {});
double node_amplitude(const Eigen::VectorXd& r_theta, const NodeOptions& options = {});

// Harmonic spectrum of r(theta) (metres): the magnitudes of its DFT R_k = sum_n r_n exp(-2 pi i k n / N),
// scaled to amplitudes: a_0 = |R_0| / N (the mean radius), a_k = 2 |R_k| / N for k >= 1, so that
// r = R + a cos(n theta + phi) has a_0 = R and a_n = a. Returns a_0 .. a_{count-1}.
Eigen::VectorXd harmonic_spectrum(const Eigen::VectorXd& r_theta, int count = 20);

struct RThetaAlignment {
  double rmse_m = 0.0;       // sqrt(mean_k (measured_k - model_{k + s})^2) at the best shift s (m)
  double rotation_rad = 0.0; // 2 pi s / N: the model is compared at theta + rotation
  int shift = 0;
};

// r(theta) RMSE after the best rotation: the minimum over all N circular shifts s of the model curve.
// Rotation-free (the folds of a redraped sample land elsewhere). Throws InputError on length mismatch.
RThetaAlignment r_theta_rmse(const Eigen::VectorXd& measured, const Eigen::VectorXd& model);

enum class HausdorffMode {
  Vertices,        // between the two vertex sets: max of nearest-vertex distances both ways
  PointToSurface,  // from each mesh's vertices to the other mesh's triangles (exact point-triangle distance)
};

// Symmetric Hausdorff distance (metres) H(A, B) = max(h(A, B), h(B, A)), h(A, B) = max_{a} min_{b} |a - b|.
// PointToSurface takes a over A's vertices and b over B's surface: exact for the vertex-to-surface
// distance and a lower bound of the surface-to-surface Hausdorff distance that is tight for meshes
// finer than their deviation. Accelerated by a uniform grid (exact, not approximate).
double hausdorff_distance(const MatrixX3d& positions_a, const MatrixX3i& faces_a, const MatrixX3d& positions_b,
                          const MatrixX3i& faces_b, HausdorffMode mode = HausdorffMode::PointToSurface);

// Distance (m) from point p to triangle (a, b, c) (closest point by Voronoi regions, Ericson 2005, 5.1.5).
double point_triangle_distance(const Eigen::Vector3d& p, const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                               const Eigen::Vector3d& c);

}  // namespace drapelab
