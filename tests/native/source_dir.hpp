// The repository's folder for the C++ tests (assets, fuzz corpora, ../shared beside it).
#pragma once
#include <string>

namespace drapelab::testing {

// Compiled into source_dir.cpp only: its absolute path differs from clone to clone, so keeping it out of every
// other test file lets a second clone's build (CI's clean-clone stage) take them from ccache.
std::string source_dir();

}  // namespace drapelab::testing
