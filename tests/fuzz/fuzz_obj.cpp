// libFuzzer target: OBJ text through read_obj, validate_mesh and the model built on the mesh.
// Built by -DDRAPELAB_FUZZ=ON (build-fuzz); run by ./drapelab fuzz. See loader_inputs.hpp.
#include <cstddef>
#include <cstdint>

#include "loader_inputs.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  drapelab::fuzzing::obj_input(data, size);
  return 0;
}
