// Calibration: given, checked, and estimated from an undraped disk or from a reference mesh.
#include <gtest/gtest.h>

#include "geometry/cusick.hpp"
#include "geometry/obj.hpp"
#include "measure/calibration.hpp"
#include "measure/silhouette.hpp"
#include "measure_test_support.hpp"
#include "render/camera.hpp"
#include "render/rasterizer.hpp"

using namespace drapelab;
using namespace drapelab::measure_testing;

TEST(MeasureCalibration, DefaultIsTheDatasetCalibrationAtTheImageCentre) {
  const Calibration c = resolve_calibration({}, 256, 256, "img");
  EXPECT_DOUBLE_EQ(c.px_per_m, 720.0);
  EXPECT_DOUBLE_EQ(c.cx, 128.0);
  EXPECT_DOUBLE_EQ(c.cy, 128.0);
  const Calibration d = resolve_calibration({}, 300, 200, "img");
  EXPECT_DOUBLE_EQ(d.cx, 150.0);
  EXPECT_DOUBLE_EQ(d.cy, 100.0);
}

TEST(MeasureCalibration, InvalidCalibrationsAreClearErrors) {
  Calibration c;
  c.px_per_m = 0;
  expect_input_error([&] { resolve_calibration(c, 256, 256, "a.jpg"); }, {"a.jpg", "wrong calibration", "px_per_m"});
  c.px_per_m = std::nan("");
  expect_input_error([&] { resolve_calibration(c, 256, 256, "a.jpg"); }, {"a.jpg", "px_per_m"});
  c = Calibration{};
  c.cx = -1;
  c.cy = 5;
  expect_input_error([&] { resolve_calibration(c, 256, 256, "a.jpg"); }, {"a.jpg", "centre", "outside"});
}

TEST(MeasureCalibration, WrongScaleForACusickImageIsDetected) {
  const Silhouette s = load_silhouette(asset("cusick/fabric_02/silhouettes/sample_02_capture_1.jpg"));
  EXPECT_NO_THROW(check_cusick_calibration(s.mask, s.calibration, "ok.jpg"));
  Calibration small = s.calibration, large = s.calibration, off = s.calibration;
  small.px_per_m = 400;   // the drape would be 27 cm in radius: beyond the specimen
  large.px_per_m = 1500;  // the shadow would be smaller than the support disk
  off.cx = 60;            // the far side of the drape is then 17 cm from the centre
  expect_input_error([&] { check_cusick_calibration(s.mask, small, "x.jpg"); }, {"x.jpg", "wrong calibration"});
  expect_input_error([&] { check_cusick_calibration(s.mask, large, "x.jpg"); },
                     {"x.jpg", "wrong calibration", "smaller than the support disk"});
  expect_input_error([&] { check_cusick_calibration(s.mask, off, "x.jpg"); },
                     {"x.jpg", "wrong calibration", "beyond the specimen radius"});
}

TEST(MeasureCalibration, FromAnUndrapedDiskOfKnownDiameter) {
  const double s = 612.0, cx = 121.3, cy = 133.8;
  const Image m = polar_mask(256, 256, s, cx, cy, [](double) { return 0.15; });
  const Calibration c = calibrate_from_disk(m, 0.30, "flat.png");
  EXPECT_NEAR(c.px_per_m / s, 1.0, 0.003);
  EXPECT_NEAR(c.cx, cx, 0.05);
  EXPECT_NEAR(c.cy, cy, 0.05);
}

TEST(MeasureCalibration, FromADiskRejectsADrapeAndAnEmptyImage) {
  const Image drape = polar_mask(256, 256, 720, 128, 128, [](double t) { return 0.12 + 0.02 * std::cos(8 * t); });
  expect_input_error([&] { calibrate_from_disk(drape, 0.30, "drape.png"); }, {"drape.png", "not a flat disk"});
  expect_input_error([] { calibrate_from_disk(Image::Zero(64, 64), 0.30, "none.png"); }, {"none.png"});
  expect_input_error([] { calibrate_from_disk(Image::Ones(8, 8), -1, "x.png"); }, {"diameter"});
}

TEST(MeasureCalibration, FromAReferenceMeshRecoversAKnownCalibration) {
  const TriangleMesh mesh = read_obj(asset("cusick/fabric_02/meshes/sample_02_capture_1.obj"));
  const double s = 650.0, cx = 131.4, cy = 124.2;
  const Image m = hard_silhouette(OrthographicCamera(s, cx, cy, 256, 256), mesh.positions, mesh.faces);
  const MeshCalibrationFit fit = calibrate_from_mesh(m, mesh.positions, mesh.faces, "synthetic");
  EXPECT_NEAR(fit.calibration.px_per_m / s, 1.0, 0.003);
  EXPECT_NEAR(fit.calibration.cx, cx, 0.3);
  EXPECT_NEAR(fit.calibration.cy, cy, 0.3);
  EXPECT_GT(fit.iou, 0.995);
}

TEST(MeasureCalibration, FromTheBundledMeshAndItsPhotoIsTheDatasetCalibration) {
  const TriangleMesh mesh = read_obj(asset("cusick/fabric_02/meshes/sample_02_capture_1.obj"));
  const Silhouette s = load_silhouette(asset("cusick/fabric_02/silhouettes/sample_02_capture_1.jpg"));
  const MeshCalibrationFit fit = calibrate_from_mesh(s.mask, mesh.positions, mesh.faces, "asset");
  // README: orthographic, 720 px/m, centre (128, 128).
  EXPECT_NEAR(fit.calibration.px_per_m, 720.0, 720.0 * 0.01);
  EXPECT_NEAR(fit.calibration.cx, 128.0, 1.0);
  EXPECT_NEAR(fit.calibration.cy, 128.0, 1.0);
  EXPECT_GT(fit.iou, 0.98);
}
