#include "measure/image_io.hpp"

#include <OpenImageIO/filesystem.h>
#include <OpenImageIO/imageio.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <iterator>
#include <system_error>
#include <filesystem>
#include <utility>
#include <vector>

#include "util/error.hpp"
#include "util/text.hpp"

namespace drapelab {

namespace fs = std::filesystem;

namespace {

// A decoder's message on one line; it may quote bytes of the file.
std::string one_line(std::string s) {
  std::replace(s.begin(), s.end(), '\n', ' ');
  while (!s.empty() && (s.back() == ' ' || s.back() == '\r')) s.pop_back();
  return printable(s, 300);
}

// A read-only view of an image file's bytes with bounds-checked integer reads.
class Bytes {
 public:
  Bytes(const unsigned char* data, size_t size) : data_(data), size_(size) {}
  size_t size() const { return size_; }
  bool has(uint64_t off, uint64_t n) const { return off <= size_ && n <= size_ - off; }
  uint64_t u(uint64_t off, int n, bool little) const {  // caller checks has(off, n)
    uint64_t v = 0;
    for (int i = 0; i < n; ++i) v |= uint64_t(data_[off + (little ? i : n - 1 - i)]) << (8 * i);
    return v;
  }
  unsigned char operator[](uint64_t off) const { return data_[off]; }  // caller checks has(off, 1)
  bool starts_with(const char* magic, size_t n) const {
    return has(0, n) && std::memcmp(data_, magic, n) == 0;
  }
  // Offset of the first `value` at or after `from`, or size() when there is none.
  uint64_t find(uint64_t from, unsigned char value) const {
    if (from >= size_) return size_;
    const void* hit = std::memchr(data_ + from, value, size_ - from);
    return hit ? static_cast<uint64_t>(static_cast<const unsigned char*>(hit) - data_) : size_;
  }

 private:
  const unsigned char* data_;
  size_t size_;
};

// OpenImageIO's name of the file's format, recognised by its leading bytes; nullptr for any other format.
const char* sniff_format(const Bytes& b) {
  if (b.starts_with("\x89PNG\r\n\x1a\n", 8)) return "png";
  if (b.starts_with("\xff\xd8\xff", 3)) return "jpeg";
  if (b.starts_with("II*\0", 4) || b.starts_with("MM\0*", 4) || b.starts_with("II+\0", 4) ||
      b.starts_with("MM\0+", 4))
    return "tiff";
  if (b.starts_with("\x76\x2f\x31\x01", 4)) return "openexr";
  if (b.starts_with("BM", 2)) return "bmp";
  return nullptr;
}

// What a header declares, read before any decoder runs. `error` says why the header cannot be read.
struct DeclaredImage {
  int64_t width = 0, height = 0, channels = 1;
  int64_t tile_width = 0, tile_height = 0;  // 0 = not tiled
  int64_t depth = 1;                        // > 1: a volume (TIFF ImageDepth)
  std::string error;
};

DeclaredImage png_header(const Bytes& b) {
  DeclaredImage d;
  if (!b.has(0, 26) || !b.starts_with("\x89PNG\r\n\x1a\n\0\0\0\x0dIHDR", 16)) {
    d.error = "no IHDR chunk at the start of the file";
    return d;
  }
  static const int channels_of_colour_type[7] = {1, 0, 3, 3, 2, 0, 4};  // palette expands to RGB
  d.width = static_cast<int64_t>(b.u(16, 4, false));
  d.height = static_cast<int64_t>(b.u(20, 4, false));
  d.channels = b[25] < 7 ? channels_of_colour_type[b[25]] : 0;
  if (d.channels == 0) d.error = "invalid colour type " + std::to_string(b[25]);
  return d;
}

DeclaredImage jpeg_header(const Bytes& b) {
  DeclaredImage d;
  uint64_t p = 2;
  for (;;) {
    p = b.find(p, 0xff);  // libjpeg skips stray bytes between segments too
    while (b.has(p, 1) && b[p] == 0xff) ++p;
    if (!b.has(p, 1)) {
      d.error = "no frame header (SOF marker) in the file";
      return d;
    }
    const unsigned char marker = b[p++];
    if (marker == 0x01 || marker == 0xd8 || (marker >= 0xd0 && marker <= 0xd7)) continue;  // no length
    if (marker == 0xd9 || marker == 0xda) {
      d.error = "no frame header (SOF marker) before the image data";
      return d;
    }
    if (!b.has(p, 2) || b.u(p, 2, false) < 2) {
      d.error = "segment header runs past the end of the file";
      return d;
    }
    const uint64_t length = b.u(p, 2, false);
    const bool frame = marker >= 0xc0 && marker <= 0xcf && marker != 0xc4 && marker != 0xc8 && marker != 0xcc;
    if (frame) {
      if (length < 8 || !b.has(p, 8)) {
        d.error = "frame header (SOF marker) runs past the end of the file";
        return d;
      }
      d.height = static_cast<int64_t>(b.u(p + 3, 2, false));
      d.width = static_cast<int64_t>(b.u(p + 5, 2, false));
      d.channels = b[p + 7];
      return d;
    }
    p += length;
  }
}

// The first image directory of a classic TIFF or a BigTIFF.
struct TiffDirectory {
  bool little = true;
  bool big = false;               // BigTIFF: 8-byte counts and offsets, 20-byte entries
  std::vector<uint64_t> entries;  // byte offset of each 12- or 20-byte entry
  std::string error;

  // Values of a SHORT, LONG or LONG8 entry (empty for other types or when they lie outside the file).
  std::vector<uint64_t> values(const Bytes& b, uint64_t entry) const {
    std::vector<uint64_t> out;
    const uint64_t type = b.u(entry + 2, 2, little), count = b.u(entry + 4, big ? 8 : 4, little);
    const uint64_t size = type == 3 ? 2 : type == 4 ? 4 : type == 16 ? 8 : 0;
    if (size == 0 || count > (uint64_t(1) << 24)) return out;
    const uint64_t field = entry + (big ? 12 : 8), inline_bytes = big ? 8 : 4;
    const uint64_t where = size * count <= inline_bytes ? field : b.u(field, big ? 8 : 4, little);
    if (!b.has(where, size * count)) return out;
    for (uint64_t i = 0; i < count; ++i) out.push_back(b.u(where + i * size, static_cast<int>(size), little));
    return out;
  }
  uint64_t tag(const Bytes& b, uint64_t entry) const { return b.u(entry, 2, little); }
};

TiffDirectory tiff_first_directory(const Bytes& b) {
  TiffDirectory d;
  if (!b.has(0, 16)) {
    d.error = "file shorter than a TIFF header";
    return d;
  }
  d.little = b[0] == 'I';
  d.big = b.u(2, 2, d.little) == 43;
  const uint64_t ifd = d.big ? b.u(8, 8, d.little) : b.u(4, 4, d.little);
  const int count_bytes = d.big ? 8 : 2;
  const uint64_t entry_bytes = d.big ? 20 : 12;
  if (!b.has(ifd, count_bytes)) {
    d.error = "image directory lies beyond the end of the file";
    return d;
  }
  const uint64_t n = b.u(ifd, count_bytes, d.little);
  if (n > b.size() / entry_bytes || !b.has(ifd + count_bytes, entry_bytes * n)) {
    d.error = "image directory lies beyond the end of the file";
    return d;
  }
  for (uint64_t i = 0; i < n; ++i) d.entries.push_back(ifd + count_bytes + entry_bytes * i);
  return d;
}

DeclaredImage tiff_header(const Bytes& b) {
  DeclaredImage d;
  const TiffDirectory dir = tiff_first_directory(b);
  if (!dir.error.empty()) {
    d.error = dir.error;
    return d;
  }
  d.width = d.height = -1;
  for (const uint64_t e : dir.entries) {
    const uint64_t tag = dir.tag(b, e);
    if (tag != 256 && tag != 257 && tag != 277 && tag != 322 && tag != 323 && tag != 32997) continue;
    const std::vector<uint64_t> v = dir.values(b, e);
    if (v.empty()) {
      d.error = "tag " + std::to_string(tag) + " has no readable value";
      return d;
    }
    const int64_t x = v[0] > uint64_t(1) << 40 ? int64_t(1) << 40 : static_cast<int64_t>(v[0]);
    if (tag == 256) d.width = x;
    if (tag == 257) d.height = x;
    if (tag == 277) d.channels = x;
    if (tag == 322) d.tile_width = x;
    if (tag == 323) d.tile_height = x;
    if (tag == 32997) d.depth = x;
  }
  if (d.width < 0 || d.height < 0) d.error = "the image directory declares no width or height";
  return d;
}

// The first header of an OpenEXR file (the only one of a single-part file).
struct ExrHeader {
  uint64_t version = 0;
  int64_t xmin = 0, ymin = 0, xmax = -1, ymax = -1;  // dataWindow
  int lines_per_chunk = 1;
  int64_t channels = 0;
  int64_t tile_width = 0, tile_height = 0;
  uint64_t end = 0;  // offset just past the header
  std::string error;
};

ExrHeader exr_header(const Bytes& b) {
  ExrHeader h;
  if (!b.has(0, 8) || b.u(0, 4, true) != 20000630u) {
    h.error = "no OpenEXR magic number";
    return h;
  }
  h.version = b.u(4, 4, true);
  uint64_t p = 8;
  bool window = false;
  for (;;) {
    const uint64_t name_end = b.find(p, 0);
    if (name_end == b.size()) break;
    std::string name;
    for (uint64_t i = p; i < name_end; ++i) name += static_cast<char>(b[i]);
    p = name_end + 1;
    if (name.empty()) {
      h.end = p;
      if (!window) h.error = "the header has no dataWindow";
      return h;
    }
    const uint64_t type_end = b.find(p, 0);
    if (type_end == b.size()) break;
    p = type_end + 1;
    if (!b.has(p, 4)) break;
    const uint64_t size = b.u(p, 4, true);
    p += 4;
    if (!b.has(p, size)) break;
    if (name == "compression" && size >= 1) {
      static const int lines[] = {1, 1, 1, 16, 32, 16, 32, 32, 32, 256};
      const uint64_t c = b[p];
      h.lines_per_chunk = c < 10 ? lines[c] : 1;
    }
    if (name == "dataWindow" && size == 16) {
      auto i32 = [&](uint64_t at) { return static_cast<int64_t>(static_cast<int32_t>(b.u(at, 4, true))); };
      h.xmin = i32(p);
      h.ymin = i32(p + 4);
      h.xmax = i32(p + 8);
      h.ymax = i32(p + 12);
      window = true;
    }
    if (name == "channels") {  // chlist: (name \0, 16 bytes) ... \0
      uint64_t q = p;
      while (q < p + size && b[q] != 0) {
        q = b.find(q, 0) + 17;
        ++h.channels;
      }
    }
    if (name == "tiles" && size >= 8) {
      h.tile_width = static_cast<int64_t>(b.u(p, 4, true));
      h.tile_height = static_cast<int64_t>(b.u(p + 4, 4, true));
    }
    p += size;
  }
  h.error = "header runs past the end of the file";
  return h;
}

DeclaredImage exr_declared(const Bytes& b) {
  DeclaredImage d;
  const ExrHeader h = exr_header(b);
  d.error = h.error;
  if (!d.error.empty()) return d;
  if (h.version & 0x800) {
    d.error = "deep OpenEXR images are not supported";
    return d;
  }
  d.width = h.xmax - h.xmin + 1;
  d.height = h.ymax - h.ymin + 1;
  d.channels = h.channels;
  if (h.version & 0x200 || h.tile_width > 0) {
    d.tile_width = h.tile_width;
    d.tile_height = h.tile_height;
  }
  return d;
}

// Only the plain BMP layout is read: uncompressed 24- or 32-bit pixels after a BITMAPINFOHEADER (or a later
// version of it), every row inside the file. OpenImageIO 2.4's BMP reader crashes on some run-length
// encoded files (found by tests/fuzz/fuzz_image; regressions/image/bmp_rle_24bit_segv.bmp).
DeclaredImage bmp_header(const Bytes& b) {
  DeclaredImage d;
  if (!b.has(0, 34) || b.u(14, 4, true) < 40) {
    d.error = "file shorter than a BMP header, or an old (OS/2) BMP header";
    return d;
  }
  d.width = static_cast<int32_t>(b.u(18, 4, true));
  d.height = std::abs(static_cast<int64_t>(static_cast<int32_t>(b.u(22, 4, true))));  // < 0: top-down rows
  const uint64_t bits = b.u(28, 2, true), compression = b.u(30, 4, true), data = b.u(10, 4, true);
  d.channels = bits == 32 ? 4 : 3;
  if (b.u(26, 2, true) != 1 || (bits != 24 && bits != 32) || compression != 0) {
    d.error = "only uncompressed 24- or 32-bit BMP files are read (this one has " + std::to_string(bits) +
              " bits per pixel, compression " + std::to_string(compression) + "); convert it to PNG";
    return d;
  }
  if (d.width > 0 && d.width <= kMaxImageSide && d.height <= kMaxImageSide) {
    const uint64_t row_bytes = (static_cast<uint64_t>(d.width) * bits + 31) / 32 * 4;
    if (!b.has(data, row_bytes * static_cast<uint64_t>(d.height)))
      d.error = "pixel rows run past the end of the file (" + std::to_string(b.size()) + " bytes)";
  }
  return d;
}

std::string size_text(int64_t w, int64_t h) { return std::to_string(w) + "x" + std::to_string(h); }

// Refuses a declared size beyond the caps (image_io.hpp) before anything is allocated for it.
void check_image_size(int64_t w, int64_t h, int64_t channels, const std::string& source) {
  if (w <= 0 || h <= 0) throw InputError(source + ": image has no pixels (" + size_text(w, h) + ")");
  if (w > kMaxImageSide || h > kMaxImageSide || w * h > kMaxImagePixels)
    throw InputError(source + ": image too large (" + size_text(w, h) + " pixels; at most " +
                     std::to_string(kMaxImageSide) + " per side and " + std::to_string(kMaxImagePixels) +
                     " in all)");
  if (channels < 1 || channels > kMaxImageChannels)
    throw InputError(source + ": image has " + std::to_string(channels) + " channels (1 to " +
                     std::to_string(kMaxImageChannels) + " expected)");
}

// Tiled files keep an index of one offset per tile that readers allocate whole: 2^20 tiles (8 MiB of index)
// is 8 x 8-pixel tiles over the largest image.
constexpr int64_t kMaxImageTiles = kMaxImagePixels / 64;

// Refuses what the header of a file in `format` declares when it lies beyond the caps, before any decoding.
void check_declared(const std::string& format, const Bytes& b, const std::string& source) {
  const DeclaredImage d = format == "png"      ? png_header(b)
                          : format == "jpeg"    ? jpeg_header(b)
                          : format == "tiff"    ? tiff_header(b)
                          : format == "openexr" ? exr_declared(b)
                                                : bmp_header(b);
  if (!d.error.empty())
    throw InputError(source + ": cannot read image (truncated or corrupt " + format + " header): " + d.error);
  check_image_size(d.width, d.height, d.channels, source);
  if (d.depth != 1)
    throw InputError(source + ": image is a volume (depth " + std::to_string(d.depth) + "), not a 2D image");
  if (d.tile_width == 0 && d.tile_height == 0) return;
  // A tile is decoded whole: its size is capped like the image's.
  if (d.tile_width <= 0 || d.tile_height <= 0 || d.tile_width > kMaxImageSide || d.tile_height > kMaxImageSide ||
      d.tile_width * d.tile_height > kMaxImagePixels)
    throw InputError(source + ": image tiles of " + size_text(d.tile_width, d.tile_height) +
                     " pixels are invalid or too large");
  const int64_t tiles =
      ((d.width + d.tile_width - 1) / d.tile_width) * ((d.height + d.tile_height - 1) / d.tile_height);
  if (tiles > kMaxImageTiles)
    throw InputError(source + ": image has too many tiles (" + std::to_string(tiles) + " of " +
                     size_text(d.tile_width, d.tile_height) + " pixels; at most " + std::to_string(kMaxImageTiles) +
                     ")");
}

// Structural checks of truncation: the byte ranges the file's own index refers to against its size.
// Returns an empty string when the TIFF's first image's strips/tiles all lie inside the file, else why not.
std::string check_tiff_extent(const Bytes& b) {
  const TiffDirectory dir = tiff_first_directory(b);
  if (!dir.error.empty()) return dir.error;
  std::vector<uint64_t> offsets, counts;
  for (const uint64_t e : dir.entries) {
    const uint64_t tag = dir.tag(b, e);
    if (tag == 273 || tag == 324) offsets = dir.values(b, e);
    if (tag == 279 || tag == 325) counts = dir.values(b, e);
  }
  if (offsets.empty() || offsets.size() != counts.size()) return "";
  for (size_t i = 0; i < offsets.size(); ++i)
    if (!b.has(offsets[i], counts[i]))
      return "pixel data block " + std::to_string(i + 1) + " of " + std::to_string(offsets.size()) +
             " lies beyond the end of the file (" + std::to_string(b.size()) + " bytes)";
  return "";
}

// Same for a PNG file: every chunk up to IEND must lie inside the file. (Besides refusing a truncated file
// early, this keeps libpng from reading past the end, where OpenImageIO 2.4's read callback leaks the error
// message it raises: libpng longjmp()s over the string's destructor.)
std::string check_png_extent(const Bytes& b) {
  uint64_t p = 8;
  for (int chunk = 1;; ++chunk) {
    if (!b.has(p, 8))
      return "chunk " + std::to_string(chunk) + " starts beyond the end of the file (no IEND chunk)";
    const uint64_t length = b.u(p, 4, false);
    const bool end = b.has(p + 4, 4) && b[p + 4] == 'I' && b[p + 5] == 'E' && b[p + 6] == 'N' && b[p + 7] == 'D';
    if (!b.has(p + 8, length) || !b.has(p + 8 + length, 4))
      return "chunk " + std::to_string(chunk) + " (" + std::to_string(length) +
             " bytes) runs past the end of the file (" + std::to_string(b.size()) + " bytes)";
    if (end) return "";
    p += 12 + length;
  }
}

// Same for a single-part scanline OpenEXR file: every chunk in the offset table must lie inside the file.
std::string check_exr_extent(const Bytes& b) {
  const ExrHeader h = exr_header(b);
  if (!h.error.empty()) return h.error;
  if (h.version & (0x200 | 0x800 | 0x1000)) return "";  // tiled, deep or multi-part: not checked here
  if (h.ymax < h.ymin) return "";
  const uint64_t chunks = static_cast<uint64_t>((h.ymax - h.ymin + h.lines_per_chunk) / h.lines_per_chunk);
  if (!b.has(h.end, 8 * chunks)) return "chunk offset table runs past the end of the file";
  for (uint64_t i = 0; i < chunks; ++i) {
    const uint64_t off = b.u(h.end + 8 * i, 8, true);
    if (!b.has(off, 8) || !b.has(off + 8, b.u(off + 4, 4, true)))
      return "scanline chunk " + std::to_string(i + 1) + " of " + std::to_string(chunks) +
             " lies beyond the end of the file (" + std::to_string(b.size()) + " bytes)";
  }
  return "";
}

// ---- Metadata. Luminance needs none of it, but OpenImageIO 2.4 parses it on open, and its ICC colour
// profile parser reads out of bounds on a corrupt profile (found by fuzz_image; regressions/image/
// jpeg_icc_tag_offset_segv.jpg). JPEG and PNG files reach the decoder with only the segments and chunks that
// define their pixels; a TIFF's ICC profile (tag 34675, stored as is) is checked as the parser reads it.

// Why the ICC profile in bytes [at, at + n) would make a profile parser read outside it; empty when it
// would not. Mirrors the bounds OpenImageIO's later releases check (header, tag table, each tag's data, the
// text, desc and mluc tag types) and also requires the declared size to match.
std::string check_icc_profile(const Bytes& b, uint64_t at, uint64_t n) {
  auto inside = [n](uint64_t off, uint64_t len) { return off <= n && len <= n - off; };
  if (n < 132) return "shorter than an ICC header";
  if (b.u(at, 4, false) != n) return "its declared size (" + std::to_string(b.u(at, 4, false)) + ") is not its size";
  const uint64_t tags = b.u(at + 128, 4, false);
  if (!inside(132, 12 * tags)) return "its tag table runs past its end";
  for (uint64_t i = 0; i < tags; ++i) {
    const uint64_t entry = at + 132 + 12 * i, off = b.u(entry + 4, 4, false), size = b.u(entry + 8, 4, false);
    const std::string why = "tag " + std::to_string(i + 1) + " of " + std::to_string(tags);
    if (!inside(off, std::max<uint64_t>(4, size))) return why + " lies outside the profile";
    const std::string type{static_cast<char>(b[at + off]), static_cast<char>(b[at + off + 1]),
                           static_cast<char>(b[at + off + 2]), static_cast<char>(b[at + off + 3])};
    if ((type == "text" && size < 8) || (type == "desc" && size < 12)) return why + " is too short for its type";
    if (type != "mluc") continue;
    if (!inside(off, 16)) return why + " (mluc) is too short";
    const uint64_t records = b.u(at + off + 8, 4, false);
    if (!inside(off + 16, 12 * records)) return why + " (mluc) has records outside the profile";
    for (uint64_t r = 0; r < records; ++r) {
      const uint64_t rec = at + off + 16 + 12 * r;
      if (!inside(off + b.u(rec + 8, 4, false), b.u(rec + 4, 4, false)))
        return why + " (mluc) has a string outside the profile";
    }
  }
  return "";
}

std::string check_tiff_icc_profile(const Bytes& b) {
  const TiffDirectory dir = tiff_first_directory(b);
  if (!dir.error.empty()) return dir.error;
  for (const uint64_t e : dir.entries) {
    if (dir.tag(b, e) != 34675) continue;
    const uint64_t count = b.u(e + 4, dir.big ? 8 : 4, dir.little), field = e + (dir.big ? 12 : 8);
    const uint64_t at = count <= (dir.big ? 8u : 4u) ? field : b.u(field, dir.big ? 8 : 4, dir.little);
    if (!b.has(at, count)) return "its ICC colour profile lies beyond the end of the file";
    const std::string why = check_icc_profile(b, at, count);
    if (!why.empty()) return "corrupt ICC colour profile: " + why;
  }
  return "";
}

// The byte ranges of a JPEG's segments that do not define its pixels: application data (APP1..APP13 and
// APP15: Exif, XMP, ICC profiles, IPTC) and comments. APP0 (JFIF) and APP14 (Adobe: colour transform) stay.
std::vector<std::pair<uint64_t, uint64_t>> jpeg_metadata(const Bytes& b) {
  std::vector<std::pair<uint64_t, uint64_t>> out;
  uint64_t p = 2;
  for (;;) {
    p = b.find(p, 0xff);
    while (b.has(p + 1, 1) && b[p + 1] == 0xff) ++p;
    if (!b.has(p, 4)) return out;
    const unsigned char marker = b[p + 1];
    if (marker == 0x01 || marker == 0xd8 || (marker >= 0xd0 && marker <= 0xd7)) {
      p += 2;
      continue;
    }
    if (marker == 0xd9 || marker == 0xda) return out;  // the entropy-coded data follows SOS: copied as is
    const uint64_t end = p + 2 + b.u(p + 2, 2, false);
    if ((marker >= 0xe1 && marker <= 0xed) || marker == 0xef || marker == 0xfe)
      out.emplace_back(p, std::min<uint64_t>(end, b.size()));
    p = end;
  }
}

// The byte ranges of a PNG's chunks other than those that define its pixels (checked complete by
// check_png_extent): text, Exif, ICC profile and any chunk unknown to the list below.
std::vector<std::pair<uint64_t, uint64_t>> png_metadata(const Bytes& b) {
  static const char* kept[] = {"IHDR", "PLTE", "tRNS", "IDAT", "IEND", "gAMA",
                               "cHRM", "sRGB", "sBIT", "bKGD", "pHYs"};
  std::vector<std::pair<uint64_t, uint64_t>> out;
  for (uint64_t p = 8; b.has(p, 8);) {
    const uint64_t end = p + 12 + b.u(p, 4, false);
    const std::string type{static_cast<char>(b[p + 4]), static_cast<char>(b[p + 5]), static_cast<char>(b[p + 6]),
                           static_cast<char>(b[p + 7])};
    if (std::none_of(std::begin(kept), std::end(kept), [&](const char* k) { return type == k; }))
      out.emplace_back(p, std::min<uint64_t>(end, b.size()));
    if (type == "IEND") break;
    p = end;
  }
  return out;
}

// The file's bytes without the ranges `drop` (sorted, disjoint); empty when nothing is dropped.
std::vector<unsigned char> without(const Bytes& b, const unsigned char* data,
                                   const std::vector<std::pair<uint64_t, uint64_t>>& drop) {
  std::vector<unsigned char> out;
  if (drop.empty()) return out;
  out.reserve(b.size());
  uint64_t from = 0;
  for (const auto& [begin, end] : drop) {
    out.insert(out.end(), data + from, data + begin);
    from = end;
  }
  out.insert(out.end(), data + from, data + b.size());
  return out;
}

}  // namespace

Image read_luminance(const std::string& path, ImageFileInfo* info) {
  std::error_code ec;
  const fs::file_status st = fs::status(path, ec);
  if (ec || !fs::exists(st)) throw InputError(path + ": image file not found");
  if (!fs::is_regular_file(st)) throw InputError(path + ": not a regular file");
  const uintmax_t size = fs::file_size(path, ec);
  if (ec) throw InputError(path + ": cannot read image file: " + ec.message());
  if (size == 0) throw InputError(path + ": image file is empty (0 bytes)");
  if (size > static_cast<uintmax_t>(kMaxImageFileBytes))
    throw InputError(path + ": image file too large (" + std::to_string(size) + " bytes; at most " +
                     std::to_string(kMaxImageFileBytes) + ")");
  std::vector<unsigned char> bytes(static_cast<size_t>(size));
  std::ifstream in(path, std::ios::binary);
  if (!in.read(reinterpret_cast<char*>(bytes.data()), static_cast<std::streamsize>(size)))
    throw InputError(path + ": cannot read image file (unreadable, or it changed while being read)");
  return decode_luminance(bytes.data(), bytes.size(), path, info);
}

Image decode_luminance(const unsigned char* data, size_t size, const std::string& source, ImageFileInfo* info) {
  if (size == 0) throw InputError(source + ": image file is empty (0 bytes)");
  const Bytes bytes(data, size);
  const char* sniffed = sniff_format(bytes);
  if (!sniffed)
    throw InputError(source + ": cannot read image (unrecognised format: not a PNG, JPEG, TIFF, OpenEXR or BMP "
                     "file)");
  const std::string format = sniffed;
  check_declared(format, bytes, source);
  // Truncation, checked before decoding (so a truncated file costs nothing): TIFF and OpenEXR readers
  // fill missing data with zeros instead of failing, and libpng's failure leaks inside OpenImageIO.
  if (format == "tiff" || format == "openexr" || format == "png") {
    const std::string why = format == "tiff" ? check_tiff_extent(bytes)
                            : format == "png" ? check_png_extent(bytes)
                                              : check_exr_extent(bytes);
    if (!why.empty()) throw InputError(source + ": truncated or corrupt " + format + " file: " + why);
  }
  if (format == "tiff") {
    const std::string why = check_tiff_icc_profile(bytes);
    if (!why.empty()) throw InputError(source + ": " + why);
  }
  const std::vector<unsigned char> pixels_only =
      format == "jpeg" ? without(bytes, data, jpeg_metadata(bytes))
      : format == "png" ? without(bytes, data, png_metadata(bytes))
                        : std::vector<unsigned char>();
  if (!pixels_only.empty()) {
    data = pixels_only.data();
    size = pixels_only.size();
  }

  // The reader of the recognised format only, reading from memory (the bytes checked above).
  OIIO::Filesystem::IOMemReader proxy(data, size);
  auto in = OIIO::ImageInput::create(format);
  OIIO::ImageSpec spec;
  if (!in || !in->set_ioproxy(&proxy) || !in->open(source, spec)) {
    const std::string why = one_line(in ? in->geterror() : OIIO::geterror());
    throw InputError(source + ": cannot read image (truncated or corrupt " + format + " file)" +
                     (why.empty() ? std::string() : ": " + why));
  }
  const int w = spec.width, h = spec.height, nc = spec.nchannels;
  check_image_size(w, h, nc, source);  // the decoder's view of the header may differ from ours
  if (spec.depth != 1) throw InputError(source + ": image is a volume (depth " + std::to_string(spec.depth) + ")");
  // Luminance needs at most the first four channels (RGB + alpha); reading no more bounds the buffer.
  const int read = std::min(nc, 4);
  std::vector<float> px(static_cast<size_t>(w) * h * read);
  bool ok = true;
  if (spec.tile_width > 0) {
    ok = in->read_image(0, 0, 0, read, OIIO::TypeDesc::FLOAT, px.data());
  } else {  // row by row: read_image stages every read in a 64 MiB buffer, however small the image
    std::vector<float> row(static_cast<size_t>(w) * nc);
    for (int r = 0; ok && r < h; ++r) {
      ok = in->read_scanline(spec.y + r, spec.z, OIIO::TypeDesc::FLOAT, row.data());
      for (size_t c = 0; ok && c < static_cast<size_t>(w); ++c)
        std::copy_n(&row[c * nc], read, &px[(static_cast<size_t>(r) * w + c) * read]);
    }
  }
  // JPEG reports a premature end of data as an error after a "successful" read: treat it as failure.
  const std::string err = one_line(in->geterror());
  const std::string format_name = in->format_name();
  in->close();
  if (!ok || !err.empty())
    throw InputError(source + ": cannot decode image (truncated or corrupt file)" + (err.empty() ? "" : ": " + err));

  // An alpha channel beyond the fourth is not read (and not used), nor is the only channel of an image.
  const int alpha_declared = spec.alpha_channel >= 0 ? spec.alpha_channel : (nc == 2 || nc == 4 ? nc - 1 : -1);
  const int alpha = alpha_declared < read && read > 1 ? alpha_declared : -1;
  const int colour = std::min(read - (alpha >= 0 ? 1 : 0), 3);  // grey = 1, RGB = 3
  const bool is_float = spec.format.basetype == OIIO::TypeDesc::FLOAT ||
                        spec.format.basetype == OIIO::TypeDesc::HALF ||
                        spec.format.basetype == OIIO::TypeDesc::DOUBLE;
  Image lum(h, w);
  double peak = 0.0;
  for (int r = 0; r < h; ++r)
    for (int c = 0; c < w; ++c) {
      const float* p = &px[(static_cast<size_t>(r) * w + c) * read];
      double l = 0.0;
      for (int k = 0; k < colour; ++k) l += p[k];
      l /= colour;
      if (!std::isfinite(l) || (alpha >= 0 && !std::isfinite(p[alpha])))
        throw InputError(source + ": image has non-finite pixel values (NaN or infinity) at row " +
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
        const double a = std::clamp<double>(px[(static_cast<size_t>(r) * w + c) * read + alpha], 0.0, 1.0);
        lum(r, c) = a * lum(r, c) + (1.0 - a);
      }
  if (info) *info = {w, h, nc, spec.format.c_str(), format_name};
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
  // Some writers (PNG through libpng) do not report a failed fwrite, so a full disk would leave a truncated file
  // that the rename puts in place of the old one: the temporary file is read back before it replaces anything.
  std::string unreadable;
  {
    auto in = OIIO::ImageInput::open(tmp.string());
    std::vector<float> back(px.size());
    if (!in) {
      unreadable = one_line(OIIO::geterror());
    } else {
      const OIIO::ImageSpec& got = in->spec();
      if (got.width != w || got.height != h || got.nchannels != channels ||
          !in->read_image(0, 0, 0, channels, OIIO::TypeDesc::FLOAT, back.data()))
        unreadable = one_line(in->geterror());
      in->close();
    }
  }
  std::error_code ec;
  if (!unreadable.empty()) {
    fs::remove(tmp, ec);
    throw InputError(path + ": cannot write image: the written file does not read back (disk full?): " + unreadable);
  }
  fs::rename(tmp, target, ec);
  if (ec) {
    fs::remove(tmp, ec);
    throw InputError(path + ": cannot write image: " + ec.message());
  }
}

}  // namespace drapelab
