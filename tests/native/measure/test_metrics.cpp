// Metrics: closed-form cases (disks, sinusoidal folds, shifted curves, offset meshes) and brute force.
#include <gtest/gtest.h>

#include <random>

#include "geometry/cusick.hpp"
#include "measure/drape_measurement.hpp"
#include "measure/metrics.hpp"
#include "measure_test_support.hpp"

using namespace drapelab;
using namespace drapelab::measure_testing;

TEST(Metrics, PixelMseAndIou) {
  Image a = Image::Zero(4, 4), b = Image::Zero(4, 4);
  a.block(0, 0, 2, 4) = 1.0;  // 8 px
  b.block(1, 0, 2, 4) = 1.0;  // 8 px, 4 shared
  EXPECT_DOUBLE_EQ(pixel_mse(a, b), 8.0 / 16.0);
  EXPECT_DOUBLE_EQ(iou(a, b), 4.0 / 12.0);
  EXPECT_DOUBLE_EQ(iou(a, a), 1.0);
  EXPECT_DOUBLE_EQ(pixel_mse(a, a), 0.0);
  Image soft = a * 0.5;
  EXPECT_DOUBLE_EQ(pixel_mse(a, soft), 8 * 0.25 / 16.0);
  expect_input_error([&] { iou(a, Image::Zero(3, 4)); }, {"iou", "shapes differ"});
  expect_input_error([&] { pixel_mse(a, Image::Zero(4, 5)); }, {"pixel_mse", "shapes differ"});
  expect_input_error([] { iou(Image::Zero(3, 3), Image::Zero(3, 3)); }, {"both masks are empty"});
}

TEST(Metrics, DrapeCoefficientOfTheSpecimenAndSupportDisks) {
  // The README's reference areas at 720 px/m: 13192 px and 36644 px.
  EXPECT_NEAR(kPi * 0.09 * 0.09 * 720 * 720, 13192, 1);
  EXPECT_NEAR(kPi * 0.15 * 0.15 * 720 * 720, 36644, 1);
  EXPECT_NEAR(drape_coefficient(disk_mask(0.15), 720.0), 1.0, 0.005);
  EXPECT_NEAR(drape_coefficient(disk_mask(0.09), 720.0), 0.0, 0.005);
  EXPECT_NEAR(drape_coefficient(disk_mask(0.12), 720.0),
              (0.12 * 0.12 - 0.09 * 0.09) / (0.15 * 0.15 - 0.09 * 0.09), 0.005);
  // Scale-free: the same disk drawn at another resolution.
  EXPECT_NEAR(drape_coefficient(disk_mask(0.15, 500.0), 500.0), 1.0, 0.01);
  EXPECT_DOUBLE_EQ(drape_coefficient(kPi * 0.15 * 0.15), 1.0);
  EXPECT_DOUBLE_EQ(drape_coefficient(kPi * 0.09 * 0.09), 0.0);
}

TEST(Metrics, RadiusAngleCurveOfADiskIsItsRadius) {
  const Eigen::VectorXd r = radius_angle_curve(disk_mask(0.12), Calibration{});
  ASSERT_EQ(r.size(), 360);
  EXPECT_LT((r.array() - 0.12).abs().maxCoeff(), 1.0 / 720);  // within a pixel
  EXPECT_NEAR(r.mean(), 0.12, 0.3 / 720);
}

TEST(Metrics, RadiusAngleCurveFollowsTheShapeAndItsOrientation) {
  // One lobe pointing at theta = 90 degrees (image up, towards row 0).
  const Image m = polar_mask(256, 256, 720, 128, 128, [](double t) { return 0.1 + 0.03 * std::max(0.0, std::sin(t)); });
  const Eigen::VectorXd r = radius_angle_curve(m, Calibration{});
  Eigen::Index top;
  r.maxCoeff(&top);
  EXPECT_NEAR(static_cast<double>(top), 90.0, 3.0);
  EXPECT_NEAR(r[90], 0.13, 1.5 / 720);
  EXPECT_NEAR(r[270], 0.10, 1.5 / 720);
  // An off-centre calibration is honoured.
  Calibration c;
  c.cx = 100.25;
  c.cy = 140.5;
  const Image shifted = polar_mask(256, 256, 720, c.cx, c.cy, [](double) { return 0.1; });
  EXPECT_LT((radius_angle_curve(shifted, c).array() - 0.1).abs().maxCoeff(), 1.0 / 720);
}

TEST(Metrics, RadiusAngleCurveTakesTheOuterBoundary) {
  // An annulus at 10-12 cm with a gap at 5-7 cm: the outer boundary is 12 cm.
  const Image m = disk_mask(0.12) - disk_mask(0.07) + disk_mask(0.05);
  EXPECT_LT((radius_angle_curve(m, Calibration{}).array() - 0.12).abs().maxCoeff(), 1.0 / 720);
}

TEST(Metrics, EightSinusoidalFoldsGiveNodeCountEight) {
  for (double phase : {0.0, 0.3, 1.1}) {
    const double amplitude = 0.015;
    const Image m = polar_mask(256, 256, 720, 128, 128,
                               [&](double t) { return 0.12 + amplitude * std::cos(8 * t + phase); });
    const Eigen::VectorXd r = radius_angle_curve(m, Calibration{});
    const NodeAnalysis nodes = analyse_nodes(r);
    EXPECT_EQ(nodes.count, 8) << "phase " << phase;
    EXPECT_EQ(node_count(r), 8);
    // Amplitude of the smoothed curve: a exp(-(8 sigma)^2 / 2) with sigma = 2 degrees, within a pixel.
    const double sigma = 2.0 * kPi / 180;
    EXPECT_NEAR(nodes.amplitude_m, amplitude * std::exp(-0.5 * 64 * sigma * sigma), 1.0 / 720);
    // Nodes are 45 degrees apart.
    for (size_t k = 1; k < nodes.angles_rad.size(); ++k)
      EXPECT_NEAR(nodes.angles_rad[k] - nodes.angles_rad[k - 1], kPi / 4, 3 * kPi / 180);
  }
}

TEST(Metrics, NodeCountOfSeveralFoldNumbersAndOfADisk) {
  for (int n : {5, 6, 7, 9, 10, 12}) {
    Eigen::VectorXd r(360);
    for (int k = 0; k < 360; ++k) r[k] = 0.12 + 0.01 * std::cos(n * 2 * kPi * k / 360);
    EXPECT_EQ(node_count(r), n);
  }
  EXPECT_EQ(node_count(Eigen::VectorXd::Constant(360, 0.15)), 0);
  EXPECT_EQ(node_amplitude(Eigen::VectorXd::Constant(360, 0.15)), 0.0);
  // Pixel-level jitter on a disk is not a node.
  EXPECT_EQ(node_count(radius_angle_curve(disk_mask(0.13), Calibration{})), 0);
}

TEST(Metrics, SmallRipplesBelowTheProminenceFloorAreNotNodes) {
  Eigen::VectorXd r(360);
  // 6 large folds (2 cm) plus 30 ripples of 0.5 mm.
  for (int k = 0; k < 360; ++k) {
    const double t = 2 * kPi * k / 360;
    r[k] = 0.12 + 0.02 * std::cos(6 * t) + 0.0005 * std::cos(30 * t);
  }
  EXPECT_EQ(node_count(r), 6);
  // One fold much smaller than the others (relative floor 10 %).
  for (int k = 0; k < 360; ++k) {
    const double t = 2 * kPi * k / 360;
    r[k] = 0.12 + 0.03 * std::max(0.0, std::cos(4 * t)) + (k > 20 && k < 25 ? 0.001 : 0.0);
  }
  EXPECT_EQ(node_count(r), 4);
}

TEST(Metrics, HarmonicSpectrumIsNormalisedToAmplitudes) {
  Eigen::VectorXd r(360);
  for (int k = 0; k < 360; ++k) {
    const double t = 2 * kPi * k / 360;
    r[k] = 0.12 + 0.02 * std::cos(8 * t + 0.7) + 0.005 * std::sin(3 * t);
  }
  const Eigen::VectorXd a = harmonic_spectrum(r);
  ASSERT_EQ(a.size(), 20);
  EXPECT_NEAR(a[0], 0.12, 1e-12);
  EXPECT_NEAR(a[8], 0.02, 1e-12);
  EXPECT_NEAR(a[3], 0.005, 1e-12);
  EXPECT_NEAR(a[5], 0.0, 1e-12);
  EXPECT_EQ(harmonic_spectrum(r, 5).size(), 5);
}

TEST(Metrics, RThetaRmseIsRotationFree) {
  Eigen::VectorXd a(360), b(360);
  for (int k = 0; k < 360; ++k) {
    a[k] = 0.12 + 0.02 * std::cos(7 * 2 * kPi * k / 360) + 0.004 * std::cos(2 * kPi * k / 360);
    b[(k + 37) % 360] = a[k];  // b is a rotated by 37 degrees
  }
  const RThetaAlignment al = r_theta_rmse(a, b);
  EXPECT_NEAR(al.rmse_m, 0.0, 1e-15);
  EXPECT_EQ(al.shift, 37);
  EXPECT_NEAR(al.rotation_rad, 37 * kPi / 180, 1e-12);
  const Eigen::VectorXd c = a.array() + 0.003;
  EXPECT_NEAR(r_theta_rmse(a, c).rmse_m, 0.003, 1e-12);
  expect_input_error([&] { r_theta_rmse(a, Eigen::VectorXd::Zero(180)); }, {"differ in length"});
}

TEST(Metrics, PointTriangleDistanceMatchesDenseSampling) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-1, 1);
  for (int trial = 0; trial < 50; ++trial) {
    const Eigen::Vector3d a(u(rng), u(rng), u(rng)), b(u(rng), u(rng), u(rng)), c(u(rng), u(rng), u(rng));
    const Eigen::Vector3d p(2 * u(rng), 2 * u(rng), 2 * u(rng));
    double brute = 1e300;
    constexpr int n = 300;
    for (int i = 0; i <= n; ++i)
      for (int j = 0; i + j <= n; ++j)
        brute = std::min(brute, (p - (a + (b - a) * i / double(n) + (c - a) * j / double(n))).norm());
    const double d = point_triangle_distance(p, a, b, c);
    EXPECT_LE(d, brute + 1e-12);
    EXPECT_NEAR(d, brute, 2e-2 * (b - a).norm() + 2e-2 * (c - a).norm());
  }
  // Degenerate (collinear) triangle: distance to the segment.
  EXPECT_NEAR(point_triangle_distance({0, 1, 0}, {-1, 0, 0}, {0, 0, 0}, {1, 0, 0}), 1.0, 1e-12);
}

TEST(Metrics, HausdorffOfAnOffsetSpecimenIsTheOffset) {
  const TriangleMesh disk = make_cusick_specimen(400);
  MatrixX3d lifted = disk.positions;
  lifted.col(2).array() += 0.01;
  EXPECT_NEAR(hausdorff_distance(disk.positions, disk.faces, lifted, disk.faces), 0.01, 1e-12);
  EXPECT_NEAR(hausdorff_distance(disk.positions, disk.faces, lifted, disk.faces, HausdorffMode::Vertices), 0.01,
              1e-12);
  EXPECT_DOUBLE_EQ(hausdorff_distance(disk.positions, disk.faces, disk.positions, disk.faces), 0.0);
  // Symmetric, and surface <= vertices (the surface contains the vertices).
  MatrixX3d moved = disk.positions;
  moved.col(0).array() *= 1.1;
  const double ab = hausdorff_distance(disk.positions, disk.faces, moved, disk.faces);
  EXPECT_DOUBLE_EQ(ab, hausdorff_distance(moved, disk.faces, disk.positions, disk.faces));
  EXPECT_LE(ab, hausdorff_distance(disk.positions, disk.faces, moved, disk.faces, HausdorffMode::Vertices) + 1e-15);
  EXPECT_NEAR(ab, 0.015, 1e-9);  // the rim point (0.15, 0) moves to (0.165, 0): 1.5 cm beyond the other mesh
}

TEST(Metrics, HausdorffGridAgreesWithBruteForce) {
  std::mt19937 rng(11);
  std::normal_distribution<double> n(0, 0.003);
  const TriangleMesh a = make_cusick_specimen(300);
  MatrixX3d pb = a.positions;
  for (Eigen::Index i = 0; i < pb.rows(); ++i) pb.row(i) += Eigen::RowVector3d(n(rng), n(rng), 5 * n(rng));
  pb.row(17) += Eigen::RowVector3d(0.0, 0.0, 0.05);  // one outlier
  auto brute = [](const MatrixX3d& from, const MatrixX3d& pos, const MatrixX3i& faces) {
    double h = 0;
    for (Eigen::Index i = 0; i < from.rows(); ++i) {
      double best = 1e300;
      for (Eigen::Index f = 0; f < faces.rows(); ++f)
        best = std::min(best, point_triangle_distance(from.row(i).transpose(), pos.row(faces(f, 0)).transpose(),
                                                      pos.row(faces(f, 1)).transpose(),
                                                      pos.row(faces(f, 2)).transpose()));
      h = std::max(h, best);
    }
    return h;
  };
  for (const Eigen::RowVector3d& shift : {Eigen::RowVector3d(0, 0, 0), Eigen::RowVector3d(0.4, -0.2, 0.7)}) {
    // Far apart and scaled: every query point lies outside the other mesh's grid.
    const MatrixX3d pc = (pb * (shift.norm() > 0 ? 1.3 : 1.0)).rowwise() + shift;
    const double expected = std::max(brute(a.positions, pc, a.faces), brute(pc, a.positions, a.faces));
    EXPECT_NEAR(hausdorff_distance(a.positions, a.faces, pc, a.faces), expected, 1e-14);
  }
}

TEST(Metrics, HausdorffRejectsBadMeshes) {
  const TriangleMesh a = make_cusick_specimen(50);
  MatrixX3i bad = a.faces;
  bad(0, 0) = 10000;
  expect_input_error([&] { hausdorff_distance(a.positions, a.faces, a.positions, bad); }, {"face index"});
  expect_input_error([&] { hausdorff_distance(MatrixX3d(0, 3), a.faces, a.positions, a.faces); }, {"no vertices"});
}

TEST(Metrics, MeasureDrapeCollectsEverything) {
  const Image m = polar_mask(256, 256, 720, 128, 128, [](double t) { return 0.12 + 0.015 * std::cos(8 * t); });
  const DrapeMeasurement d = measure_drape(m, Calibration{});
  EXPECT_EQ(d.nodes.count, 8);
  EXPECT_EQ(d.r_theta_m.size(), 360);
  EXPECT_EQ(d.harmonics_m.size(), 20);
  EXPECT_NEAR(d.harmonics_m[8], 0.015, 1.0 / 720);
  EXPECT_EQ(d.area_px, static_cast<long>(m.sum()));
  EXPECT_DOUBLE_EQ(d.px_per_m, 720.0);
  EXPECT_DOUBLE_EQ(d.centre_px.x(), 128.0);
}
