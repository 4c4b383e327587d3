// Silhouette rasterizers: hard (for metrics) and soft (differentiable, SoftRas/DIB-R family).
#pragma once
#include <memory>

#include "geometry/mesh.hpp"
#include "render/camera.hpp"
#include "util/image.hpp"

namespace drapelab {

// Binary silhouette (1 where a pixel centre is covered by any projected triangle).
Image hard_silhouette(const Camera& camera, const MatrixX3d& positions, const MatrixX3i& faces);

}  // namespace drapelab
