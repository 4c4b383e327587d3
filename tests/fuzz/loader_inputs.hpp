// One fuzz input through each loader of user files, called as the CLI and the add-on call it. A loader may
// accept the input or refuse it with InputError whose message is valid UTF-8 (the Python bindings decode it
// strictly); any other exception escapes (a finding), as does every crash, leak or undefined behaviour the
// sanitizers report, and a bad message aborts. Shared by the libFuzzer targets (fuzz_*.cpp)
// and the GoogleTest that replays their corpora and regression inputs (tests/native/test_fuzz_regressions.cpp).
#pragma once
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <sstream>
#include <string>

#include "geometry/mesh.hpp"
#include "geometry/obj.hpp"
#include "measure/calibration.hpp"
#include "measure/drape_measurement.hpp"
#include "measure/image_io.hpp"
#include "measure/manifest.hpp"
#include "measure/silhouette.hpp"
#include "physics/model.hpp"
#include "util/error.hpp"
#include "util/text.hpp"

namespace drapelab::fuzzing {

inline void check_message(const InputError& e) {
  const std::string message = e.what();
  if (!message.empty() && valid_utf8(message)) return;
  std::fprintf(stderr, "InputError with an empty or non-UTF-8 message: '%s'\n", printable(message, 500).c_str());
  std::abort();
}

// `drapelab measure IMG`: image file bytes -> luminance -> silhouette -> calibration check -> drape measures.
inline void image_input(const uint8_t* data, size_t size) {
  try {
    const Image luminance = decode_luminance(data, size, "fuzz.img");
    const Silhouette silhouette = extract_silhouette(luminance, Calibration{}, SilhouetteOptions{}, "fuzz.img");
    check_cusick_calibration(silhouette.mask, silhouette.calibration, "fuzz.img");
    measure_drape(silhouette);
  } catch (const InputError& e) {
    check_message(e);
  }
}

// An OBJ given to a fit or a simulation: text -> mesh -> validate_mesh (the Python facade's read_obj) ->
// the model built on it (validation again, orientation, bending edges, terms, sparsity pattern).
inline void obj_input(const uint8_t* data, size_t size) {
  std::istringstream in(std::string(reinterpret_cast<const char*>(data), size));
  try {
    const TriangleMesh mesh = read_obj(in, "fuzz.obj");
    validate_mesh(mesh);
    const Model model(mesh);
  } catch (const InputError& e) {
    check_message(e);
  }
}

// manifest.csv text -> rows, without and with the check that the files exist (relative paths resolve
// against a folder that does not exist).
inline void manifest_input(const uint8_t* data, size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  for (const bool check_files : {false, true}) {
    std::istringstream in(text);
    try {
      read_manifest(in, "/nonexistent-drapelab-fuzz/manifest.csv", check_files);
    } catch (const InputError& e) {
      check_message(e);
    }
  }
}

}  // namespace drapelab::fuzzing
