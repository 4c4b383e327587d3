// A single-channel image: rows top to bottom, columns left to right, values usually in [0, 1].
//
// Continuous image coordinates: pixel (row r, column c) covers [c, c+1) x [r, r+1), its centre is
// (c + 0.5, r + 0.5). For the bundled Cusick data the disk centre is at (128, 128) in these coordinates.
#pragma once
#include <Eigen/Core>

namespace drapelab {

using Image = Eigen::Array<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

}  // namespace drapelab
