// Image import: formats, bit depths, channel layouts, and clear errors for bad files.
#include <gtest/gtest.h>

#include <OpenImageIO/imageio.h>

#include <cmath>
#include <fstream>
#include <vector>

#include "measure/image_io.hpp"
#include "measure_test_support.hpp"

using namespace drapelab;
using namespace drapelab::measure_testing;

namespace {

Image gradient(int h = 40, int w = 50) {
  Image g(h, w);
  for (int r = 0; r < h; ++r)
    for (int c = 0; c < w; ++c) g(r, c) = (r * w + c) / static_cast<double>(h * w - 1);
  return g;
}

}  // namespace

struct FormatCase {
  const char* name;
  PixelType type;
  int channels;
  double tolerance;
};

class MeasureImageIoRoundTrip : public ::testing::TestWithParam<FormatCase> {};

TEST_P(MeasureImageIoRoundTrip, LuminanceSurvivesWriteAndRead) {
  const FormatCase fc = GetParam();
  TempDir dir;
  const Image g = gradient();
  const std::string path = dir.file(fc.name);
  write_image(path, g, fc.type, fc.channels);
  ImageFileInfo info;
  const Image back = read_luminance(path, &info);
  ASSERT_EQ(back.rows(), g.rows());
  ASSERT_EQ(back.cols(), g.cols());
  EXPECT_EQ(info.channels, fc.channels);
  EXPECT_LT((back - g).abs().maxCoeff(), fc.tolerance) << fc.name;
}

INSTANTIATE_TEST_SUITE_P(Formats, MeasureImageIoRoundTrip,
                         ::testing::Values(FormatCase{"grey8.png", PixelType::UInt8, 1, 0.5 / 255 + 1e-9},
                                           FormatCase{"rgb8.png", PixelType::UInt8, 3, 0.5 / 255 + 1e-9},
                                           FormatCase{"rgba16.png", PixelType::UInt16, 4, 1e-4},
                                           FormatCase{"grey16.tif", PixelType::UInt16, 1, 1e-4},
                                           FormatCase{"rgbf.tif", PixelType::Float, 3, 1e-6},
                                           FormatCase{"greyf.exr", PixelType::Float, 1, 1e-6},
                                           FormatCase{"rgbaf.exr", PixelType::Float, 4, 1e-6},
                                           FormatCase{"rgb.jpg", PixelType::UInt8, 3, 0.06}),
                         [](const auto& info) {
                           std::string n = info.param.name;
                           for (char& ch : n) if (ch == '.') ch = '_';
                           return n;
                         });

TEST(MeasureImageIo, ReadsTheBundledJpegAsTheReadmeSilhouetteValue) {
  ImageFileInfo info;
  const Image lum = read_luminance(asset("cusick/fabric_02/silhouettes/sample_02_capture_1.jpg"), &info);
  EXPECT_EQ(lum.rows(), 256);
  EXPECT_EQ(lum.cols(), 256);
  EXPECT_EQ(info.format, "jpeg");
  EXPECT_EQ(info.pixel_type, "uint8");
  // s = 1 - mean(RGB)/255 > 0.5 counts 28909 cloth pixels in this image (measured with another decoder).
  EXPECT_NEAR(static_cast<double>(((1.0 - lum) > 0.5).count()), 28909, 30);
}

// Writes raw float pixels (interleaved channels) with OpenImageIO, for layouts write_image does not make.
static void write_raw(const std::string& path, int w, int h, int nc, const std::vector<float>& px, OIIO::TypeDesc type) {
  auto out = OIIO::ImageOutput::create(path);
  ASSERT_TRUE(out);
  ASSERT_TRUE(out->open(path, OIIO::ImageSpec(w, h, nc, type)));
  ASSERT_TRUE(out->write_image(OIIO::TypeDesc::FLOAT, px.data()));
  ASSERT_TRUE(out->close());
}

TEST(MeasureImageIo, HdrFloatImagesAreNormalisedByTheirPeak) {
  TempDir dir;
  write_raw(dir.file("hdr.exr"), 2, 1, 1, {0.5f, 4.0f}, OIIO::TypeDesc::FLOAT);
  const Image lum = read_luminance(dir.file("hdr.exr"));
  EXPECT_NEAR(lum(0, 0), 0.125, 1e-6);
  EXPECT_NEAR(lum(0, 1), 1.0, 1e-6);
}

TEST(MeasureImageIo, TransparentPixelsAreCompositedOverWhite) {
  TempDir dir;
  // Grey + alpha: black opaque, black transparent, black half transparent.
  write_raw(dir.file("ga.png"), 3, 1, 2, {0, 1, 0, 0, 0, 0.5f}, OIIO::TypeDesc::UINT16);
  const Image lum = read_luminance(dir.file("ga.png"));
  EXPECT_NEAR(lum(0, 0), 0.0, 1e-4);
  EXPECT_NEAR(lum(0, 1), 1.0, 1e-4);
  EXPECT_NEAR(lum(0, 2), 0.5, 1e-4);
  // RGBA: luminance is the mean of R, G, B.
  write_raw(dir.file("rgba.tif"), 1, 1, 4, {0.3f, 0.6f, 0.9f, 1.0f}, OIIO::TypeDesc::FLOAT);
  EXPECT_NEAR(read_luminance(dir.file("rgba.tif"))(0, 0), 0.6, 1e-6);
}

TEST(MeasureImageIo, NonFinitePixelsAreAClearError) {
  TempDir dir;
  write_raw(dir.file("nan.exr"), 2, 1, 1, {0.5f, std::nanf("")}, OIIO::TypeDesc::FLOAT);
  expect_input_error([&] { read_luminance(dir.file("nan.exr")); }, {"nan.exr", "non-finite"});
}

TEST(MeasureImageIo, MissingFileIsAClearError) {
  expect_input_error([] { read_luminance("/nonexistent/silhouette.jpg"); },
                     {"/nonexistent/silhouette.jpg", "not found"});
}

TEST(MeasureImageIo, EmptyFileIsAClearError) {
  TempDir dir;
  std::ofstream(dir.file("empty.jpg")).close();
  expect_input_error([&] { read_luminance(dir.file("empty.jpg")); }, {"empty.jpg", "empty"});
}

TEST(MeasureImageIo, DirectoryIsAClearError) {
  TempDir dir;
  expect_input_error([&] { read_luminance(dir.file("")); }, {"not a regular file"});
}

TEST(MeasureImageIo, CorruptFileIsAClearError) {
  TempDir dir;
  std::ofstream out(dir.file("noise.jpg"), std::ios::binary);
  for (int i = 0; i < 2000; ++i) out.put(static_cast<char>((i * 7919) % 251));
  out.close();
  expect_input_error([&] { read_luminance(dir.file("noise.jpg")); }, {"noise.jpg", "cannot read image"});
  std::ofstream(dir.file("text.png")) << "this is not an image\n";
  expect_input_error([&] { read_luminance(dir.file("text.png")); }, {"text.png"});
}

TEST(MeasureImageIo, TruncatedFilesOfEveryFormatAreClearErrors) {
  TempDir dir;
  const Image g = disk_mask(0.12);
  struct Case { const char* name; PixelType type; int channels; };
  for (const Case c : {Case{"t.png", PixelType::UInt8, 3}, Case{"t.tif", PixelType::UInt16, 3},
                       Case{"t.exr", PixelType::Float, 3}}) {
    write_image(dir.file(c.name), g, c.type, c.channels);
    const std::string cut = dir.file(std::string("cut_") + c.name);
    copy_prefix(dir.file(c.name), cut, 0.5);
    expect_input_error([&] { read_luminance(cut); }, {cut});
  }
  const std::string jpg = dir.file("cut.jpg");
  copy_prefix(asset("cusick/fabric_02/silhouettes/sample_02_capture_1.jpg"), jpg, 0.5);
  expect_input_error([&] { read_luminance(jpg); }, {"cut.jpg", "truncated or corrupt"});
}

TEST(MeasureImageIo, UnwritablePathIsAClearError) {
  expect_input_error([] { write_image("/nonexistent/folder/out.png", Image::Zero(4, 4)); },
                     {"/nonexistent/folder/out.png", "cannot write"});
}
