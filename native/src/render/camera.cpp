#include "render/camera.hpp"

#include <cmath>
#include <sstream>

#include "util/error.hpp"

namespace drapelab {

namespace {

void check_image_size(const char* camera, int width, int height) {
  if (width <= 0 || height <= 0) {
    std::ostringstream os;
    os << camera << ": image size must be positive, got " << width << "x" << height;
    throw InputError(os.str());
  }
}

}  // namespace

OrthographicCamera::OrthographicCamera(double px_per_m, double cx, double cy, int width, int height)
    : s_(px_per_m), cx_(cx), cy_(cy), width_(width), height_(height) {
  if (!std::isfinite(px_per_m) || px_per_m <= 0.0)
    throw InputError("OrthographicCamera: px_per_m must be positive and finite, got " + std::to_string(px_per_m));
  if (!std::isfinite(cx) || !std::isfinite(cy)) throw InputError("OrthographicCamera: centre (cx, cy) must be finite");
  check_image_size("OrthographicCamera", width, height);
}

Eigen::Vector2d OrthographicCamera::project(const Eigen::Vector3d& p, Eigen::Matrix<double, 2, 3>* jacobian) const {
  if (jacobian) *jacobian << s_, 0.0, 0.0, 0.0, -s_, 0.0;
  return {cx_ + s_ * p.x(), cy_ - s_ * p.y()};
}

PerspectiveCamera::PerspectiveCamera(double fov_y, double eye_height, int width, int height)
    : fov_y_(fov_y), eye_height_(eye_height), width_(width), height_(height) {
  if (!std::isfinite(fov_y) || fov_y <= 0.0 || fov_y >= M_PI)
    throw InputError("PerspectiveCamera: fov_y must lie in (0, pi) radians, got " + std::to_string(fov_y));
  if (!std::isfinite(eye_height) || eye_height <= 0.0)
    throw InputError("PerspectiveCamera: eye_height must be positive and finite (m), got " +
                     std::to_string(eye_height));
  check_image_size("PerspectiveCamera", width, height);
}

double PerspectiveCamera::focal_px() const { return 0.5 * height_ / std::tan(0.5 * fov_y_); }

Eigen::Vector2d PerspectiveCamera::project(const Eigen::Vector3d& p, Eigen::Matrix<double, 2, 3>* jacobian) const {
  const double f = focal_px();
  const double depth = eye_height_ - p.z();
  // A point at or above the eye has no image; renderers check in_front() before projecting.
  const double inv = 1.0 / depth;
  const double col = 0.5 * width_ + f * p.x() * inv;
  const double row = 0.5 * height_ - f * p.y() * inv;
  if (jacobian) {
    // d(1/depth)/dz = 1/depth^2
    *jacobian << f * inv, 0.0, f * p.x() * inv * inv,
                 0.0, -f * inv, -f * p.y() * inv * inv;
  }
  return {col, row};
}

}  // namespace drapelab
