// The Cusick drape specimen (BS EN ISO 9073-9): a 30 cm disk on an 18 cm support disk.
#pragma once
#include <string>

#include "geometry/mesh.hpp"

namespace drapelab {

struct CusickGeometry {
  double specimen_radius = 0.15;  // m
  double support_radius = 0.09;   // m: vertices with rest radius below this are held by the handle
};

// A flat disk mesh (z = 0, centred at the origin, u = x weft, v = y warp) of concentric rings with
// exactly `target_vertices` vertices (at least 7).
TriangleMesh make_cusick_specimen(int target_vertices, const CusickGeometry& geometry = {});

// Loads `template_dir`/circle{level}.obj (the Cusick template meshes, 297 / 1205 / 2699 / 4766 / 7496
// vertices). Throws InputError naming the path when the file is missing or has the wrong vertex count.
TriangleMesh load_cusick_template(int level, const std::string& template_dir);

// Vertex counts of the dataset's circle1..circle5.
int cusick_template_vertices(int level);

}  // namespace drapelab
