// Per-corner pattern coordinates (TriangleMesh::corner_uv): a sewn garment simulated as one welded mesh, whose
// seam vertices lie on two pattern pieces, has the same stretching as its pieces simulated apart, one more
// bending edge per seam edge (oriented by its first face's piece), and the same total mass.
#include <gtest/gtest.h>

#include <random>

#include "../test_support.hpp"
#include "physics/model.hpp"
#include "util/error.hpp"

using namespace drapelab;

namespace {

// Two 10 cm squares side by side in 3D (x in [0, 0.1] and [0.1, 0.2]), cut as two pieces: A at its place in the
// pattern, B shifted by 0.1 m and turned by 90 degrees (its grain line runs along 3D x).
struct TwoPieces {
  TriangleMesh welded, apart;
  std::vector<int> apart_to_welded;
};

TwoPieces two_pieces() {
  const double s = 0.1;
  TwoPieces t;
  t.welded.positions.resize(6, 3);
  t.welded.positions << 0, 0, 0, s, 0, 0, s, s, 0, 0, s, 0, 2 * s, 0, 0, 2 * s, s, 0;
  t.welded.faces.resize(4, 3);
  t.welded.faces << 0, 1, 2, 0, 2, 3, 1, 4, 5, 1, 5, 2;
  t.welded.uv = t.welded.positions.leftCols<2>();  // ignored where corner_uv is given
  auto b_uv = [&](int v) {  // piece B: rotated by 90 degrees about (s, 0), then shifted by (s, 0)
    const Eigen::Vector2d p = t.welded.positions.row(v).leftCols<2>().transpose() - Eigen::Vector2d(s, 0);
    return Eigen::Vector2d(2 * s - p.y() + s, p.x());
  };
  t.welded.corner_uv.resize(12, 2);
  for (int f = 0; f < 4; ++f)
    for (int k = 0; k < 3; ++k) {
      const int v = t.welded.faces(f, k);
      t.welded.corner_uv.row(3 * f + k) =
          f < 2 ? Eigen::Vector2d(t.welded.positions.row(v).leftCols<2>().transpose()).transpose()
                : b_uv(v).transpose();
    }
  // Apart: A's vertices 0-3, B's copies of 1, 4, 5, 2 as 4-7.
  t.apart_to_welded = {0, 1, 2, 3, 1, 4, 5, 2};
  t.apart.positions.resize(8, 3);
  t.apart.uv.resize(8, 2);
  for (int i = 0; i < 8; ++i) {
    const int v = t.apart_to_welded[i];
    t.apart.positions.row(i) = t.welded.positions.row(v);
    t.apart.uv.row(i) = i < 4 ? Eigen::RowVector2d(t.welded.positions.row(v).leftCols<2>()) : b_uv(v).transpose();
  }
  t.apart.faces.resize(4, 3);
  t.apart.faces << 0, 1, 2, 0, 2, 3, 4, 5, 6, 4, 6, 7;
  orient_faces_ccw(t.welded);
  orient_faces_ccw(t.apart);
  return t;
}

double term_energy(const Model& m, const std::string& name, const Eigen::VectorXd& x, const Eigen::VectorXd& p) {
  for (const auto& t : m.terms())
    if (t->name() == name) return t->energy(x, p);
  ADD_FAILURE() << "no term " << name;
  return 0;
}

}  // namespace

TEST(CornerUv, WeldedPiecesStretchAsThePiecesApart) {
  TwoPieces t = two_pieces();
  validate_mesh(t.welded);
  validate_mesh(t.apart);
  const Eigen::VectorXd aw = rest_areas(t.welded), aa = rest_areas(t.apart);
  for (int f = 0; f < 4; ++f) EXPECT_NEAR(aw[f], aa[f], 1e-15);
  EXPECT_GT(aw.minCoeff(), 0.0);
  ModelOptions o;
  o.heterogeneous = true;
  o.held_vertices = {0};
  const Model mw(t.welded, o), ma(t.apart, o);
  EXPECT_NEAR(mw.area_weights().sum(), ma.area_weights().sum(), 1e-15);
  EXPECT_NEAR(mw.area_weights()[1], ma.area_weights()[1] + ma.area_weights()[4], 1e-15);
  EXPECT_EQ(ma.bending_edges().size(), 2u);
  EXPECT_EQ(mw.bending_edges().size(), 3u);  // + the seam edge 1-2
  // A generic deformed state (both pieces strained, the seam folded): equal stretching energy.
  std::mt19937 rng(3);
  std::normal_distribution<double> n(0.0, 0.01);
  Eigen::VectorXd xw(18), xa(24);
  for (int i = 0; i < 18; ++i) xw[i] = t.welded.positions(i / 3, i % 3) + n(rng);
  for (int i = 0; i < 8; ++i) xa.segment<3>(3 * i) = xw.segment<3>(3 * t.apart_to_welded[i]);
  Eigen::VectorXd pw = mw.default_parameters(), pa = ma.default_parameters();
  const double ew = term_energy(mw, "stretch", xw, pw), ea = term_energy(ma, "stretch", xa, pa);
  EXPECT_GT(ea, 0.0);
  EXPECT_NEAR(ew, ea, 1e-12 * ea);
  // The seam edge bends (a fold across it costs energy the pieces apart do not have).
  EXPECT_GT(term_energy(mw, "bend", xw, pw), term_energy(ma, "bend", xa, pa));
  // At rest (flat), nothing bends.
  Eigen::VectorXd rest(18);
  for (int i = 0; i < 18; ++i) rest[i] = t.welded.positions(i / 3, i % 3);
  EXPECT_NEAR(term_energy(mw, "bend", rest, pw), 0.0, 1e-18);
  EXPECT_NEAR(term_energy(mw, "stretch", rest, pw), 0.0, 1e-18);
}

TEST(CornerUv, OrientationSwapsCornersAndBadShapesAreRefused) {
  TwoPieces t = two_pieces();
  TriangleMesh m = t.welded;
  std::swap(m.faces(2, 1), m.faces(2, 2));
  m.corner_uv.row(7).swap(m.corner_uv.row(8));
  EXPECT_LT(rest_areas(m)[2], 0.0);
  orient_faces_ccw(m);
  EXPECT_EQ(m.faces, t.welded.faces);
  EXPECT_EQ(m.corner_uv, t.welded.corner_uv);
  TriangleMesh bad = t.welded;
  bad.corner_uv.conservativeResize(11, 2);
  EXPECT_THROW(validate_mesh(bad), InputError);
  bad = t.welded;
  bad.corner_uv(4, 1) = std::nan("");
  EXPECT_THROW(validate_mesh(bad), InputError);
  const TriangleMesh permuted = permute_vertices(t.welded, {5, 4, 3, 2, 1, 0});
  EXPECT_EQ(permuted.corner_uv, t.welded.corner_uv);
  EXPECT_NEAR(rest_areas(permuted).sum(), rest_areas(t.welded).sum(), 1e-15);
}
