#include "measure/mesh_comparison.hpp"

#include "render/camera.hpp"
#include "render/rasterizer.hpp"
#include "util/error.hpp"

namespace drapelab {

MeshComparison compare_mesh_to_silhouette(const MatrixX3d& positions, const MatrixX3i& faces,
                                          const Silhouette& silhouette, const MeshComparisonOptions& options) {
  if (positions.rows() == 0 || faces.rows() == 0)
    throw InputError("compare: the mesh has no vertices or no faces");
  if (!positions.allFinite()) throw InputError("compare: the mesh has non-finite vertex positions");
  if (faces.minCoeff() < 0 || faces.maxCoeff() >= positions.rows())
    throw InputError("compare: the mesh has a face index outside 0.." + std::to_string(positions.rows() - 1));
  const int w = static_cast<int>(silhouette.mask.cols()), h = static_cast<int>(silhouette.mask.rows());
  const Calibration& cal = silhouette.calibration;
  const OrthographicCamera ortho(cal.px_per_m, cal.cx, cal.cy, w, h);
  MeshComparison out;
  const Image shadow = hard_silhouette(ortho, positions, faces);
  if (options.camera == CameraModel::Orthographic) {
    out.model_mask = shadow;
  } else {
    if (!(options.fov_y > 0 && options.fov_y < 3.1) || !(options.eye_height > 0))
      throw InputError("compare: perspective camera needs 0 < fov_y < pi and eye_height > 0");
    out.model_mask = hard_silhouette(PerspectiveCamera(options.fov_y, options.eye_height, w, h), positions, faces);
  }
  if (out.model_mask.sum() == 0)
    throw InputError("compare: the mesh casts no silhouette in the " + std::to_string(w) + "x" + std::to_string(h) +
                     " image under this camera (wrong units or camera?)");
  out.iou = iou(out.model_mask, silhouette.mask);
  out.mse = pixel_mse(out.model_mask, silhouette.mask);
  out.mesh = measure_drape(shadow, cal, options.measurement);
  out.image = measure_drape(silhouette.mask, cal, options.measurement);
  out.r_theta = r_theta_rmse(out.image.r_theta_m, out.mesh.r_theta_m);
  return out;
}

}  // namespace drapelab
