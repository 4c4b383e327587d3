// Real Cusick data: the README's drape-coefficient table (shared dataset, skipped when absent) and the
// bundled mesh/silhouette pair (always).
#include <gtest/gtest.h>

#include <map>

#include "geometry/obj.hpp"
#include "measure/manifest.hpp"
#include "measure/mesh_comparison.hpp"
#include "measure/silhouette.hpp"
#include "measure_test_support.hpp"

using namespace drapelab;
using namespace drapelab::measure_testing;

TEST(MeasureRealData, DrapeCoefficientsOfFabricsOneToFiveMatchTheReadmeTable) {
  const std::string dir = cusick_dir();
  if (dir.empty()) GTEST_SKIP() << kNoDatasetReason;
  const std::map<int, double> table = {{1, 0.504}, {2, 0.643}, {3, 0.157}, {4, 0.582}, {5, 0.795}};
  std::map<int, std::vector<double>> dc;
  for (const ManifestEntry& e : read_manifest(dir + "/manifest.csv", true)) {
    if (e.capture != 1 || !table.count(e.fabric)) continue;
    const Silhouette s = load_silhouette(e.silhouette);
    check_cusick_calibration(s.mask, s.calibration, e.silhouette);
    dc[e.fabric].push_back(drape_coefficient(s.mask, s.calibration.px_per_m));
  }
  for (const auto& [fabric, expected] : table) {
    ASSERT_EQ(dc[fabric].size(), 12u) << "fabric " << fabric;
    double mean = 0;
    for (double v : dc[fabric]) mean += v / dc[fabric].size();
    EXPECT_NEAR(mean, expected, 0.01) << "fabric " << fabric;
  }
}

TEST(MeasureRealData, EveryDatasetSilhouetteIsMeasurable) {
  const std::string dir = cusick_dir();
  if (dir.empty()) GTEST_SKIP() << kNoDatasetReason;
  int count = 0;
  for (const ManifestEntry& e : read_manifest(dir + "/manifest.csv", true)) {
    const Silhouette s = load_silhouette(e.silhouette);
    EXPECT_NO_THROW(check_cusick_calibration(s.mask, s.calibration, e.silhouette));
    EXPECT_TRUE(s.dark_on_light) << e.silhouette;
    const DrapeMeasurement m = measure_drape(s);
    EXPECT_GE(m.nodes.count, 1) << e.silhouette;  // fabric 20 (stiff, DC 0.9) has 2 folds
    EXPECT_LE(m.nodes.count, 16) << e.silhouette;
    ++count;
  }
  EXPECT_GT(count, 300);
}

TEST(MeasureRealData, BundledMeshMatchesItsSilhouetteOrthographically) {
  const TriangleMesh mesh = read_obj(asset("cusick/fabric_02/meshes/sample_02_capture_1.obj"));
  const Silhouette s = load_silhouette(asset("cusick/fabric_02/silhouettes/sample_02_capture_1.jpg"));
  const MeshComparison ortho = compare_mesh_to_silhouette(mesh.positions, mesh.faces, s);
  EXPECT_GT(ortho.iou, 0.97);
  EXPECT_LT(ortho.mse, 0.01);
  EXPECT_NEAR(ortho.mesh.drape_coefficient, ortho.image.drape_coefficient, 0.03);
  EXPECT_EQ(ortho.mesh.nodes.count, ortho.image.nodes.count);
  EXPECT_LT(ortho.r_theta.rmse_m, 0.003);
  // The README: the paper's perspective camera matches these images worse.
  MeshComparisonOptions o;
  o.camera = CameraModel::Perspective;
  const MeshComparison persp = compare_mesh_to_silhouette(mesh.positions, mesh.faces, s, o);
  EXPECT_LT(persp.iou, ortho.iou);
  // The mesh's own measures do not depend on the camera model.
  EXPECT_DOUBLE_EQ(persp.mesh.drape_coefficient, ortho.mesh.drape_coefficient);
}

TEST(MeasureRealData, MeshComparisonRejectsBadMeshes) {
  const Silhouette s = load_silhouette(asset("cusick/fabric_02/silhouettes/sample_02_capture_1.jpg"));
  MatrixX3d p(3, 3);
  p << 0, 0, 0, 1, 0, 0, 0, 1, 0;
  MatrixX3i f(1, 3);
  f << 0, 1, 5;
  expect_input_error([&] { compare_mesh_to_silhouette(p, f, s); }, {"face index"});
  f << 0, 1, 2;
  p *= 1e-6;  // a micro-mesh: no pixel centre covered
  expect_input_error([&] { compare_mesh_to_silhouette(p, f, s); }, {"casts no silhouette"});
}
