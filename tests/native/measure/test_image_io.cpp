// Image import: formats, bit depths, channel layouts, and clear errors for bad files.
#include <gtest/gtest.h>

#include <OpenImageIO/imageio.h>

#include <array>
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

// ---- header checks before decoding (issue 16)

namespace {

std::string u32_be(uint32_t v) {
  return {static_cast<char>(v >> 24), static_cast<char>(v >> 16), static_cast<char>(v >> 8), static_cast<char>(v)};
}
std::string u32_le(uint32_t v) {
  return {static_cast<char>(v), static_cast<char>(v >> 8), static_cast<char>(v >> 16), static_cast<char>(v >> 24)};
}
std::string u16_le(uint32_t v) { return {static_cast<char>(v), static_cast<char>(v >> 8)}; }

uint32_t crc32(const std::string& bytes) {  // PNG's chunk CRC (ISO 3309)
  uint32_t c = 0xffffffffu;
  for (const char ch : bytes) {
    c ^= static_cast<unsigned char>(ch);
    for (int k = 0; k < 8; ++k) c = (c >> 1) ^ (0xedb88320u & (0u - (c & 1u)));
  }
  return ~c;
}

// Well-formed headers declaring a w x h image (RGBA or RGB) with no pixel data after them.
std::string png_declaring(uint32_t w, uint32_t h) {
  const std::string ihdr = "IHDR" + u32_be(w) + u32_be(h) + std::string("\x10\x06\0\0\0", 5);  // 16-bit RGBA
  return std::string("\x89PNG\r\n\x1a\n", 8) + u32_be(13) + ihdr + u32_be(crc32(ihdr));
}
std::string tiff_declaring(uint32_t w, uint32_t h) {
  std::string t = std::string("II*\0", 4) + u32_le(8) + u16_le(3);
  t += u16_le(256) + u16_le(4) + u32_le(1) + u32_le(w);  // ImageWidth, LONG
  t += u16_le(257) + u16_le(4) + u32_le(1) + u32_le(h);  // ImageLength, LONG
  t += u16_le(277) + u16_le(3) + u32_le(1) + u32_le(4);  // SamplesPerPixel, SHORT
  return t + u32_le(0);
}
std::string exr_declaring(uint32_t w, uint32_t h) {
  std::string e = std::string("\x76\x2f\x31\x01\x02\0\0\0", 8);
  e += std::string("channels\0chlist\0", 16) + u32_le(19) + std::string("R\0", 2) + u32_le(2) + u32_le(0) +
       u32_le(1) + u32_le(1) + std::string("\0", 1);
  e += std::string("compression\0compression\0", 24) + u32_le(1) + std::string("\0", 1);
  e += std::string("dataWindow\0box2i\0", 17) + u32_le(16) + u32_le(0) + u32_le(0) + u32_le(w - 1) + u32_le(h - 1);
  return e + std::string("\0", 1);
}
std::string jpeg_declaring(uint32_t w, uint32_t h) {
  std::string j = std::string("\xff\xd8\xff\xc0\0\x11\x08", 7);
  j += {static_cast<char>(h >> 8), static_cast<char>(h), static_cast<char>(w >> 8), static_cast<char>(w), 3};
  for (char id = 1; id <= 3; ++id) j += std::string{id, 0x11, 0};
  return j + std::string("\xff\xd9", 2);
}
std::string bmp_declaring(uint32_t w, uint32_t h) {
  return "BM" + u32_le(54) + u32_le(0) + u32_le(54) + u32_le(40) + u32_le(w) + u32_le(-h) + u16_le(1) + u16_le(32) +
         std::string(24, '\0');
}

Image decode(const std::string& bytes, const std::string& source) {
  return decode_luminance(reinterpret_cast<const unsigned char*>(bytes.data()), bytes.size(), source);
}

}  // namespace

TEST(MeasureImageIo, HugeDeclaredSizesAreRefusedBeforeDecoding) {
  // Each file is under 100 bytes and declares 100000 x 100000 pixels (or 65535 x 65535 for JPEG, its
  // largest): the header check refuses it; decoding it would allocate tens of gigabytes.
  struct Case { const char* name; std::string bytes; };
  for (const Case& c : {Case{"huge.png", png_declaring(100000, 100000)},
                        Case{"huge.tif", tiff_declaring(100000, 100000)},
                        Case{"huge.exr", exr_declaring(100000, 100000)},
                        Case{"huge.jpg", jpeg_declaring(65535, 65535)},
                        Case{"huge.bmp", bmp_declaring(100000, 100000)}}) {
    expect_input_error([&] { decode(c.bytes, c.name); }, {c.name, "image too large", "pixels"});
    TempDir dir;
    std::ofstream(dir.file(c.name), std::ios::binary) << c.bytes;
    expect_input_error([&] { read_luminance(dir.file(c.name)); }, {c.name, "image too large"});
  }
  // The pixel cap applies to the product as well as to each side; a wide strip within both is read on.
  expect_input_error([] { decode(png_declaring(kMaxImageSide, kMaxImageSide), "square.png"); }, {"too large"});
  expect_input_error([] { decode(png_declaring(2, kMaxImageSide + 1), "tall.png"); }, {"too large"});
  expect_input_error([] { decode(png_declaring(0, 10), "empty.png"); }, {"no pixels"});
  expect_input_error([] { decode(png_declaring(4, 4), "short.png"); }, {"short.png", "truncated"});
}

TEST(MeasureImageIo, OnlyTheSupportedFormatsReachADecoder) {
  expect_input_error([] { decode("GIF89a\x01\0\x01\0\0\0\0;", "anim.gif"); }, {"anim.gif", "unrecognised format"});
  expect_input_error([] { decode("P5\n2 2\n255\n\0\0\0\0", "grey.pgm"); }, {"grey.pgm", "unrecognised format"});
  expect_input_error([] { decode(std::string(1, '\0'), "zero"); }, {"zero", "unrecognised format"});
  expect_input_error([] { decode("", "nothing"); }, {"nothing", "empty"});
  // BMP: the plain layout only (OpenImageIO 2.4's reader crashes on some run-length encoded files).
  std::string rle = bmp_declaring(8, 8);
  rle[30] = 1;  // BI_RLE8
  expect_input_error([&] { decode(rle, "rle.bmp"); }, {"rle.bmp", "only uncompressed"});
}

TEST(MeasureImageIo, DecodingBytesInMemoryEqualsReadingTheFile) {
  const std::string path = asset("cusick/fabric_02/silhouettes/sample_02_capture_1.jpg");
  std::ifstream in(path, std::ios::binary);
  const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  ImageFileInfo info;
  const Image from_memory = decode_luminance(reinterpret_cast<const unsigned char*>(bytes.data()), bytes.size(),
                                             "memory", &info);
  EXPECT_EQ(info.format, "jpeg");
  EXPECT_EQ((from_memory - read_luminance(path)).abs().maxCoeff(), 0.0);
  // The format comes from the content, not the name.
  TempDir dir;
  std::ofstream(dir.file("really_a_jpeg.png"), std::ios::binary) << bytes;
  EXPECT_EQ((read_luminance(dir.file("really_a_jpeg.png")) - from_memory).abs().maxCoeff(), 0.0);
}

// ---- metadata (issue 16): OpenImageIO 2.4 parses ICC profiles on open and reads out of bounds on corrupt ones

namespace {

std::string file_bytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return {(std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>()};
}

// A minimal ICC profile: header (size, 'acsp'), then `tags` entries of (signature, offset, size).
std::string icc_profile(const std::vector<std::array<uint32_t, 2>>& tags, uint32_t extra = 0) {
  const uint32_t size = 132 + 12 * static_cast<uint32_t>(tags.size()) + extra;
  std::string p = u32_be(size) + std::string(32, '\0') + "acsp" + std::string(88, '\0') + u32_be(tags.size());
  for (const auto& t : tags) p += "text" + u32_be(t[0]) + u32_be(t[1]);
  return p + std::string(extra, 't');
}

// A 2 x 2 grey 8-bit uncompressed TIFF carrying `icc` as its ICC profile (tag 34675).
std::string tiff_with_icc(const std::string& icc) {
  auto entry = [](uint16_t tag, uint16_t type, uint32_t count, uint32_t value) {
    return u16_le(tag) + u16_le(type) + u32_le(count) + u32_le(value);
  };
  const uint32_t entries = 10, pixels_at = 8 + 2 + 12 * entries + 4, icc_at = pixels_at + 4;
  std::string t = std::string("II*\0", 4) + u32_le(8) + u16_le(entries);
  t += entry(256, 3, 1, 2) + entry(257, 3, 1, 2) + entry(258, 3, 1, 8) + entry(259, 3, 1, 1) + entry(262, 3, 1, 1) +
       entry(273, 4, 1, pixels_at) + entry(277, 3, 1, 1) + entry(278, 3, 1, 2) + entry(279, 4, 1, 4) +
       entry(34675, 7, static_cast<uint32_t>(icc.size()), icc_at);
  return t + u32_le(0) + std::string("\x00\x40\x80\xff", 4) + icc;
}

}  // namespace

TEST(MeasureImageIo, CorruptIccProfilesNeverReachTheDecoder) {
  // JPEG: the bundled photo carries an ICC profile (and Exif, XMP); with a tag offset pointing 4 GB away it
  // reads the same as the original (application segments are left out before decoding).
  const std::string jpeg = file_bytes(asset("cusick/fabric_02/silhouettes/sample_02_capture_1.jpg"));
  const size_t icc = jpeg.find("ICC_PROFILE");
  ASSERT_NE(icc, std::string::npos);
  std::string corrupt = jpeg;
  corrupt.replace(icc + 14 + 132 + 4, 4, std::string("\xff\xff\xf0\x00", 4));  // first tag's offset
  EXPECT_EQ((decode(corrupt, "icc.jpg") - decode(jpeg, "original.jpg")).abs().maxCoeff(), 0.0);

  // PNG: an iCCP chunk (here garbage, with a wrong CRC) is left out too.
  TempDir dir;
  write_image(dir.file("g.png"), gradient(8, 8));
  const std::string png = file_bytes(dir.file("g.png"));
  const std::string iccp = u32_be(5) + std::string("iCCPjunk\0\x01\x02\x03\x04", 13);  // type, data, CRC
  const std::string with_iccp = png.substr(0, 33) + iccp + png.substr(33);  // after the signature and IHDR
  EXPECT_EQ((decode(with_iccp, "iccp.png") - decode(png, "g.png")).abs().maxCoeff(), 0.0);

  // TIFF: the profile is checked as a profile parser reads it.
  EXPECT_NEAR(decode(tiff_with_icc(icc_profile({})), "ok.tif")(1, 1), 1.0, 1e-6);
  EXPECT_NEAR(decode(tiff_with_icc(icc_profile({{144, 8}}, 8)), "text.tif")(0, 1), 64 / 255.0, 1e-6);
  expect_input_error([] { decode(tiff_with_icc(icc_profile({{0xfffff93cu, 2060}})), "far.tif"); },
                     {"far.tif", "corrupt ICC colour profile", "outside"});
  expect_input_error([] { decode(tiff_with_icc(icc_profile({}).substr(0, 100)), "short.tif"); },
                     {"short.tif", "corrupt ICC colour profile"});
}
