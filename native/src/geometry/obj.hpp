// Wavefront OBJ read/write (v, vt, f; polygons are fan-triangulated).
#pragma once
#include <string>

#include "geometry/mesh.hpp"

namespace drapelab {

// Reads positions and faces. The rest (u,v) pattern comes from `vt` when every face vertex has one
// and `vt` spans metres-scale coordinates consistently; otherwise from (x, y) of the positions
// (flat specimens lie in z = 0). Throws InputError naming the file and the problem.
TriangleMesh read_obj(const std::string& path);

// Writes positions (and uv as vt) atomically: a temporary file renamed into place.
void write_obj(const std::string& path, const MatrixX3d& positions, const MatrixX3i& faces,
               const MatrixX2d* uv = nullptr);

}  // namespace drapelab
