#include "source_dir.hpp"

namespace drapelab::testing {

std::string source_dir() { return DRAPELAB_SOURCE_DIR; }

}  // namespace drapelab::testing
