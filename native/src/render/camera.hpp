// Cameras: measurement models mapping 3D points (metres) to continuous image coordinates (pixels).
//
// Orthographic (calibrated, the bundled Cusick data): col = cx + s x, row = cy - s y, looking down -z,
//   s = px_per_m (720 for the dataset), (cx, cy) = (128, 128).
// Perspective (the paper's released scripts): eye at (0, 0, eye_height) looking down -z, +y up in the
//   image, vertical field of view fov_y (0.5 rad): col = W/2 + f x / (eye_height - z),
//   row = H/2 - f y / (eye_height - z), f = (H / 2) / tan(fov_y / 2).
#pragma once
#include <Eigen/Core>
#include <memory>
#include <string>

namespace drapelab {

class Camera {
 public:
  virtual ~Camera() = default;
  virtual int width() const = 0;
  virtual int height() const = 0;
  // Image coordinates (col, row) of a point, and d(col,row)/d(x,y,z) (2x3) when jacobian != nullptr.
  virtual Eigen::Vector2d project(const Eigen::Vector3d& p, Eigen::Matrix<double, 2, 3>* jacobian = nullptr) const = 0;
  virtual std::string kind() const = 0;
  // False when p has no image (a perspective camera: p at or above the eye plane); renderers reject such input.
  virtual bool in_front(const Eigen::Vector3d& p) const { return true; }
  // A copy, so renderers can own their measurement model independently of the caller's object.
  virtual std::unique_ptr<Camera> clone() const = 0;
};

class OrthographicCamera : public Camera {
 public:
  OrthographicCamera(double px_per_m = 720.0, double cx = 128.0, double cy = 128.0, int width = 256, int height = 256);
  int width() const override { return width_; }
  int height() const override { return height_; }
  Eigen::Vector2d project(const Eigen::Vector3d& p, Eigen::Matrix<double, 2, 3>* jacobian = nullptr) const override;
  std::string kind() const override { return "ortho"; }
  std::unique_ptr<Camera> clone() const override { return std::make_unique<OrthographicCamera>(*this); }
  double px_per_m() const { return s_; }
  Eigen::Vector2d centre() const { return {cx_, cy_}; }

 private:
  double s_, cx_, cy_;
  int width_, height_;
};

class PerspectiveCamera : public Camera {
 public:
  PerspectiveCamera(double fov_y = 0.5, double eye_height = 0.7, int width = 256, int height = 256);
  int width() const override { return width_; }
  int height() const override { return height_; }
  Eigen::Vector2d project(const Eigen::Vector3d& p, Eigen::Matrix<double, 2, 3>* jacobian = nullptr) const override;
  std::string kind() const override { return "perspective"; }
  // Points closer to the eye plane than min_depth (m) are rejected: their projection blows up.
  bool in_front(const Eigen::Vector3d& p) const override { return eye_height_ - p.z() > min_depth; }
  std::unique_ptr<Camera> clone() const override { return std::make_unique<PerspectiveCamera>(*this); }
  double fov_y() const { return fov_y_; }
  double eye_height() const { return eye_height_; }
  double focal_px() const;  // f = (H / 2) / tan(fov_y / 2), pixels
  static constexpr double min_depth = 1e-6;

 private:
  double fov_y_, eye_height_;
  int width_, height_;
};

}  // namespace drapelab
