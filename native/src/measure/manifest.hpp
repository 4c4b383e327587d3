// Loader for `manifest.csv` datasets (the layout of ../shared/data/cusick): one row per silhouette.
//
// Columns (by header name, any order; extra columns are ignored):
//   required: fabric, sample, capture, silhouette
//   optional: name, material, weave, density_kg_m2 (kg/m^2), thickness_mm (mm), mesh (empty when absent)
// Relative paths are resolved against the manifest's folder. Fields may be quoted ("a, b"; "" escapes ").
#pragma once
#include <istream>
#include <string>
#include <vector>

namespace drapelab {

struct ManifestEntry {
  int fabric = 0;
  std::string name, material, weave;
  double density_kg_m2 = 0.0;   // NaN when the column is absent or empty
  double thickness_mm = 0.0;    // NaN when the column is absent or empty
  int sample = 0;
  int capture = 0;
  std::string silhouette;       // path of the silhouette image (resolved)
  std::string mesh;             // path of the 3D reconstruction (resolved), empty when absent
};

// Reads the manifest. Throws InputError naming the file (and line) for a missing file, a missing
// required column, a malformed number, or (when check_files) a silhouette or mesh file that does not exist.
std::vector<ManifestEntry> read_manifest(const std::string& path, bool check_files = false);

// The same from a stream of CSV text; `path` names it in error messages and its folder resolves relative paths.
std::vector<ManifestEntry> read_manifest(std::istream& in, const std::string& path, bool check_files = false);

}  // namespace drapelab
