// libFuzzer target: an image file's bytes through the CLI's import path (decode, silhouette, calibration check, drape measures).
// Built by -DDRAPELAB_FUZZ=ON (build-fuzz); run by ./drapelab fuzz. See loader_inputs.hpp.
#include <cstddef>
#include <cstdint>

#include "loader_inputs.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  drapelab::fuzzing::image_input(data, size);
  return 0;
}
