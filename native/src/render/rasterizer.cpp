#include "render/rasterizer.hpp"

#include <algorithm>
#include <cmath>
#include <sstream>

#include "util/error.hpp"

namespace drapelab {

void check_render_input(const Camera& camera, const MatrixX3d& positions, const MatrixX3i& faces) {
  const Index num_vertices = static_cast<Index>(positions.rows());
  if (num_vertices == 0) throw InputError("render: positions are empty (need V x 3 vertex positions)");
  for (Index v = 0; v < num_vertices; ++v) {
    const Eigen::Vector3d p = positions.row(v).transpose();
    if (!p.allFinite()) {
      std::ostringstream os;
      os << "render: position of vertex " << v << " is not finite (" << p.x() << ", " << p.y() << ", " << p.z()
         << ")";
      throw InputError(os.str());
    }
    if (!camera.in_front(p)) {
      std::ostringstream os;
      os << "render: vertex " << v << " at (" << p.x() << ", " << p.y() << ", " << p.z() << ") is not in front of the "
         << camera.kind() << " camera";
      throw InputError(os.str());
    }
  }
  for (Eigen::Index f = 0; f < faces.rows(); ++f) {
    for (int k = 0; k < 3; ++k) {
      const int i = faces(f, k);
      if (i < 0 || i >= num_vertices) {
        std::ostringstream os;
        os << "render: face " << f << " refers to vertex " << i << ", out of range [0, " << num_vertices << ")";
        throw InputError(os.str());
      }
    }
  }
}

MatrixX2d project_vertices(const Camera& camera, const MatrixX3d& positions) {
  MatrixX2d image_points(positions.rows(), 2);
  for (Eigen::Index v = 0; v < positions.rows(); ++v)
    image_points.row(v) = camera.project(positions.row(v).transpose()).transpose();
  return image_points;
}

void fill_covered_pixels(const MatrixX2d& q, const MatrixX3i& faces, Image& image, double value) {
  const int width = static_cast<int>(image.cols()), height = static_cast<int>(image.rows());
  for (Eigen::Index f = 0; f < faces.rows(); ++f) {
    const double x[3] = {q(faces(f, 0), 0), q(faces(f, 1), 0), q(faces(f, 2), 0)};
    const double y[3] = {q(faces(f, 0), 1), q(faces(f, 1), 1), q(faces(f, 2), 1)};
    const double area2 = (x[1] - x[0]) * (y[2] - y[0]) - (y[1] - y[0]) * (x[2] - x[0]);
    if (area2 == 0.0) continue;
    const double orient = area2 > 0.0 ? 1.0 : -1.0;
    // Pixel centres (c + 0.5, r + 0.5) inside the triangle's bounding box.
    const int c0 = first_pixel(std::min({x[0], x[1], x[2]}), width);
    const int c1 = last_pixel(std::max({x[0], x[1], x[2]}), width);
    const int r0 = first_pixel(std::min({y[0], y[1], y[2]}), height);
    const int r1 = last_pixel(std::max({y[0], y[1], y[2]}), height);
    // Edge functions e_k(p) = orient * cross(v_{k+1} - v_k, p - v_k) = a_k px + b_k py + c_k, all >= 0 on
    // the closed triangle.
    double ea[3], eb[3], ec[3];
    for (int k = 0; k < 3; ++k) {
      const int k1 = (k + 1) % 3;
      const double dx = orient * (x[k1] - x[k]), dy = orient * (y[k1] - y[k]);
      ea[k] = -dy;
      eb[k] = dx;
      ec[k] = dy * x[k] - dx * y[k];
    }
    for (int r = r0; r <= r1; ++r) {
      const double py = r + 0.5;
      double* row = image.data() + static_cast<Eigen::Index>(r) * width;
      const double row0 = eb[0] * py + ec[0], row1 = eb[1] * py + ec[1], row2 = eb[2] * py + ec[2];
      for (int col = c0; col <= c1; ++col) {
        const double px = col + 0.5;
        if (ea[0] * px + row0 >= 0.0 && ea[1] * px + row1 >= 0.0 && ea[2] * px + row2 >= 0.0) row[col] = value;
      }
    }
  }
}

Image hard_silhouette(const Camera& camera, const MatrixX3d& positions, const MatrixX3i& faces) {
  check_render_input(camera, positions, faces);
  Image image = Image::Zero(camera.height(), camera.width());
  fill_covered_pixels(project_vertices(camera, positions), faces, image, 1.0);
  return image;
}

double silhouette_iou(const Image& a, const Image& b) {
  if (a.rows() != b.rows() || a.cols() != b.cols()) {
    std::ostringstream os;
    os << "silhouette_iou: image sizes differ (" << a.rows() << "x" << a.cols() << " vs " << b.rows() << "x"
       << b.cols() << ")";
    throw InputError(os.str());
  }
  const auto ma = a > 0.5, mb = b > 0.5;
  const double inter = (ma && mb).cast<double>().sum();
  const double uni = (ma || mb).cast<double>().sum();
  return uni > 0.0 ? inter / uni : 1.0;
}

}  // namespace drapelab
