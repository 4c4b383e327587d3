// Silhouette rasterizers: hard (for metrics) and soft (differentiable, SoftRas/DIB-R family; see
// render/soft_rasterizer.hpp).
#pragma once
#include <algorithm>
#include <cmath>
#include <memory>

#include "geometry/mesh.hpp"
#include "render/camera.hpp"
#include "util/image.hpp"

namespace drapelab {

// Binary silhouette (1 where a pixel centre is covered by any projected triangle).
// Coverage is closed (a centre exactly on an edge counts) and independent of face orientation;
// faces whose projection has zero area cover nothing. Image size = camera.width() x camera.height().
Image hard_silhouette(const Camera& camera, const MatrixX3d& positions, const MatrixX3i& faces);

// Checks renderer input: non-empty, finite positions, face indices in [0, V), every vertex in front of
// the camera. Throws InputError naming the first offending vertex/face.
void check_render_input(const Camera& camera, const MatrixX3d& positions, const MatrixX3i& faces);

// Image coordinates (col, row) of every vertex (V x 2, pixels).
MatrixX2d project_vertices(const Camera& camera, const MatrixX3d& positions);

// Sets image(r, c) = value at every pixel centre covered by a projected triangle (the coverage rule of
// hard_silhouette). image_points: (col, row) of every vertex; indices are not checked here.
void fill_covered_pixels(const MatrixX2d& image_points, const MatrixX3i& faces, Image& image, double value);

// Pixel index range whose centres c + 0.5 lie in [lo, hi], clamped to [0, size) (first > last when empty);
// safe for any finite coordinate.
inline int first_pixel(double lo, int size) {
  return static_cast<int>(std::clamp(std::ceil(lo - 0.5), 0.0, static_cast<double>(size)));
}
inline int last_pixel(double hi, int size) {
  return static_cast<int>(std::clamp(std::floor(hi - 0.5), -1.0, size - 1.0));
}

// Intersection over union of two silhouettes thresholded at 0.5 (1 when both are empty).
double silhouette_iou(const Image& a, const Image& b);

}  // namespace drapelab
