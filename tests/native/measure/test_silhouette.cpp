// Silhouette extraction: thresholds, polarity, specks and holes, the central region, and bad images.
#include <gtest/gtest.h>

#include <random>

#include "measure/image_io.hpp"
#include "measure/metrics.hpp"
#include "measure/silhouette.hpp"
#include "measure_test_support.hpp"

using namespace drapelab;
using namespace drapelab::measure_testing;

namespace {

// A drape-like shape: 8 folds on a 12 cm mean radius.
Image folded_mask(double px_per_m = 720.0, double cx = 128.0, double cy = 128.0) {
  return polar_mask(256, 256, px_per_m, cx, cy, [](double t) { return 0.12 + 0.015 * std::cos(8 * t); });
}

// A raw-photo-like luminance image: cloth at `cloth` and table at `table` tones, an illumination gradient,
// Gaussian noise and a soft edge.
Image photo(const Image& mask, double cloth, double table, double noise, unsigned seed = 1) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> n(0.0, noise);
  Image lum(mask.rows(), mask.cols());
  for (int r = 0; r < mask.rows(); ++r)
    for (int c = 0; c < mask.cols(); ++c) {
      const double shade = 1.0 - 0.1 * c / static_cast<double>(mask.cols());
      lum(r, c) = std::clamp((mask(r, c) > 0.5 ? cloth : table) * shade + n(rng), 0.0, 1.0);
    }
  return lum;
}

}  // namespace

TEST(Silhouette, CleanDarkOnLightSilhouetteIsRecoveredExactly) {
  const Image truth = folded_mask();
  const Silhouette s = extract_silhouette(1.0 - truth);
  EXPECT_TRUE(s.dark_on_light);
  EXPECT_NEAR(s.threshold, 0.5, 1e-6);
  EXPECT_EQ((s.mask != truth).count(), 0);
  EXPECT_DOUBLE_EQ(s.calibration.px_per_m, 720.0);
  EXPECT_DOUBLE_EQ(s.calibration.cx, 128.0);
  EXPECT_DOUBLE_EQ(s.calibration.cy, 128.0);
}

TEST(Silhouette, LightOnDarkIsDetected) {
  const Image truth = folded_mask();
  const Silhouette s = extract_silhouette(truth);
  EXPECT_FALSE(s.dark_on_light);
  EXPECT_EQ((s.mask != truth).count(), 0);
  SilhouetteOptions forced;
  forced.polarity = Polarity::DarkOnLight;  // wrong polarity: the centre is then background
  expect_input_error([&] { extract_silhouette(truth, {}, forced, "forced.png"); }, {"forced.png"});
}

TEST(Silhouette, NoisyRawPhotoGivesTheShapeBothWays) {
  const Image truth = folded_mask();
  for (bool dark : {true, false}) {
    const Image lum = dark ? photo(truth, 0.25, 0.85, 0.05) : photo(truth, 0.8, 0.15, 0.05);
    const Silhouette s = extract_silhouette(lum);
    EXPECT_EQ(s.dark_on_light, dark);
    EXPECT_GT(iou(s.mask, truth), 0.99) << (dark ? "dark on light" : "light on dark");
    EXPECT_GT(s.threshold, 0.2);
    EXPECT_LT(s.threshold, 0.8);
  }
}

TEST(Silhouette, SpecksAreRemovedAndSmallHolesFilled) {
  const Image truth = folded_mask();
  Image m = truth;
  m.block(5, 5, 3, 3) = 1.0;      // speck in a corner
  m.block(240, 200, 2, 6) = 1.0;  // another
  m.block(120, 150, 3, 3) = 0.0;  // hole inside the cloth
  const Silhouette s = extract_silhouette(1.0 - m);
  EXPECT_EQ(s.specks_removed_px, 9 + 12);
  EXPECT_EQ(s.holes_filled_px, 9);
  EXPECT_EQ((s.mask != truth).count(), 0);
  SilhouetteOptions keep_all;
  keep_all.keep_central_region = false;
  keep_all.max_hole_fraction = 0.0;
  EXPECT_EQ((extract_silhouette(1.0 - m, {}, keep_all).mask != m).count(), 0);
}

TEST(Silhouette, LargeHolesAreKept) {
  // A hole of 3.5 cm radius is more than 5 % of the region: not a defect to fill.
  const Image m = disk_mask(0.12) - polar_mask(256, 256, 720, 170, 128, [](double) { return 0.035; });
  const Silhouette s = extract_silhouette(1.0 - m);
  EXPECT_EQ(s.holes_filled_px, 0);
  EXPECT_EQ((s.mask != m).count(), 0);
}

TEST(Silhouette, RegionAwayFromTheCentreIsFoundWhenTheCentrePixelIsBackground) {
  Image m = folded_mask();
  m.block(126, 126, 4, 4) = 0.0;  // a dark hole exactly at the centre (filled afterwards)
  const Silhouette s = extract_silhouette(1.0 - m);
  EXPECT_EQ((s.mask != folded_mask()).count(), 0);
}

TEST(Silhouette, FixedThresholdIsUsed) {
  Image lum = 1.0 - folded_mask();
  lum = lum * 0.6 + 0.2;  // cloth s = 0.8, table s = 0.2
  SilhouetteOptions o;
  o.threshold = 0.7;
  const Silhouette s = extract_silhouette(lum, {}, o);
  EXPECT_DOUBLE_EQ(s.threshold, 0.7);
  EXPECT_EQ((s.mask != folded_mask()).count(), 0);
  o.threshold = 1.5;
  expect_input_error([&] { extract_silhouette(lum, {}, o, "x.png"); }, {"x.png", "threshold"});
}

TEST(Silhouette, AllBlackAndAllWhiteImagesAreClearErrors) {
  expect_input_error([] { extract_silhouette(Image::Zero(64, 64), {}, {}, "black.png"); },
                     {"black.png", "no contrast", "all dark"});
  expect_input_error([] { extract_silhouette(Image::Ones(64, 64), {}, {}, "white.png"); },
                     {"white.png", "no contrast", "all light"});
}

TEST(Silhouette, ImageWithoutACentralRegionIsAClearError) {
  // A blob in a corner only.
  const Image m = polar_mask(256, 256, 720, 30, 30, [](double) { return 0.02; });
  expect_input_error([&] { extract_silhouette(1.0 - m, {}, {}, "corner.png"); },
                     {"corner.png", "no specimen region at the centre"});
}

TEST(Silhouette, CentreOutsideTheImageIsAWrongCalibration) {
  Calibration c;
  c.cx = 500;
  c.cy = 10;
  expect_input_error([&] { extract_silhouette(1.0 - folded_mask(), c, {}, "img.png"); },
                     {"img.png", "wrong calibration", "centre"});
  c = Calibration{};
  c.px_per_m = -3;
  expect_input_error([&] { extract_silhouette(1.0 - folded_mask(), c, {}, "img.png"); },
                     {"img.png", "px_per_m"});
}

TEST(Silhouette, AutomaticThresholdOfABimodalImage) {
  Image v = Image::Constant(10, 10, 0.2);
  v.block(0, 0, 5, 10) = 0.6;
  EXPECT_NEAR(automatic_threshold(v), 0.4, 1e-9);
}

TEST(Silhouette, FileFormatsAndBitDepthsGiveTheSameSilhouette) {
  TempDir dir;
  const Image lum = photo(folded_mask(), 0.25, 0.85, 0.02);
  const Image reference = extract_silhouette(lum).mask;
  for (const auto& [name, type] : {std::pair{"a.png", PixelType::UInt8}, std::pair{"b.tif", PixelType::UInt16},
                                   std::pair{"c.exr", PixelType::Float}}) {
    write_image(dir.file(name), lum, type, 3);
    const Silhouette s = load_silhouette(dir.file(name));
    EXPECT_EQ(s.source, dir.file(name));
    EXPECT_GT(iou(s.mask, reference), 0.998) << name;
  }
}

TEST(Silhouette, BadFilesNameTheFile) {
  expect_input_error([] { load_silhouette("/no/such/drape.png"); }, {"/no/such/drape.png", "not found"});
  TempDir dir;
  write_image(dir.file("black.png"), Image::Zero(32, 32));
  expect_input_error([&] { load_silhouette(dir.file("black.png")); }, {"black.png", "no contrast"});
}

TEST(Silhouette, AnyFiniteScaleIsHandledWithoutOverflow) {
  // A border half dark, half light sends the polarity to the support disk, whose pixel bounds a huge scale
  // (px/m) puts beyond int: they are clamped to the image (the sanitizer build checks the conversions).
  Image lum = Image::Ones(64, 64);
  lum.leftCols(32) = 0.0;
  for (const double px_per_m : {720.0, 1e12, 1e300}) {
    Calibration cal;
    cal.px_per_m = px_per_m;
    const Silhouette s = extract_silhouette(lum, cal, {}, "half.png");
    EXPECT_EQ(s.area_px(), 32 * 64) << px_per_m;
  }
}
