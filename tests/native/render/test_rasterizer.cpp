// Hard silhouette rasterizer: coverage rules, the calibrated Cusick disk area, bad input.
#include <gtest/gtest.h>

#include <cmath>

#include "geometry/cusick.hpp"
#include "render/rasterizer.hpp"
#include "util/error.hpp"

using namespace drapelab;

TEST(HardRasterTest, DiskAreaMatchesCalibration) {
  // A 0.15 m disk at 720 px/m has radius 108 px.
  const TriangleMesh disk = make_cusick_specimen(2699);
  const OrthographicCamera camera;
  const Image image = hard_silhouette(camera, disk.positions, disk.faces);
  ASSERT_EQ(image.rows(), 256);
  ASSERT_EQ(image.cols(), 256);
  const double expected = M_PI * 108.0 * 108.0;
  EXPECT_NEAR(image.sum(), expected, 0.01 * expected);
  EXPECT_EQ(image(128, 128), 1.0);
  EXPECT_EQ(image(0, 0), 0.0);
  EXPECT_TRUE(((image == 0.0) || (image == 1.0)).all());
}

TEST(HardRasterTest, SquareCoversExactlyItsPixelCentres) {
  // Square [10.2, 20.7] x [30.0, 35.5] in image coordinates: columns 10..20 (centres 10.5..20.5),
  // rows 30..34 (centre 35.5 lies on the closed boundary, so row 35 counts too).
  const OrthographicCamera camera(1.0, 0.0, 0.0, 64, 48);  // col = x, row = -y
  MatrixX3d positions(4, 3);
  positions << 10.2, -30.0, 0, 20.7, -30.0, 0, 20.7, -35.5, 0, 10.2, -35.5, 0;
  MatrixX3i faces(2, 3);
  faces << 0, 1, 2, 0, 3, 2;  // mixed orientation on purpose
  const Image image = hard_silhouette(camera, positions, faces);
  ASSERT_EQ(image.rows(), 48);
  ASSERT_EQ(image.cols(), 64);
  EXPECT_EQ(image.sum(), 11.0 * 6.0);
  EXPECT_EQ(image.block(30, 10, 6, 11).sum(), 66.0);
}

TEST(HardRasterTest, ClipsToImageAndSkipsDegenerateFaces) {
  const OrthographicCamera camera(1.0, 0.0, 0.0, 16, 16);
  MatrixX3d positions(5, 3);
  // Image points (col, row) = (x, -y): a triangle much larger than the image, and a degenerate one.
  positions << -100, 100, 0, 100, 100, 0, 0, -100, 0, 3, -3, 0, 9, -9, 0;
  MatrixX3i faces(2, 3);
  faces << 0, 1, 2, 3, 4, 3;
  const Image image = hard_silhouette(camera, positions, faces);
  EXPECT_EQ(image.sum(), 256.0);
  positions.col(0).array() += 300.0;  // now entirely right of the image
  EXPECT_EQ(hard_silhouette(camera, positions, faces).sum(), 0.0);
}

TEST(HardRasterTest, BadInputThrowsInputError) {
  const OrthographicCamera camera;
  MatrixX3d positions(3, 3);
  positions << 0, 0, 0, 0.1, 0, 0, 0, 0.1, 0;
  MatrixX3i faces(1, 3);
  faces << 0, 1, 3;
  try {
    hard_silhouette(camera, positions, faces);
    FAIL() << "out-of-range face accepted";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("face 0 refers to vertex 3"), std::string::npos) << e.what();
  }
  faces << 0, 1, 2;
  positions(1, 2) = NAN;
  try {
    hard_silhouette(camera, positions, faces);
    FAIL() << "NaN position accepted";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("vertex 1 is not finite"), std::string::npos) << e.what();
  }
  positions(1, 2) = 0.8;
  EXPECT_THROW(hard_silhouette(PerspectiveCamera(), positions, faces), InputError);  // above the eye
  EXPECT_THROW(hard_silhouette(camera, MatrixX3d(0, 3), MatrixX3i(0, 3)), InputError);
}

TEST(HardRasterTest, IouOfSilhouettes) {
  Image a = Image::Zero(4, 4), b = Image::Zero(4, 4);
  EXPECT_EQ(silhouette_iou(a, b), 1.0);
  a.block(0, 0, 2, 4) = 1.0;
  b.block(1, 0, 2, 4) = 1.0;
  EXPECT_DOUBLE_EQ(silhouette_iou(a, b), 4.0 / 12.0);
  EXPECT_THROW(silhouette_iou(a, Image::Zero(3, 4)), InputError);
}
