// Soft rasterizer: backward against central finite differences (random directions, per vertex, at
// silhouette edges, both profiles, both cameras), agreement with an all-pairs reference, convergence to
// the hard silhouette as sigma -> 0, saturation without NaN, bad input.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <random>

#include "geometry/cusick.hpp"
#include "geometry/obj.hpp"
#include "render/rasterizer.hpp"
#include "render/soft_rasterizer.hpp"
#include "util/error.hpp"
#include "../source_dir.hpp"

using namespace drapelab;

namespace {

// A Cusick specimen pushed into a drape-like shape: the overhang falls and its radius varies with angle
// (6 nodes). The radial map is monotonic, so the projection has no folds.
TriangleMesh synthetic_drape(int target_vertices, double wobble = 0.0, unsigned seed = 1) {
  TriangleMesh mesh = make_cusick_specimen(target_vertices);
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> noise(-1.0, 1.0);
  const double support = 0.09;
  for (Index v = 0; v < mesh.num_vertices(); ++v) {
    const double x = mesh.positions(v, 0), y = mesh.positions(v, 1);
    const double r = std::hypot(x, y), theta = std::atan2(y, x);
    double scale = 1.0, z = 0.0;
    if (r > support) {
      const double overhang = r - support;
      const double projected = support + overhang * (0.65 + 0.25 * std::cos(6.0 * theta));
      scale = projected / r;
      z = -0.8 * overhang;
    }
    mesh.positions(v, 0) = scale * x + wobble * noise(rng);
    mesh.positions(v, 1) = scale * y + wobble * noise(rng);
    mesh.positions(v, 2) = z + wobble * noise(rng);
  }
  return mesh;
}

Image random_weights(int rows, int cols, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  Image w(rows, cols);
  for (Eigen::Index i = 0; i < w.size(); ++i) w.data()[i] = u(rng);
  return w;
}

// L(positions) = sum_p w(p) I(p).
double weighted_loss(SoftRasterizer& rasterizer, const MatrixX3d& positions, const MatrixX3i& faces,
                     const Image& w) {
  return (rasterizer.forward(positions, faces) * w).sum();
}

struct FdCase {
  const char* name;
  std::shared_ptr<Camera> camera;
  SoftProfile profile;
  double sigma;
};

std::vector<FdCase> fd_cases() {
  // 64 x 64 images; the 0.3 m specimen spans ~45 px so soft edges cover many pixels.
  auto ortho = std::make_shared<OrthographicCamera>(150.0, 32.0, 32.0, 64, 64);
  auto persp = std::make_shared<PerspectiveCamera>(1.2, 0.5, 64, 64);
  return {{"ortho-gaussian", ortho, SoftProfile::Gaussian, 1.0},
          {"ortho-logistic", ortho, SoftProfile::Logistic, 1.0},
          {"perspective-gaussian", persp, SoftProfile::Gaussian, 0.7},
          {"perspective-logistic", persp, SoftProfile::Logistic, 0.7}};
}

// Brute-force reference: every face at every pixel, no cutoff, barycentric inside test, written independently.
Image reference_render(const Camera& camera, const MatrixX3d& positions, const MatrixX3i& faces,
                       const SoftRasterOptions& options) {
  const MatrixX2d q = project_vertices(camera, positions);
  Image transmittance = Image::Ones(camera.height(), camera.width());
  auto segment_d2 = [](Eigen::Vector2d p, Eigen::Vector2d a, Eigen::Vector2d b) {
    const Eigen::Vector2d e = b - a;
    const double t = e.squaredNorm() > 0 ? std::clamp((p - a).dot(e) / e.squaredNorm(), 0.0, 1.0) : 0.0;
    return (p - a - t * e).squaredNorm();
  };
  for (Eigen::Index f = 0; f < faces.rows(); ++f) {
    const Eigen::Vector2d a = q.row(faces(f, 0)), b = q.row(faces(f, 1)), c = q.row(faces(f, 2));
    const double area2 = (b - a).x() * (c - a).y() - (b - a).y() * (c - a).x();
    for (int r = 0; r < camera.height(); ++r)
      for (int col = 0; col < camera.width(); ++col) {
        const Eigen::Vector2d p(col + 0.5, r + 0.5);
        bool inside = false;
        if (area2 != 0.0) {
          // Barycentric coordinates, all >= 0 on the closed triangle.
          const double l1 = ((p - a).x() * (c - a).y() - (p - a).y() * (c - a).x()) / area2;
          const double l2 = ((b - a).x() * (p - a).y() - (b - a).y() * (p - a).x()) / area2;
          inside = l1 >= 0 && l2 >= 0 && 1 - l1 - l2 >= 0;
        }
        const double d2 = std::min({segment_d2(p, a, b), segment_d2(p, b, c), segment_d2(p, c, a)});
        const double s2 = options.sigma * options.sigma;
        double coverage;
        if (options.profile == SoftProfile::Gaussian)
          coverage = inside ? 1.0 : std::exp(-d2 / s2);
        else
          coverage = 1.0 / (1.0 + std::exp(-(inside ? d2 : -d2) / s2));
        transmittance(r, col) *= 1.0 - coverage;
      }
  }
  return 1.0 - transmittance;
}

}  // namespace

TEST(SoftRasterTest, BackwardMatchesFiniteDifferencesInRandomDirections) {
  const TriangleMesh mesh = synthetic_drape(150, 0.002);
  const Image w = random_weights(64, 64, 7);
  std::mt19937 rng(3);
  std::normal_distribution<double> normal;
  for (const FdCase& fc : fd_cases()) {
    SoftRasterOptions options;
    options.sigma = fc.sigma;
    options.profile = fc.profile;
    options.epsilon = 1e-15;  // keeps cutoff jumps (<= epsilon) far below the FD resolution
    SoftRasterizer rasterizer(*fc.camera, options);
    rasterizer.forward(mesh.positions, mesh.faces);
    const MatrixX3d grad = rasterizer.backward(w);
    ASSERT_TRUE(grad.allFinite()) << fc.name;
    for (int trial = 0; trial < 4; ++trial) {
      MatrixX3d direction(mesh.num_vertices(), 3);
      for (Eigen::Index i = 0; i < direction.size(); ++i) direction.data()[i] = normal(rng);
      const double h = 1e-7;  // m
      const double fd = (weighted_loss(rasterizer, mesh.positions + h * direction, mesh.faces, w) -
                         weighted_loss(rasterizer, mesh.positions - h * direction, mesh.faces, w)) /
                        (2 * h);
      const double analytic = (grad.array() * direction.array()).sum();
      EXPECT_NEAR(analytic, fd, 1e-5 * grad.norm() * direction.norm()) << fc.name << " trial " << trial;
      EXPECT_NEAR(analytic, fd, 1e-4 * std::abs(fd) + 1e-3) << fc.name << " trial " << trial;
    }
  }
}

TEST(SoftRasterTest, BackwardMatchesFiniteDifferencesPerVertexAtSilhouetteEdge) {
  // Rim vertices (rest radius 0.15 m) lie on the silhouette boundary; the support region deep inside.
  const TriangleMesh mesh = synthetic_drape(150, 0.002, 5);
  const TriangleMesh rest = make_cusick_specimen(150);
  const Image w = random_weights(64, 64, 11);
  std::vector<Index> rim, centre;
  for (Index v = 0; v < rest.num_vertices(); ++v) {
    const double r = rest.positions.row(v).head<2>().norm();
    if (r > 0.149) rim.push_back(v);
    if (r < 0.03) centre.push_back(v);
  }
  ASSERT_GE(rim.size(), 8u);
  ASSERT_GE(centre.size(), 1u);
  for (const FdCase& fc : fd_cases()) {
    SoftRasterOptions options;
    options.sigma = fc.sigma;
    options.profile = fc.profile;
    options.epsilon = 1e-15;
    SoftRasterizer rasterizer(*fc.camera, options);
    rasterizer.forward(mesh.positions, mesh.faces);
    const MatrixX3d grad = rasterizer.backward(w);
    double rim_gradient = 0.0;
    for (size_t i = 0; i < rim.size(); i += 2) {
      const Index v = rim[i];
      for (int k = 0; k < 3; ++k) {
        MatrixX3d plus = mesh.positions, minus = mesh.positions;
        const double h = 1e-7;
        plus(v, k) += h;
        minus(v, k) -= h;
        const double fd = (weighted_loss(rasterizer, plus, mesh.faces, w) -
                           weighted_loss(rasterizer, minus, mesh.faces, w)) / (2 * h);
        EXPECT_NEAR(grad(v, k), fd, 1e-4 * std::abs(fd) + 1e-4 * grad.norm() / std::sqrt(grad.rows()))
            << fc.name << " vertex " << v << " component " << k;
        rim_gradient += std::abs(grad(v, k));
      }
    }
    EXPECT_GT(rim_gradient, 0.0) << fc.name;
    if (fc.profile == SoftProfile::Gaussian) {
      // Far inside the silhouette every pixel is covered: no gradient at all.
      for (Index v : centre) EXPECT_EQ(grad.row(v).norm(), 0.0) << fc.name << " vertex " << v;
    }
  }
}

TEST(SoftRasterTest, GradientWhenPixelCentresLieOnEdges) {
  // Edges through rows of pixel centres (y = 10.5) and vertices exactly on pixel centres.
  const OrthographicCamera camera(1.0, 0.0, 0.0, 24, 24);  // col = x, row = -y
  MatrixX3d positions(4, 3);
  // Not symmetric about a pixel column: the logistic profile's inside distance has kinks on the triangle's
  // medial axis (documented), which a symmetric triangle would put on pixel centres.
  positions << 4.5, -10.5, 0, 18.5, -10.5, 0, 12.2, -19.5, 0, 10.9, -3.5, 0;
  MatrixX3i faces(2, 3);
  faces << 0, 1, 2, 0, 3, 1;
  const Image w = random_weights(24, 24, 2);
  for (SoftProfile profile : {SoftProfile::Gaussian, SoftProfile::Logistic}) {
    SoftRasterOptions options;
    options.sigma = 0.8;
    options.profile = profile;
    options.epsilon = 1e-15;
    SoftRasterizer rasterizer(camera, options);
    rasterizer.forward(positions, faces);
    const MatrixX3d grad = rasterizer.backward(w);
    for (Index v = 0; v < 4; ++v)
      for (int k = 0; k < 2; ++k) {
        MatrixX3d plus = positions, minus = positions;
        const double h = 1e-6;  // px
        plus(v, k) += h;
        minus(v, k) -= h;
        const double fd = (weighted_loss(rasterizer, plus, faces, w) - weighted_loss(rasterizer, minus, faces, w)) /
                          (2 * h);
        EXPECT_NEAR(grad(v, k), fd, 1e-5 * std::abs(fd) + 1e-6) << to_string(profile) << " v" << v << " k" << k;
      }
    EXPECT_EQ(grad.col(2).norm(), 0.0);  // orthographic: depth does not move the image
  }
}

TEST(SoftRasterTest, ForwardMatchesAllPairsReferenceWithinCutoffError) {
  const TriangleMesh mesh = synthetic_drape(150, 0.002);
  for (const FdCase& fc : fd_cases()) {
    SoftRasterOptions options;
    options.sigma = fc.sigma;
    options.profile = fc.profile;
    const Image reference = reference_render(*fc.camera, mesh.positions, mesh.faces, options);
    SoftRasterizer rasterizer(*fc.camera, options);  // default epsilon 1e-8: "exact to ~1e-6"
    const Image image = rasterizer.forward(mesh.positions, mesh.faces);
    EXPECT_LT((image - reference).abs().maxCoeff(), 1e-6) << fc.name;
    EXPECT_GE(image.minCoeff(), 0.0);
    EXPECT_LE(image.maxCoeff(), 1.0);
    options.epsilon = 1e-15;
    SoftRasterizer tight(*fc.camera, options);
    EXPECT_LT((tight.forward(mesh.positions, mesh.faces) - reference).abs().maxCoeff(), 1e-12) << fc.name;
  }
}

TEST(SoftRasterTest, BackwardMatchesFiniteDifferencesOnRealFoldedDrape) {
  // A real 5226-face reconstruction at 256 x 256: folds make faces overlap in the projection.
  const std::string path = drapelab::testing::source_dir() + "/assets/cusick/fabric_02/meshes/sample_02_capture_1.obj";
  if (!std::filesystem::exists(path)) GTEST_SKIP() << "bundled mesh missing: " << path;
  const TriangleMesh mesh = read_obj(path);
  const OrthographicCamera camera;
  const Image target = hard_silhouette(camera, mesh.positions, mesh.faces);
  std::mt19937 rng(9);
  std::normal_distribution<double> normal;
  for (SoftProfile profile : {SoftProfile::Gaussian, SoftProfile::Logistic}) {
    SoftRasterOptions options;
    options.profile = profile;
    options.sigma = profile == SoftProfile::Gaussian ? 1.0 : 0.5;
    options.epsilon = 1e-15;
    SoftRasterizer rasterizer(camera, options);
    // Pixel MSE against a shifted target, the loss of a fit.
    Image shifted = Image::Zero(256, 256);
    shifted.block(0, 2, 256, 254) = target.block(0, 0, 256, 254);
    auto loss = [&](const MatrixX3d& positions) {
      return (rasterizer.forward(positions, mesh.faces) - shifted).square().mean();
    };
    const Image image = rasterizer.forward(mesh.positions, mesh.faces);
    const MatrixX3d grad = rasterizer.backward(2.0 * (image - shifted) / static_cast<double>(image.size()));
    for (int trial = 0; trial < 3; ++trial) {
      MatrixX3d direction(mesh.num_vertices(), 3);
      for (Eigen::Index i = 0; i < direction.size(); ++i) direction.data()[i] = normal(rng);
      const double h = 1e-7;
      const double fd = (loss(mesh.positions + h * direction) - loss(mesh.positions - h * direction)) / (2 * h);
      const double analytic = (grad.array() * direction.array()).sum();
      // The logistic profile's inside distance has kinks on triangle medial axes (a few pixels of 65536
      // may straddle one at this step), hence its looser tolerance.
      const double tolerance = profile == SoftProfile::Gaussian ? 1e-6 : 1e-4;
      EXPECT_NEAR(analytic, fd, tolerance * grad.norm() * direction.norm()) << to_string(profile) << " trial " << trial;
    }
  }
}

TEST(SoftRasterTest, DegenerateFacesActAsSegments) {
  // A zero-area (collinear) projected face has no inside; its soft coverage is that of a segment.
  const OrthographicCamera camera(1.0, 0.0, 0.0, 24, 24);
  MatrixX3d positions(6, 3);
  positions << 3.2, -4.1, 0, 9.7, -11.3, 0, 16.2, -18.5, 0,  // collinear
      12.3, -3.4, 0, 20.1, -4.6, 0, 15.2, -9.9, 0;
  MatrixX3i faces(2, 3);
  faces << 0, 1, 2, 3, 4, 5;
  const Image w = random_weights(24, 24, 5);
  for (SoftProfile profile : {SoftProfile::Gaussian, SoftProfile::Logistic}) {
    SoftRasterOptions options;
    options.profile = profile;
    options.sigma = 0.9;
    options.epsilon = 1e-15;
    SoftRasterizer rasterizer(camera, options);
    const Image image = rasterizer.forward(positions, faces);
    EXPECT_LT((image - reference_render(camera, positions, faces, options)).abs().maxCoeff(), 1e-12);
    EXPECT_GT(image(7, 6), 0.3);  // next to the segment
    const MatrixX3d grad = rasterizer.backward(w);
    ASSERT_TRUE(grad.allFinite());
    // A collinear face is a non-differentiable configuration across its line (an inside appears on either
    // side); along the line it stays a segment, and that derivative is well defined.
    const Eigen::Vector3d along = (positions.row(2) - positions.row(0)).normalized().transpose();
    for (Index v = 0; v < 3; ++v) {
      MatrixX3d plus = positions, minus = positions;
      const double h = 1e-6;
      plus.row(v) += h * along.transpose();
      minus.row(v) -= h * along.transpose();
      const double fd = (weighted_loss(rasterizer, plus, faces, w) - weighted_loss(rasterizer, minus, faces, w)) /
                        (2 * h);
      EXPECT_NEAR(grad.row(v).dot(along.transpose()), fd, 1e-5 * std::abs(fd) + 1e-6) << to_string(profile) << " v" << v;
    }
  }
}

TEST(SoftRasterTest, SoftConvergesToHardAsSigmaShrinks) {
  const TriangleMesh mesh = synthetic_drape(2699);
  const OrthographicCamera camera;
  const Image hard = hard_silhouette(camera, mesh.positions, mesh.faces);
  // The logistic profile dips to 0.75 on interior edges, so its error grows again for sigma around
  // 0.5-1 px on this 2699-vertex mesh; it decreases monotonically below that.
  for (SoftProfile profile : {SoftProfile::Gaussian, SoftProfile::Logistic}) {
    const std::vector<double> sigmas = profile == SoftProfile::Gaussian
                                           ? std::vector<double>{2.0, 1.0, 0.5, 0.25, 0.1, 0.03, 0.01}
                                           : std::vector<double>{0.5, 0.25, 0.1, 0.03, 0.01};
    double previous_mse = INFINITY;
    double mse = 0.0, iou = 0.0;
    Image soft;
    for (double sigma : sigmas) {
      SoftRasterOptions options;
      options.sigma = sigma;
      options.profile = profile;
      SoftRasterizer rasterizer(camera, options);
      soft = rasterizer.forward(mesh.positions, mesh.faces);
      mse = (soft - hard).square().mean();
      iou = silhouette_iou(soft, hard);
      EXPECT_LT(mse, previous_mse) << to_string(profile) << " sigma " << sigma;
      previous_mse = mse;
    }
    EXPECT_LT(mse, profile == SoftProfile::Gaussian ? 2e-4 : 1e-3) << to_string(profile);
    EXPECT_GT(iou, 0.999) << to_string(profile);
    // What remains is a sliver of pixels within ~sigma of an edge (the silhouette's for the Gaussian profile,
    // where also a few centres lie on an edge up to rounding; every interior edge for the logistic one).
    EXPECT_LT(((soft - hard).abs() > 1e-3).count(), hard.size() / (profile == SoftProfile::Gaussian ? 1000 : 20))
        << to_string(profile);
  }
}

TEST(SoftRasterTest, GaussianProfileIsExactlyOneOnCoveredPixels) {
  const TriangleMesh mesh = synthetic_drape(1205);
  const OrthographicCamera camera;
  const Image hard = hard_silhouette(camera, mesh.positions, mesh.faces);
  SoftRasterizer rasterizer(camera, {});
  const Image soft = rasterizer.forward(mesh.positions, mesh.faces);
  EXPECT_TRUE((hard == 0.0 || soft == 1.0).all());
  EXPECT_GT((soft > 0.0 && soft < 1.0).count(), 0);
  EXPECT_NEAR(rasterizer.cutoff_radius_px(), std::sqrt(std::log(1e8)), 1e-12);
}

TEST(SoftRasterTest, SaturatedPixelsGiveFiniteGradients) {
  // 50 copies of a large triangle at a tiny sigma: D_f -> 1 everywhere inside, T underflows.
  const OrthographicCamera camera(1.0, 0.0, 0.0, 32, 32);
  const int copies = 50;
  MatrixX3d positions(3 * copies, 3);
  MatrixX3i faces(copies, 3);
  for (int i = 0; i < copies; ++i) {
    positions.row(3 * i) << 2.0 + 1e-3 * i, -2.0, 0;
    positions.row(3 * i + 1) << 30.0, -3.0, 0;
    positions.row(3 * i + 2) << 15.0, -29.0, 0;
    faces.row(i) << 3 * i, 3 * i + 1, 3 * i + 2;
  }
  const Image ones = Image::Ones(32, 32);
  for (SoftProfile profile : {SoftProfile::Gaussian, SoftProfile::Logistic})
    for (double sigma : {0.01, 1.0, 10.0}) {
      SoftRasterOptions options;
      options.sigma = sigma;
      options.profile = profile;
      SoftRasterizer rasterizer(camera, options);
      const Image image = rasterizer.forward(positions, faces);
      EXPECT_TRUE(image.allFinite());
      EXPECT_EQ(image(15, 15), 1.0);
      const MatrixX3d grad = rasterizer.backward(ones);
      EXPECT_TRUE(grad.allFinite()) << to_string(profile) << " sigma " << sigma;
    }
}

TEST(SoftRasterTest, BadInputThrowsInputError) {
  const OrthographicCamera camera(100.0, 16.0, 16.0, 32, 32);
  MatrixX3d positions(3, 3);
  positions << 0, 0, 0, 0.1, 0, 0, 0, 0.1, 0;
  MatrixX3i faces(1, 3);
  faces << 0, 1, 2;
  SoftRasterizer rasterizer(camera, {});
  EXPECT_THROW(rasterizer.backward(Image::Zero(32, 32)), InputError);  // no forward yet

  MatrixX3i bad_faces(1, 3);
  bad_faces << 0, -1, 2;
  try {
    rasterizer.forward(positions, bad_faces);
    FAIL();
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("face 0 refers to vertex -1"), std::string::npos) << e.what();
  }
  MatrixX3d nan_positions = positions;
  nan_positions(2, 0) = NAN;
  try {
    rasterizer.forward(nan_positions, faces);
    FAIL();
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("vertex 2 is not finite"), std::string::npos) << e.what();
  }

  rasterizer.forward(positions, faces);
  try {
    rasterizer.backward(Image::Zero(32, 31));
    FAIL();
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("32x31"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("32x32"), std::string::npos) << e.what();
  }
  Image nan_grad = Image::Zero(32, 32);
  nan_grad(3, 4) = NAN;
  EXPECT_THROW(rasterizer.backward(nan_grad), InputError);

  SoftRasterOptions options;
  options.sigma = 0.0;
  EXPECT_THROW(SoftRasterizer(camera, options), InputError);
  options.sigma = 1.0;
  options.epsilon = 0.7;
  EXPECT_THROW(SoftRasterizer(camera, options), InputError);
  EXPECT_THROW(soft_profile_from_string("box"), InputError);
  EXPECT_EQ(soft_profile_from_string("logistic"), SoftProfile::Logistic);
}

TEST(SoftRasterTest, TimingHelperReportsPositiveTimes) {
  const TriangleMesh mesh = synthetic_drape(297);
  const RenderTiming timing = time_soft_render(mesh, 2);
  EXPECT_GT(timing.forward_ms, 0.0);
  EXPECT_GT(timing.backward_ms, 0.0);
  EXPECT_EQ(timing.faces, mesh.num_faces());
  EXPECT_EQ(timing.width, 256);
}
