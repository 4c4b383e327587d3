// Shared helpers of the measure/ tests: synthetic silhouettes, temporary files, data locations.
#pragma once
#include <gtest/gtest.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <initializer_list>
#include <string>
#include <unistd.h>

#include "../test_support.hpp"
#include "util/error.hpp"
#include "util/image.hpp"

namespace drapelab::measure_testing {

inline constexpr double kPi = 3.14159265358979323846;

// Binary mask of the star-shaped region r < radius_m(theta) about (cx, cy) under s px/m, sampled at pixel
// centres (the same convention as the hard rasterizer): theta counter-clockwise from +x, +y up.
inline Image polar_mask(int h, int w, double px_per_m, double cx, double cy,
                        const std::function<double(double)>& radius_m) {
  Image m = Image::Zero(h, w);
  for (int r = 0; r < h; ++r)
    for (int c = 0; c < w; ++c) {
      const double x = (c + 0.5 - cx) / px_per_m, y = (cy - (r + 0.5)) / px_per_m;
      if (std::hypot(x, y) < radius_m(std::atan2(y, x))) m(r, c) = 1.0;
    }
  return m;
}

inline Image disk_mask(double radius_m, double px_per_m = 720.0, int size = 256) {
  return polar_mask(size, size, px_per_m, size / 2.0, size / 2.0, [=](double) { return radius_m; });
}

// A fresh temporary folder, removed at the end of the test.
class TempDir {
 public:
  TempDir() {
    std::string tmpl = (std::filesystem::temp_directory_path() / "drapelab_measure_XXXXXX").string();
    if (!mkdtemp(tmpl.data())) throw std::runtime_error("mkdtemp failed");
    path_ = tmpl;
  }
  ~TempDir() {
    std::error_code ec;
    std::filesystem::remove_all(path_, ec);
  }
  std::string file(const std::string& name) const { return (path_ / name).string(); }

 private:
  std::filesystem::path path_;
};

inline std::string asset(const std::string& rel) { return drapelab::testing::source_dir() + "/assets/" + rel; }

using drapelab::testing::kNoDatasetReason;
// The shared dataset (test_support.hpp's one locator). "" if absent.
inline std::string cusick_dir() { return drapelab::testing::cusick_dataset_dir(); }

inline void copy_prefix(const std::string& from, const std::string& to, double fraction) {
  std::ifstream in(from, std::ios::binary);
  std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  std::ofstream(to, std::ios::binary) << bytes.substr(0, static_cast<size_t>(fraction * bytes.size()));
}

// Runs f, expects an InputError whose message contains every one of `parts`.
template <class F>
void expect_input_error(F&& f, std::initializer_list<std::string> parts) {
  try {
    f();
    ADD_FAILURE() << "expected InputError";
  } catch (const InputError& e) {
    const std::string msg = e.what();
    for (const auto& p : parts) EXPECT_NE(msg.find(p), std::string::npos) << "'" << p << "' not in: " << msg;
  } catch (const std::exception& e) {
    ADD_FAILURE() << "expected InputError, got another exception: " << e.what();
  }
}

}  // namespace drapelab::measure_testing
