// A 3D drape (mesh) against a measured silhouette: pixel agreement under a camera model, and the
// rotation-free measures of both.
#pragma once
#include "measure/drape_measurement.hpp"
#include "measure/silhouette.hpp"

namespace drapelab {

enum class CameraModel {
  Orthographic,  // the silhouette's calibration (dataset: 720 px/m, centre at the image centre)
  Perspective,   // the paper's scripts: eye at (0, 0, eye_height) looking down -z, vertical fov fov_y
};

struct MeshComparisonOptions {
  CameraModel camera = CameraModel::Orthographic;
  double fov_y = 0.5;        // rad (perspective)
  double eye_height = 0.7;   // m (perspective)
  DrapeMeasurementOptions measurement;
};

struct MeshComparison {
  double iou = 0.0;            // model silhouette (camera) vs measured mask
  double mse = 0.0;            // pixel MSE of the two binary silhouettes
  DrapeMeasurement mesh;       // of the mesh's orthographic shadow at the silhouette's calibration
  DrapeMeasurement image;      // of the measured mask
  RThetaAlignment r_theta;     // measured r(theta) vs the mesh's, after the best rotation
  Image model_mask;            // the model silhouette under the chosen camera (image size)
};

// Renders the mesh (metres, support disk centred at the origin, z up) with a hard rasterizer. The
// drape coefficient, nodes and r(theta) of the mesh are always taken from its orthographic top-down
// shadow under the silhouette's calibration (a drape coefficient is defined on the true shadow), so
// only iou, mse and model_mask depend on the camera model.
MeshComparison compare_mesh_to_silhouette(const MatrixX3d& positions, const MatrixX3i& faces,
                                          const Silhouette& silhouette, const MeshComparisonOptions& options = {});

}  // namespace drapelab
