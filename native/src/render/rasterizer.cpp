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

Image hard_silhouette(const Camera& camera, const MatrixX3d& positions, const MatrixX3i& faces) {
  check_render_input(camera, positions, faces);
  const int width = camera.width(), height = camera.height();
  Image image = Image::Zero(height, width);
  const MatrixX2d q = project_vertices(camera, positions);
  for (Eigen::Index f = 0; f < faces.rows(); ++f) {
    const Eigen::Vector2d a = q.row(faces(f, 0)).transpose();
    const Eigen::Vector2d b = q.row(faces(f, 1)).transpose();
    const Eigen::Vector2d c = q.row(faces(f, 2)).transpose();
    const double area2 = (b - a).x() * (c - a).y() - (b - a).y() * (c - a).x();
    if (area2 == 0.0) continue;
    const double orient = area2 > 0.0 ? 1.0 : -1.0;
    // Pixel centres (c + 0.5, r + 0.5) inside the triangle's bounding box.
    const double xmin = std::min({a.x(), b.x(), c.x()}), xmax = std::max({a.x(), b.x(), c.x()});
    const double ymin = std::min({a.y(), b.y(), c.y()}), ymax = std::max({a.y(), b.y(), c.y()});
    const int c0 = std::max(0, static_cast<int>(std::ceil(xmin - 0.5)));
    const int c1 = std::min(width - 1, static_cast<int>(std::floor(xmax - 0.5)));
    const int r0 = std::max(0, static_cast<int>(std::ceil(ymin - 0.5)));
    const int r1 = std::min(height - 1, static_cast<int>(std::floor(ymax - 0.5)));
    if (c0 > c1 || r0 > r1) continue;
    // Edge functions e_k(p) = cross(v_{k+1} - v_k, p - v_k), all >= 0 (times orient) inside.
    const Eigen::Vector2d v[3] = {a, b, c};
    for (int r = r0; r <= r1; ++r) {
      const double py = r + 0.5;
      for (int col = c0; col <= c1; ++col) {
        const double px = col + 0.5;
        bool inside = true;
        for (int k = 0; k < 3 && inside; ++k) {
          const Eigen::Vector2d& p0 = v[k];
          const Eigen::Vector2d& p1 = v[(k + 1) % 3];
          const double e = (p1.x() - p0.x()) * (py - p0.y()) - (p1.y() - p0.y()) * (px - p0.x());
          inside = orient * e >= 0.0;
        }
        if (inside) image(r, col) = 1.0;
      }
    }
  }
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
