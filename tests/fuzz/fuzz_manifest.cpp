// libFuzzer target: manifest.csv text through read_manifest (without and with checking that the files exist).
// Built by -DDRAPELAB_FUZZ=ON (build-fuzz); run by ./drapelab fuzz. See loader_inputs.hpp.
#include <cstddef>
#include <cstdint>

#include "loader_inputs.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  drapelab::fuzzing::manifest_input(data, size);
  return 0;
}
