#include "measure/silhouette.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <vector>

#include "measure/image_io.hpp"
#include "util/error.hpp"

namespace drapelab {

namespace {

std::string fmt(double v, int digits = 1) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.*f", digits, v);
  return buf;
}

// Connected components of the pixels where `inside(r, c)` holds; returns labels (-1 = not inside) and
// the size of each component. 8- or 4-connected.
struct Components {
  std::vector<int> label;
  std::vector<long> size;
  std::vector<bool> touches_border;
};

template <class Inside>
Components label_components(int h, int w, bool eight, Inside inside) {
  Components out;
  out.label.assign(static_cast<size_t>(h) * w, -1);
  std::vector<int> stack;
  static const std::array<int, 16> n8 = {-1, -1, -1, 0, -1, 1, 0, -1, 0, 1, 1, -1, 1, 0, 1, 1};
  static const std::array<int, 8> n4 = {-1, 0, 1, 0, 0, -1, 0, 1};
  const int count = eight ? 8 : 4;
  for (int r0 = 0; r0 < h; ++r0)
    for (int c0 = 0; c0 < w; ++c0) {
      const size_t i0 = static_cast<size_t>(r0) * w + c0;
      if (out.label[i0] >= 0 || !inside(r0, c0)) continue;
      const int id = static_cast<int>(out.size.size());
      out.size.push_back(0);
      out.touches_border.push_back(false);
      out.label[i0] = id;
      stack.assign(1, static_cast<int>(i0));
      while (!stack.empty()) {
        const int i = stack.back();
        stack.pop_back();
        const int r = i / w, c = i % w;
        ++out.size[id];
        if (r == 0 || c == 0 || r == h - 1 || c == w - 1) out.touches_border[id] = true;
        for (int k = 0; k < count; ++k) {
          const int rr = r + (eight ? n8[2 * k] : n4[2 * k]), cc = c + (eight ? n8[2 * k + 1] : n4[2 * k + 1]);
          if (rr < 0 || cc < 0 || rr >= h || cc >= w) continue;
          const size_t j = static_cast<size_t>(rr) * w + cc;
          if (out.label[j] >= 0 || !inside(rr, cc)) continue;
          out.label[j] = id;
          stack.push_back(static_cast<int>(j));
        }
      }
    }
  return out;
}

double percentile(std::vector<double> v, double q) {
  const size_t k = std::min(v.size() - 1, static_cast<size_t>(q * static_cast<double>(v.size() - 1) + 0.5));
  std::nth_element(v.begin(), v.begin() + static_cast<long>(k), v.end());
  return v[k];
}

}  // namespace

double automatic_threshold(const Image& values) {
  constexpr int kBins = 256;
  std::array<double, kBins> hist{};
  const double n = static_cast<double>(values.size());
  if (n == 0) throw InputError("automatic_threshold: empty image");
  for (Eigen::Index i = 0; i < values.size(); ++i) {
    const double v = std::clamp(values.data()[i], 0.0, 1.0);
    ++hist[std::min(kBins - 1, static_cast<int>(v * kBins))];
  }
  // Otsu: maximise the between-class variance w0 w1 (mu0 - mu1)^2 over thresholds k / kBins.
  double total_mean = 0;
  for (int k = 0; k < kBins; ++k) total_mean += hist[k] / n * (k + 0.5) / kBins;
  double w0 = 0, m0 = 0, best = -1, t = 0.5;
  for (int k = 1; k < kBins; ++k) {
    w0 += hist[k - 1] / n;
    m0 += hist[k - 1] / n * (k - 0.5) / kBins;
    if (w0 <= 0 || w0 >= 1) continue;
    const double d = total_mean * w0 - m0, sb = d * d / (w0 * (1 - w0));
    if (sb > best) best = sb, t = static_cast<double>(k) / kBins;
  }
  // ISODATA refinement on the exact values: the midpoint of the two class means. On a flat-bottomed
  // histogram (a clean silhouette) Otsu's optimum is ill-defined; this fixed point is not.
  for (int it = 0; it < 100; ++it) {
    double s0 = 0, s1 = 0;
    long c0 = 0, c1 = 0;
    for (Eigen::Index i = 0; i < values.size(); ++i) {
      const double v = values.data()[i];
      if (v <= t) s0 += v, ++c0;
      else s1 += v, ++c1;
    }
    if (c0 == 0 || c1 == 0) break;
    const double next = 0.5 * (s0 / c0 + s1 / c1);
    const bool done = std::abs(next - t) < 1e-7;
    t = next;
    if (done) break;
  }
  return t;
}

Silhouette extract_silhouette(const Image& luminance, const Calibration& calibration,
                              const SilhouetteOptions& options, const std::string& source) {
  const int h = static_cast<int>(luminance.rows()), w = static_cast<int>(luminance.cols());
  if (h < 3 || w < 3)
    throw InputError(source + ": image too small for a silhouette (" + std::to_string(w) + "x" +
                     std::to_string(h) + " pixels)");
  if (!luminance.allFinite()) throw InputError(source + ": image has non-finite values");
  if (!(options.threshold < 0) && !(options.threshold > 0 && options.threshold < 1))
    throw InputError(source + ": threshold must lie in (0, 1) (or be negative for automatic), got " +
                     fmt(options.threshold, 3));
  Silhouette out;
  out.source = source;
  out.calibration = resolve_calibration(calibration, w, h, source);
  const double cx = out.calibration.cx, cy = out.calibration.cy;
  const double support_px = options.geometry.support_radius * out.calibration.px_per_m;

  const std::vector<double> all(luminance.data(), luminance.data() + luminance.size());
  const double lo = percentile(all, 0.001), hi = percentile(all, 0.999);
  if (hi - lo < options.min_contrast) {
    const double mean = luminance.mean();
    throw InputError(source + ": image has no contrast (" +
                     (mean < 0.25 ? "all dark" : mean > 0.75 ? "all light" : "uniform grey") +
                     ", luminance 0.1-99.9th percentile " + fmt(lo, 3) + "-" + fmt(hi, 3) +
                     "): no silhouette to extract");
  }

  // Polarity: the image border is background. When the border is mixed, the centre (on the support
  // disk, always covered) is cloth.
  if (options.polarity == Polarity::Auto) {
    const double tl = automatic_threshold(luminance);
    const int band = std::max(1, std::min(w, h) / 64);
    long bright = 0, count = 0;
    for (int r = 0; r < h; ++r)
      for (int c = 0; c < w; ++c)
        if (r < band || c < band || r >= h - band || c >= w - band) {
          ++count;
          bright += luminance(r, c) > tl;
        }
    const double frac = static_cast<double>(bright) / static_cast<double>(count);
    if (frac >= 0.65) out.dark_on_light = true;
    else if (frac <= 0.35) out.dark_on_light = false;
    else {
      const double rad = std::max(2.0, 0.5 * support_px);
      // Clamped to the image in floating point: a huge scale (px/m) puts the disk's bounds beyond int.
      const int r_begin = static_cast<int>(std::max(0.0, cy - rad));
      const int r_end = static_cast<int>(std::min(h - 1.0, cy + rad));
      const int c_begin = static_cast<int>(std::max(0.0, cx - rad));
      const int c_end = static_cast<int>(std::min(w - 1.0, cx + rad));
      long cbright = 0, ccount = 0;
      for (int r = r_begin; r <= r_end; ++r)
        for (int c = c_begin; c <= c_end; ++c)
          if (std::hypot(c + 0.5 - cx, r + 0.5 - cy) <= rad) {
            ++ccount;
            cbright += luminance(r, c) > tl;
          }
      out.dark_on_light = ccount == 0 || 2 * cbright < ccount;
    }
  } else {
    out.dark_on_light = options.polarity == Polarity::DarkOnLight;
  }
  out.cloth_value = out.dark_on_light ? Image(1.0 - luminance) : luminance;
  out.threshold = options.threshold > 0 ? options.threshold : automatic_threshold(out.cloth_value);

  Image mask = (out.cloth_value > out.threshold).cast<double>();
  const long fg = static_cast<long>(mask.sum());
  if (fg == 0)
    throw InputError(source + ": no cloth pixels above the threshold " + fmt(out.threshold, 3));
  if (fg == static_cast<long>(mask.size()))
    throw InputError(source + ": every pixel is above the threshold " + fmt(out.threshold, 3) +
                     ": no background, no silhouette");

  if (options.keep_central_region) {
    const Components fgc = label_components(h, w, true, [&](int r, int c) { return mask(r, c) > 0.5; });
    int keep = -1;
    const int r0 = static_cast<int>(std::floor(cy)), c0 = static_cast<int>(std::floor(cx));
    if (r0 >= 0 && r0 < h && c0 >= 0 && c0 < w) keep = fgc.label[static_cast<size_t>(r0) * w + c0];
    if (keep < 0) {
      std::vector<long> near(fgc.size.size(), 0);
      for (int r = 0; r < h; ++r)
        for (int c = 0; c < w; ++c) {
          const int l = fgc.label[static_cast<size_t>(r) * w + c];
          if (l >= 0 && std::hypot(c + 0.5 - cx, r + 0.5 - cy) <= support_px) ++near[l];
        }
      const auto it = std::max_element(near.begin(), near.end());
      if (it != near.end() && *it > 0) keep = static_cast<int>(it - near.begin());
    }
    if (keep < 0)
      throw InputError(source + ": no specimen region at the centre: no cloth within the support-disk radius (" +
                       fmt(support_px) + " px) of (" + fmt(cx) + ", " + fmt(cy) +
                       "); check the image and the calibration centre");
    for (int r = 0; r < h; ++r)
      for (int c = 0; c < w; ++c)
        if (mask(r, c) > 0.5 && fgc.label[static_cast<size_t>(r) * w + c] != keep) {
          mask(r, c) = 0;
          ++out.specks_removed_px;
        }
  }

  if (options.max_hole_fraction > 0) {
    const double region = mask.sum();
    const Components bgc = label_components(h, w, false, [&](int r, int c) { return mask(r, c) < 0.5; });
    for (int r = 0; r < h; ++r)
      for (int c = 0; c < w; ++c) {
        const int l = bgc.label[static_cast<size_t>(r) * w + c];
        if (l >= 0 && !bgc.touches_border[l] &&
            static_cast<double>(bgc.size[l]) <= options.max_hole_fraction * region) {
          mask(r, c) = 1;
          ++out.holes_filled_px;
        }
      }
  }
  out.mask = std::move(mask);
  return out;
}

Silhouette load_silhouette(const std::string& path, const Calibration& calibration,
                           const SilhouetteOptions& options) {
  return extract_silhouette(read_luminance(path), calibration, options, path);
}

}  // namespace drapelab
