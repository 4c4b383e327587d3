// The fuzz targets' inputs replayed in the normal build: every seed (tests/fuzz/corpus/<target>) and every
// input that once crashed a loader (tests/fuzz/regressions/<target>) goes through the same harness as the
// libFuzzer targets (tests/fuzz/loader_inputs.hpp): it loads or raises InputError with a readable message.
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#include "../fuzz/loader_inputs.hpp"
#include "source_dir.hpp"

namespace {

namespace fs = std::filesystem;

// Files of tests/fuzz/<kind>/<target>, sorted; none when the folder does not exist.
std::vector<fs::path> inputs(const std::string& kind, const std::string& target) {
  const fs::path folder = fs::path(drapelab::testing::source_dir()) / "tests" / "fuzz" / kind / target;
  std::vector<fs::path> files;
  if (fs::is_directory(folder))
    for (const auto& entry : fs::directory_iterator(folder))
      if (entry.is_regular_file()) files.push_back(entry.path());
  std::sort(files.begin(), files.end());
  return files;
}

template <class Harness>
void replay(const std::string& target, Harness harness) {
  EXPECT_FALSE(inputs("corpus", target).empty()) << "no seed corpus for fuzz_" << target;
  for (const std::string kind : {"corpus", "regressions"})
    for (const fs::path& file : inputs(kind, target)) {
      std::ifstream in(file, std::ios::binary);
      const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
      SCOPED_TRACE(file.string());
      EXPECT_NO_THROW(harness(reinterpret_cast<const uint8_t*>(bytes.data()), bytes.size()));
    }
}

}  // namespace

TEST(FuzzRegressions, ImageInputsLoadOrRaiseInputError) { replay("image", drapelab::fuzzing::image_input); }
TEST(FuzzRegressions, ObjInputsLoadOrRaiseInputError) { replay("obj", drapelab::fuzzing::obj_input); }
TEST(FuzzRegressions, ManifestInputsLoadOrRaiseInputError) { replay("manifest", drapelab::fuzzing::manifest_input); }
