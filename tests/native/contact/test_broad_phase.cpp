// The hash-grid broad phase returns exactly the box-overlapping pairs that brute force finds (static and swept,
// self and cross filters), on crumpled random meshes.
#include <gtest/gtest.h>

#include <chrono>
#include <random>

#include "contact/broad_phase.hpp"
#include "contact/diagnostics.hpp"
#include "contact_support.hpp"

namespace drapelab {
namespace {

ContactPositions crumpled(const TriangleMesh& m, double amplitude, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> n01(0.0, 1.0);
  ContactPositions P = m.positions;
  for (int i = 0; i < P.rows(); ++i) {
    P(i, 2) += amplitude * std::sin(20 * P(i, 0)) * std::cos(17 * P(i, 1));
    for (int k = 0; k < 3; ++k) P(i, k) += 0.3 * amplitude * n01(rng);
  }
  return P;
}

void expect_same(const CandidatePairs& a, const CandidatePairs& b) {
  auto pt = a.point_triangle, pt2 = b.point_triangle, ee = a.edge_edge, ee2 = b.edge_edge;
  std::sort(pt.begin(), pt.end());
  std::sort(pt2.begin(), pt2.end());
  std::sort(ee.begin(), ee.end());
  std::sort(ee2.begin(), ee2.end());
  EXPECT_EQ(pt, pt2);
  EXPECT_EQ(ee, ee2);
}

TEST(BroadPhase, MatchesBruteForceOnRandomMeshes) {
  const TriangleMesh m = testing::grid_mesh(14, 0.1);
  const ContactSurfaces s = make_contact_surfaces(m.faces, m.num_vertices());
  for (unsigned seed = 0; seed < 4; ++seed) {
    const ContactPositions x0 = crumpled(m, 0.01, seed), x1 = crumpled(m, 0.01, seed + 10);
    for (double inflation : {0.0, 1e-3, 0.02}) {
      SCOPED_TRACE(inflation);
      const CandidatePairs a = broad_phase(s, x0, nullptr, inflation, PairFilter::kSelf);
      expect_same(a, broad_phase_brute_force(s, x0, nullptr, inflation, PairFilter::kSelf));
      const CandidatePairs b = broad_phase(s, x0, &x1, inflation, PairFilter::kSelf);
      expect_same(b, broad_phase_brute_force(s, x0, &x1, inflation, PairFilter::kSelf));
      if (inflation > 0) EXPECT_FALSE(a.point_triangle.empty() || a.edge_edge.empty());
      for (const auto& q : a.point_triangle)
        for (int v : s.faces[q[1]]) EXPECT_NE(v, q[0]);  // no pair sharing a vertex
    }
  }
}

TEST(BroadPhase, CrossFilterKeepsOnlyClothObstaclePairs) {
  const TriangleMesh m = testing::grid_mesh(10, 0.1, 0.0);
  const ObstacleMesh sphere = testing::icosphere(2, 0.03, {0, 0, -0.029});
  const ContactSurfaces s = make_contact_surfaces(m.faces, m.num_vertices(), &sphere);
  ContactPositions P(s.num_vertices(), 3);
  P.topRows(m.num_vertices()) = m.positions;
  P.bottomRows(sphere.positions.rows()) = sphere.positions;
  const CandidatePairs a = broad_phase(s, P, nullptr, 2e-3, PairFilter::kCross);
  expect_same(a, broad_phase_brute_force(s, P, nullptr, 2e-3, PairFilter::kCross));
  ASSERT_FALSE(a.point_triangle.empty());
  for (const auto& q : a.point_triangle) EXPECT_NE(s.vertex_group[q[0]], s.face_group(q[1]));
  for (const auto& q : a.edge_edge) EXPECT_NE(s.edge_group(q[0]), s.edge_group(q[1]));
}

}  // namespace
}  // namespace drapelab

namespace drapelab {
namespace {

// Probe for docs/lab/contact-broad-phase.md: the hash grid on a crumpled 20k-triangle sheet (101 x 101
// vertices), static (dhat 1 mm) and swept (a random step of 2 mm per vertex), against brute force on a 5k one.
TEST(BroadPhase, DISABLED_ProbeTwentyThousandTriangles) {
  for (int n : {51, 101}) {
    const TriangleMesh m = testing::grid_mesh(n, 0.3);
    const ContactSurfaces s = make_contact_surfaces(m.faces, m.num_vertices());
    const ContactPositions x0 = crumpled(m, 0.01, 1), x1 = crumpled(m, 0.01, 1) + 2e-3 * ContactPositions::Random(x0.rows(), 3);
    auto time = [&](auto&& f) {
      const auto t0 = std::chrono::steady_clock::now();
      size_t count = 0;
      for (int r = 0; r < 5; ++r) count = f();
      return std::make_pair(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count() / 5, count);
    };
    const auto st = time([&] {
      const auto c = broad_phase(s, x0, nullptr, 1e-3, PairFilter::kSelf);
      return c.point_triangle.size() + c.edge_edge.size();
    });
    const auto sw = time([&] {
      const auto c = broad_phase(s, x0, &x1, 0.0, PairFilter::kSelf);
      return c.point_triangle.size() + c.edge_edge.size();
    });
    std::printf("%zu triangles: hash static %.2f ms (%zu pairs), swept %.2f ms (%zu pairs)\n", s.faces.size(),
                1e3 * st.first, st.second, 1e3 * sw.first, sw.second);
    if (n == 51) {
      const auto t0 = std::chrono::steady_clock::now();
      const auto c = broad_phase_brute_force(s, x0, nullptr, 1e-3, PairFilter::kSelf);
      std::printf("  brute force static %.1f ms (%zu pairs)\n",
                  1e3 * std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(),
                  c.point_triangle.size() + c.edge_edge.size());
    }
  }
}

}  // namespace
}  // namespace drapelab

namespace drapelab {
namespace {

TEST(ContactReport, CountsClothPairsAndNotTheObstacleItself) {
  // Two crossing cloth sheets (one intersecting pair region) over an obstacle made of two crossing plates (its
  // own intersection is not reported), the cloth clear of the plates.
  TriangleMesh a = testing::grid_mesh(3, 0.02, 0.0);
  MatrixX3i faces(2 * a.num_faces(), 3);
  faces << a.faces, a.faces.array() + a.num_vertices();
  Eigen::VectorXd x(6 * a.num_vertices());
  for (int i = 0; i < a.num_vertices(); ++i) {
    x.segment<3>(3 * i) = a.positions.row(i).transpose();
    // the second sheet: vertical, through the first along x = 0.001
    x.segment<3>(3 * (i + a.num_vertices())) = Eigen::Vector3d(0.001, a.positions(i, 1), a.positions(i, 0));
  }
  ObstacleMesh plates;
  plates.positions.resize(8, 3);
  plates.positions << -0.01, -0.01, -0.05, 0.01, -0.01, -0.05, 0.01, 0.01, -0.05, -0.01, 0.01, -0.05,  //
      0.0, -0.01, -0.06, 0.0, 0.01, -0.06, 0.0, 0.01, -0.04, 0.0, -0.01, -0.04;
  plates.faces.resize(4, 3);
  plates.faces << 0, 1, 2, 0, 2, 3, 4, 5, 6, 4, 6, 7;
  const ContactReport r = contact_report(faces, x, &plates);
  EXPECT_GT(r.intersecting_pairs, 0);
  for (const auto& q : r.first_pairs) {
    EXPECT_LT(q[0], faces.rows()) << "an obstacle-obstacle pair was reported";
    EXPECT_LT(std::min(q[0], q[1]), faces.rows());
  }
  // the cloth alone: the same count (the plates are 4 cm below)
  EXPECT_EQ(contact_report(faces, x).intersecting_pairs, r.intersecting_pairs);
  // the plates' own intersection is not counted
  ContactSurfaces s = make_contact_surfaces(MatrixX3i(0, 3), 0, &plates);
  EXPECT_EQ(contact_report(s, plates.positions, PairFilter::kAll).intersecting_pairs, 0);
}

}  // namespace
}  // namespace drapelab
