// Soft silhouette rasterizer (DIB-R / SoftRas family) with an exact backward pass (vector-Jacobian product
// into vertex positions).
//
// Forward, for every pixel centre p (image coordinates, pixels; see util/image.hpp):
//
//   I(p) = 1 - T(p),   T(p) = prod_f (1 - D_f(p))          (soft occupancy in [0, 1]; T = transmittance)
//
// d_f(p) is the Euclidean distance (pixels) from p to the boundary of face f as projected by the camera;
// "inside" is the closed coverage rule of hard_silhouette (either face orientation; zero-area projections
// have no inside). sigma (pixels) is the sharpness. Two profiles D_f:
//
//  * SoftProfile::Gaussian (default; DIB-R, Chen et al. NeurIPS 2019):
//      D_f(p) = 1 inside face f,   D_f(p) = exp(-d_f(p)^2 / sigma^2) outside.
//    So I = 1 exactly on every covered pixel (no gradient there) and decays as a Gaussian over ~sigma
//    outside the silhouette. D_f is C1 across edges (value 1, slope 0 on both sides). Interior edges
//    between adjacent faces leave no trace, which matters for our dense meshes (triangles ~3 px wide
//    at 256x256): gradients only come from the band of uncovered pixels around the silhouette.
//  * SoftProfile::Logistic (SoftRas, Liu et al. ICCV 2019):
//      D_f(p) = logistic(delta_f(p) d_f(p)^2 / sigma^2),  delta_f = +1 inside, -1 outside
//    (SoftRas's sigma equals our sigma^2 in pixel^2). Smooth on both sides of every edge, but a pixel
//    centre on an edge shared by two faces gets I = 0.75: on dense meshes the interior is mottled
//    (mean I ~0.85 inside a real 5226-face Cusick drape at sigma = 0.5 px) and interior vertices feel
//    spurious gradients. The distance inside a triangle has kinks on its medial axis (measure zero).
//
// Both tend to the hard silhouette as sigma -> 0 (the Gaussian profile to exactly hard_silhouette's
// closed coverage; the logistic one except on edges).
//
// Cutoff: pairs (p, f) with D_f(p) < epsilon are skipped: outside the face with d_f(p) > r_c,
//   r_c = sigma sqrt(ln(1/epsilon))        (Gaussian; 4.29 sigma for the default epsilon = 1e-8)
//   r_c = sigma sqrt(ln(1/epsilon - 1))    (Logistic; the same to 1e-8)
// Each face only visits its bounding box dilated by r_c, and rejects centres more than r_c behind one of
// its edge lines with three multiply-adds. Skipping changes I(p) by at most the sum of the skipped
// D_f(p): below 1e-6 while fewer than 100 faces lie within about 5 sigma of a pixel (measured on a real
// 5226-face drape at 256x256: max |error| 3e-8, 5e-8, 1.3e-7 for sigma = 0.5, 1, 2 px). The truncation
// makes I jump by up to epsilon when a pair crosses the cutoff; finite-difference checks at tiny steps
// should use a smaller epsilon. The Gaussian profile also skips every face whose dilated box holds no
// uncovered pixel (a summed-area table of the hard coverage), i.e. most of the interior.
//
// Cost (one core, median over 100 runs on a shared, loaded 2-core machine; 256x256, fabric 1 sample 1
// capture 1, 5226 faces; forward + backward): Gaussian 1.1 + 0.4 ms at sigma = 0.5 px, 1.8 + 1.2 ms at
// 1 px (default), 4.6 + 4.5 ms at 2 px; logistic 5.5 + 6.3 ms at 0.5 px, 12 + 14 ms at 1 px (it visits
// every pixel near every face). Strongly draping fabrics cost more (fabric 3: ~3.0 + 2.6 ms Gaussian
// 1 px: the hanging skirt projects many faces into the silhouette band). time_soft_render() measures it.
//
// Saturation (D_f -> 1) never produces NaN. Gaussian: 1 - D_f = -expm1(-d^2/sigma^2) is accurate for
// tiny d, covered pixels have T = 0 and are skipped, and the backward divides T by 1 - D_f only when that
// factor is nonzero (dI/dD_f = prod_{g != f} (1 - D_g) = T / (1 - D_f)). Logistic: the forward multiplies
// 1 - D_f = 1 / (1 + e^{x_f}), x_f = delta d^2 / sigma^2 (a factor with x_f > 40 is taken as 0: a change
// below 1e-17 in I; T below 1e-200 is flushed to 0), and the backward uses dI/dx_f = T D_f, with no division.
// Backward: dL/dq (image coordinates of each face corner) from d(d^2)/d(segment endpoints), then
// dL/dpositions = J^T dL/dq with the camera Jacobian J (render/camera.hpp).
//
// The forward keeps T (H x W), the positions, faces, projected vertices and per-face edge data for the
// backward; buffers are reused between calls of the same size. Single-threaded; one instance must not be
// used from two threads at once (separate instances are independent).
#pragma once
#include <memory>
#include <string>
#include <vector>

#include "geometry/mesh.hpp"
#include "render/camera.hpp"
#include "util/image.hpp"

namespace drapelab {

enum class SoftProfile { Gaussian, Logistic };

struct SoftRasterOptions {
  double sigma = 1.0;                         // pixels: width of the soft edge (formulas above); > 0
  double epsilon = 1e-8;                      // D_f below this is skipped (cutoff above); in (0, 0.5)
  SoftProfile profile = SoftProfile::Gaussian;
};

// "gaussian" / "logistic" (throws InputError naming the accepted values otherwise).
SoftProfile soft_profile_from_string(const std::string& name);
std::string to_string(SoftProfile profile);

class SoftRasterizer {
 public:
  explicit SoftRasterizer(const Camera& camera, SoftRasterOptions options = {});

  // Soft occupancy image (camera.height() x camera.width()), values in [0, 1]. Throws InputError on
  // non-finite positions, out-of-range face indices or vertices behind a perspective camera.
  Image forward(const MatrixX3d& positions, const MatrixX3i& faces);

  // dL/dpositions (V x 3) of the last forward, given dL/dI (same size as the image, finite).
  MatrixX3d backward(const Image& grad_image) const;

  const Camera& camera() const { return *camera_; }
  const SoftRasterOptions& options() const { return options_; }
  double cutoff_radius_px() const { return cutoff_radius_; }
  // T = 1 - I of the last forward.
  const Image& transmittance() const { return transmittance_; }

  // Edge data of one projected face (image coordinates), exposed for the implementation only.
  struct FaceEdges {
    double vx[3], vy[3];      // corners
    double ex[3], ey[3];      // edges v[k+1] - v[k]
    double inv_len2[3];       // 1 / |e_k|^2 (0 for a zero-length edge)
    double orientation;       // +1 / -1 for counter-clockwise / clockwise in image coordinates, 0 degenerate
    double la[3], lb[3], lc[3];  // signed distance to edge line k: la px + lb py + lc (pixels, > 0 inside)
    int col0, col1, row0, row1;  // pixels visited (inclusive; empty when col0 > col1 or row0 > row1)
  };

 private:
  void forward_gaussian();
  void forward_logistic();
  void backward_gaussian(const Image& grad_image, MatrixX2d& grad_points) const;
  void backward_logistic(const Image& grad_image, MatrixX2d& grad_points) const;
  void accumulate_corner_gradients(size_t face, const double gx[3], const double gy[3], MatrixX2d& grad_points) const;

  std::unique_ptr<Camera> camera_;
  SoftRasterOptions options_;
  double inv_sigma2_ = 0, cutoff_d2_ = 0, cutoff_radius_ = 0;
  // State of the last forward.
  bool has_forward_ = false;
  MatrixX3d positions_;
  MatrixX3i faces_;
  MatrixX2d image_points_;
  std::vector<FaceEdges> face_edges_;
  Image transmittance_;
  std::vector<int> uncovered_sum_;   // summed-area table of uncovered pixels ((H+1) x (W+1)), Gaussian only
  std::vector<int> next_uncovered_;  // per row, first uncovered column >= c (H x (W+1)), Gaussian only
};

// Timing of forward + backward on a mesh (median over `repeats` runs, milliseconds), for the bench driver.
struct RenderTiming {
  double forward_ms = 0;
  double backward_ms = 0;
  int repeats = 0;
  int width = 0, height = 0, faces = 0;
};
RenderTiming time_soft_render(const TriangleMesh& mesh, int repeats, const Camera& camera = OrthographicCamera(),
                              SoftRasterOptions options = {});

}  // namespace drapelab
