// Wavefront OBJ read/write (v, vt, f; polygons are fan-triangulated).
#pragma once
#include <istream>
#include <string>

#include "geometry/mesh.hpp"

namespace drapelab {

// Reads positions and faces. The rest (u,v) pattern is (x, y) of the positions (flat specimens lie in
// z = 0; `vt` is not read: texture space has no unit). Garment patterns come with the garment module.
// Throws InputError naming the file and the problem.
TriangleMesh read_obj(const std::string& path);

// The same from a stream of OBJ text; `source` names it in error messages.
TriangleMesh read_obj(std::istream& in, const std::string& source);

// Writes positions (and uv as vt) atomically: a temporary file renamed into place.
void write_obj(const std::string& path, const MatrixX3d& positions, const MatrixX3i& faces,
               const MatrixX2d* uv = nullptr);

}  // namespace drapelab
