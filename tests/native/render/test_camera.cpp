// Cameras: formulas of camera.hpp, Jacobians against central finite differences, bad parameters.
#include <gtest/gtest.h>

#include <cmath>

#include "render/camera.hpp"
#include "util/error.hpp"

using namespace drapelab;

namespace {

void expect_jacobian_matches_fd(const Camera& camera, const Eigen::Vector3d& p) {
  Eigen::Matrix<double, 2, 3> jacobian;
  camera.project(p, &jacobian);
  const double h = 1e-6;
  for (int k = 0; k < 3; ++k) {
    Eigen::Vector3d plus = p, minus = p;
    plus[k] += h;
    minus[k] -= h;
    const Eigen::Vector2d fd = (camera.project(plus) - camera.project(minus)) / (2 * h);
    for (int i = 0; i < 2; ++i)
      EXPECT_NEAR(jacobian(i, k), fd[i], 1e-6 * (1.0 + std::abs(fd[i]))) << camera.kind() << " d" << i << "/d" << k;
  }
}

}  // namespace

TEST(CameraTest, OrthographicMatchesCalibration) {
  const OrthographicCamera camera;  // 720 px/m, centre (128, 128), 256 x 256
  EXPECT_EQ(camera.width(), 256);
  EXPECT_EQ(camera.height(), 256);
  const Eigen::Vector2d centre = camera.project({0, 0, -0.05});
  EXPECT_DOUBLE_EQ(centre.x(), 128.0);
  EXPECT_DOUBLE_EQ(centre.y(), 128.0);
  const Eigen::Vector2d q = camera.project({0.1, 0.05, 0.0});  // +x right, +y up
  EXPECT_DOUBLE_EQ(q.x(), 128.0 + 72.0);
  EXPECT_DOUBLE_EQ(q.y(), 128.0 - 36.0);
}

TEST(CameraTest, PerspectiveMatchesFormula) {
  const PerspectiveCamera camera(0.5, 0.7, 256, 256);
  const double f = 128.0 / std::tan(0.25);
  EXPECT_NEAR(camera.focal_px(), f, 1e-12);
  const Eigen::Vector3d p(0.1, -0.05, -0.1);
  const Eigen::Vector2d q = camera.project(p);
  EXPECT_NEAR(q.x(), 128.0 + f * 0.1 / 0.8, 1e-12);
  EXPECT_NEAR(q.y(), 128.0 + f * 0.05 / 0.8, 1e-12);
  EXPECT_TRUE(camera.in_front(p));
  EXPECT_FALSE(camera.in_front({0, 0, 0.7}));
}

TEST(CameraTest, JacobiansMatchFiniteDifferences) {
  const OrthographicCamera ortho(500.0, 100.0, 90.0, 200, 180);
  const PerspectiveCamera persp(0.6, 0.9, 320, 240);
  for (const Eigen::Vector3d& p : {Eigen::Vector3d(0.1, -0.07, -0.12), Eigen::Vector3d(-0.13, 0.02, 0.05),
                                   Eigen::Vector3d(0.0, 0.0, 0.0)}) {
    expect_jacobian_matches_fd(ortho, p);
    expect_jacobian_matches_fd(persp, p);
  }
}

TEST(CameraTest, CloneKeepsParameters) {
  const PerspectiveCamera camera(0.4, 1.1, 128, 64);
  const auto copy = camera.clone();
  const Eigen::Vector3d p(0.03, 0.02, -0.2);
  EXPECT_EQ(copy->kind(), "perspective");
  EXPECT_EQ(copy->width(), 128);
  EXPECT_EQ(copy->height(), 64);
  EXPECT_EQ((copy->project(p) - camera.project(p)).norm(), 0.0);
}

TEST(CameraTest, BadParametersThrowInputError) {
  EXPECT_THROW(OrthographicCamera(0.0), InputError);
  EXPECT_THROW(OrthographicCamera(NAN), InputError);
  EXPECT_THROW(OrthographicCamera(720, 128, 128, 0, 256), InputError);
  EXPECT_THROW(PerspectiveCamera(0.0), InputError);
  EXPECT_THROW(PerspectiveCamera(4.0), InputError);
  EXPECT_THROW(PerspectiveCamera(0.5, -1.0), InputError);
  EXPECT_THROW(PerspectiveCamera(0.5, 0.7, 256, -3), InputError);
  try {
    OrthographicCamera(-5.0);
    FAIL();
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("px_per_m"), std::string::npos) << e.what();
  }
}
