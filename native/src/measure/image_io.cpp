#include "measure/image_io.hpp"

#include <OpenImageIO/imageio.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <fstream>
#include <system_error>
#include <filesystem>
#include <vector>

#include "util/error.hpp"

namespace drapelab {

namespace fs = std::filesystem;

namespace {

std::string one_line(std::string s) {
  std::replace(s.begin(), s.end(), '\n', ' ');
  while (!s.empty() && (s.back() == ' ' || s.back() == '\r')) s.pop_back();
  return s;
}

// Some readers (TIFF, OpenEXR) fill missing data with zeros instead of failing on a truncated file.
// These structural checks compare the byte ranges the file's own index refers to with its size.
class Bytes {
 public:
  explicit Bytes(const std::string& path) {
    std::ifstream in(path, std::ios::binary);
    data_.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  }
  size_t size() const { return data_.size(); }
  bool has(uint64_t off, uint64_t n) const { return off <= data_.size() && n <= data_.size() - off; }
  uint64_t u(uint64_t off, int n, bool little) const {  // caller checks has(off, n)
    uint64_t v = 0;
    for (int i = 0; i < n; ++i) {
      const uint64_t b = static_cast<unsigned char>(data_[off + (little ? i : n - 1 - i)]);
      v |= b << (8 * i);
    }
    return v;
  }
  const std::vector<char>& data() const { return data_; }

 private:
  std::vector<char> data_;
};

// Returns an empty string when the TIFF's first image's strips/tiles all lie inside the file, else why not.
std::string check_tiff_extent(const Bytes& b) {
  if (!b.has(0, 8)) return "file shorter than a TIFF header";
  const bool little = b.data()[0] == 'I';
  if (b.u(2, 2, little) != 42) return "";  // BigTIFF: not checked here
  const uint64_t ifd = b.u(4, 4, little);
  if (!b.has(ifd, 2)) return "image directory lies beyond the end of the file";
  const uint64_t n = b.u(ifd, 2, little);
  if (!b.has(ifd + 2, 12 * n)) return "image directory lies beyond the end of the file";
  auto values = [&](uint64_t entry) {
    std::vector<uint64_t> out;
    const uint64_t type = b.u(entry + 2, 2, little), count = b.u(entry + 4, 4, little);
    const int size = type == 3 ? 2 : type == 4 ? 4 : type == 16 ? 8 : 0;
    if (size == 0 || count > (uint64_t(1) << 24)) return out;
    const uint64_t where = size * count <= 4 ? entry + 8 : b.u(entry + 8, 4, little);
    if (!b.has(where, size * count)) return out;
    for (uint64_t i = 0; i < count; ++i) out.push_back(b.u(where + i * size, size, little));
    return out;
  };
  std::vector<uint64_t> offsets, counts;
  for (uint64_t i = 0; i < n; ++i) {
    const uint64_t e = ifd + 2 + 12 * i, tag = b.u(e, 2, little);
    if (tag == 273 || tag == 324) offsets = values(e);
    if (tag == 279 || tag == 325) counts = values(e);
  }
  if (offsets.empty() || offsets.size() != counts.size()) return "";
  for (size_t i = 0; i < offsets.size(); ++i)
    if (!b.has(offsets[i], counts[i]))
      return "pixel data block " + std::to_string(i + 1) + " of " + std::to_string(offsets.size()) +
             " lies beyond the end of the file (" + std::to_string(b.size()) + " bytes)";
  return "";
}

// Same for a single-part scanline OpenEXR file: every chunk in the offset table must lie inside the file.
std::string check_exr_extent(const Bytes& b) {
  if (!b.has(0, 8) || b.u(0, 4, true) != 20000630u) return "";
  const uint64_t version = b.u(4, 4, true);
  if (version & (0x200 | 0x800 | 0x1000)) return "";  // tiled, deep or multi-part: not checked here
  uint64_t p = 8;
  int lines_per_chunk = 1;
  int64_t ymin = 0, ymax = -1;
  const auto& d = b.data();
  for (;;) {
    const auto name_end = std::find(d.begin() + static_cast<long>(p), d.end(), '\0');
    if (name_end == d.end()) return "header runs past the end of the file";
    const std::string name(d.begin() + static_cast<long>(p), name_end);
    p = static_cast<uint64_t>(name_end - d.begin()) + 1;
    if (name.empty()) break;
    const auto type_end = std::find(d.begin() + static_cast<long>(p), d.end(), '\0');
    if (type_end == d.end()) return "header runs past the end of the file";
    p = static_cast<uint64_t>(type_end - d.begin()) + 1;
    if (!b.has(p, 4)) return "header runs past the end of the file";
    const uint64_t size = b.u(p, 4, true);
    p += 4;
    if (!b.has(p, size)) return "header runs past the end of the file";
    if (name == "compression" && size >= 1) {
      static const int lines[] = {1, 1, 1, 16, 32, 16, 32, 32, 32, 256};
      const uint64_t c = b.u(p, 1, true);
      lines_per_chunk = c < 10 ? lines[c] : 1;
    }
    if (name == "dataWindow" && size == 16) {
      ymin = static_cast<int32_t>(b.u(p + 4, 4, true));
      ymax = static_cast<int32_t>(b.u(p + 12, 4, true));
    }
    p += size;
  }
  if (ymax < ymin) return "";
  const uint64_t chunks = static_cast<uint64_t>((ymax - ymin + lines_per_chunk) / lines_per_chunk);
  if (!b.has(p, 8 * chunks)) return "chunk offset table runs past the end of the file";
  for (uint64_t i = 0; i < chunks; ++i) {
    const uint64_t off = b.u(p + 8 * i, 8, true);
    if (!b.has(off, 8) || !b.has(off + 8, b.u(off + 4, 4, true)))
      return "scanline chunk " + std::to_string(i + 1) + " of " + std::to_string(chunks) +
             " lies beyond the end of the file (" + std::to_string(b.size()) + " bytes)";
  }
  return "";
}

}  // namespace

Image read_luminance(const std::string& path, ImageFileInfo* info) {
  std::error_code ec;
  const fs::file_status st = fs::status(path, ec);
  if (ec || !fs::exists(st)) throw InputError(path + ": image file not found");
  if (!fs::is_regular_file(st)) throw InputError(path + ": not a regular file");
  if (fs::file_size(path, ec) == 0) throw InputError(path + ": image file is empty (0 bytes)");

  auto in = OIIO::ImageInput::open(path);
  if (!in) {
    const std::string why = one_line(OIIO::geterror());
    throw InputError(path + ": cannot read image (unrecognised format, truncated or corrupt file)" +
                     (why.empty() ? std::string() : ": " + why));
  }
  const OIIO::ImageSpec spec = in->spec();
  const int w = spec.width, h = spec.height, nc = spec.nchannels;
  if (w <= 0 || h <= 0 || nc <= 0)
    throw InputError(path + ": image has no pixels (" + std::to_string(w) + "x" + std::to_string(h) + ")");
  if (static_cast<int64_t>(w) * h > (int64_t(1) << 28))
    throw InputError(path + ": image too large (" + std::to_string(w) + "x" + std::to_string(h) + ")");
  std::vector<float> px(static_cast<size_t>(w) * h * nc);
  const bool ok = in->read_image(0, 0, 0, nc, OIIO::TypeDesc::FLOAT, px.data());
  // JPEG reports a premature end of data as an error after a "successful" read: treat it as failure.
  const std::string err = one_line(in->geterror());
  const std::string format = in->format_name();
  in->close();
  if (!ok || !err.empty())
    throw InputError(path + ": cannot decode image (truncated or corrupt file)" + (err.empty() ? "" : ": " + err));
  if (format == "tiff" || format == "openexr") {
    const Bytes bytes(path);
    const std::string why = format == "tiff" ? check_tiff_extent(bytes) : check_exr_extent(bytes);
    if (!why.empty()) throw InputError(path + ": truncated or corrupt " + format + " file: " + why);
  }

  const int alpha = spec.alpha_channel >= 0 ? spec.alpha_channel : (nc == 2 || nc == 4 ? nc - 1 : -1);
  const int colour = std::min(nc - (alpha >= 0 ? 1 : 0), 3);  // grey = 1, RGB = 3
  const bool is_float = spec.format.basetype == OIIO::TypeDesc::FLOAT ||
                        spec.format.basetype == OIIO::TypeDesc::HALF ||
                        spec.format.basetype == OIIO::TypeDesc::DOUBLE;
  Image lum(h, w);
  double peak = 0.0;
  for (int r = 0; r < h; ++r)
    for (int c = 0; c < w; ++c) {
      const float* p = &px[(static_cast<size_t>(r) * w + c) * nc];
      double l = 0.0;
      for (int k = 0; k < colour; ++k) l += p[k];
      l /= colour;
      if (!std::isfinite(l) || (alpha >= 0 && !std::isfinite(p[alpha])))
        throw InputError(path + ": image has non-finite pixel values (NaN or infinity) at row " +
                         std::to_string(r) + ", column " + std::to_string(c));
      l = std::max(l, 0.0);
      lum(r, c) = l;
      peak = std::max(peak, l);
    }
  // HDR float images are normalised by their peak before compositing (the alpha blend assumes [0, 1]).
  if (is_float && peak > 1.0) lum /= peak;
  lum = lum.min(1.0);
  if (alpha >= 0)
    for (int r = 0; r < h; ++r)
      for (int c = 0; c < w; ++c) {
        const double a = std::clamp<double>(px[(static_cast<size_t>(r) * w + c) * nc + alpha], 0.0, 1.0);
        lum(r, c) = a * lum(r, c) + (1.0 - a);
      }
  if (info) *info = {w, h, nc, spec.format.c_str(), format};
  return lum;
}

void write_image(const std::string& path, const Image& image, PixelType type, int channels) {
  if (channels != 1 && channels != 3 && channels != 4)
    throw InputError(path + ": can only write 1, 3 or 4 channels, not " + std::to_string(channels));
  if (image.size() == 0) throw InputError(path + ": refusing to write an empty image");
  const int w = static_cast<int>(image.cols()), h = static_cast<int>(image.rows());
  const OIIO::TypeDesc td = type == PixelType::UInt8 ? OIIO::TypeDesc::UINT8
                            : type == PixelType::UInt16 ? OIIO::TypeDesc::UINT16 : OIIO::TypeDesc::FLOAT;
  std::vector<float> px(static_cast<size_t>(w) * h * channels);
  for (int r = 0; r < h; ++r)
    for (int c = 0; c < w; ++c)
      for (int k = 0; k < channels; ++k)
        px[(static_cast<size_t>(r) * w + c) * channels + k] =
            k == 3 ? 1.0f : static_cast<float>(std::clamp(image(r, c), 0.0, 1.0));
  const fs::path target(path);
  // Keep the extension on the temporary name: OpenImageIO picks the format from it.
  const fs::path tmp = target.parent_path() / (".tmp_" + target.stem().string() + target.extension().string());
  auto out = OIIO::ImageOutput::create(path);
  if (!out) throw InputError(path + ": no image writer for this file type: " + one_line(OIIO::geterror()));
  OIIO::ImageSpec spec(w, h, channels, td);
  if (!out->open(tmp.string(), spec) || !out->write_image(OIIO::TypeDesc::FLOAT, px.data()) || !out->close()) {
    const std::string why = one_line(out->geterror());
    std::error_code ec;
    fs::remove(tmp, ec);
    throw InputError(path + ": cannot write image" + (why.empty() ? "" : ": " + why));
  }
  std::error_code ec;
  fs::rename(tmp, target, ec);
  if (ec) {
    fs::remove(tmp, ec);
    throw InputError(path + ": cannot write image: " + ec.message());
  }
}

}  // namespace drapelab
