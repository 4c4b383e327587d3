#include "measure/manifest.hpp"

#include <filesystem>
#include <fstream>
#include <limits>
#include <map>

#include "util/error.hpp"
#include "util/text.hpp"

namespace drapelab {

namespace fs = std::filesystem;

namespace {

// Splits one CSV record (RFC 4180 quoting, no embedded newlines).
bool split_csv(const std::string& line, std::vector<std::string>& out) {
  out.clear();
  std::string field;
  bool quoted = false, was_quoted = false;
  for (size_t i = 0; i < line.size(); ++i) {
    const char ch = line[i];
    if (quoted) {
      if (ch == '"' && i + 1 < line.size() && line[i + 1] == '"') field += '"', ++i;
      else if (ch == '"') quoted = false;
      else field += ch;
    } else if (ch == '"' && field.empty() && !was_quoted) {
      quoted = was_quoted = true;
    } else if (ch == ',') {
      out.push_back(field);
      field.clear();
      was_quoted = false;
    } else if (ch != '\r') {
      field += ch;
    }
  }
  out.push_back(field);
  return !quoted;
}

// The rows' text reaches Python as str: it must be UTF-8 (a manifest is a UTF-8 CSV file).
void check_utf8(const std::string& line, const std::string& where) {
  if (!valid_utf8(line))
    throw InputError(where + ": not UTF-8 text: " + printable(line));
}

}  // namespace

std::vector<ManifestEntry> read_manifest(const std::string& path, bool check_files) {
  std::ifstream in(path);
  if (!in) throw InputError(path + ": cannot open manifest (missing or unreadable)");
  return read_manifest(in, path, check_files);
}

std::vector<ManifestEntry> read_manifest(std::istream& in, const std::string& path, bool check_files) {
  const fs::path root = fs::path(path).parent_path();
  std::string line;
  std::vector<std::string> fields;
  if (!std::getline(in, line) || line.find_first_not_of(" \t\r") == std::string::npos)
    throw InputError(path + ": manifest is empty (no header row)");
  if (line.size() >= 3 && line.compare(0, 3, "\xEF\xBB\xBF") == 0) line.erase(0, 3);  // UTF-8 BOM
  check_utf8(line, path + ":1");
  split_csv(line, fields);
  std::map<std::string, size_t> column;
  for (size_t i = 0; i < fields.size(); ++i) column[fields[i]] = i;
  for (const char* required : {"fabric", "sample", "capture", "silhouette"})
    if (!column.count(required))
      throw InputError(path + ": manifest has no '" + required + "' column (header: " + printable(line, 200) + ")");

  std::vector<ManifestEntry> entries;
  long lineno = 1;
  while (std::getline(in, line)) {
    ++lineno;
    if (line.find_first_not_of(" \t\r") == std::string::npos) continue;
    const std::string where = path + ":" + std::to_string(lineno);
    check_utf8(line, where);
    if (!split_csv(line, fields)) throw InputError(where + ": unterminated quoted field");
    auto get = [&](const char* name) -> std::string {
      const auto it = column.find(name);
      return it == column.end() || it->second >= fields.size() ? std::string() : fields[it->second];
    };
    auto integer = [&](const char* name) {
      const std::string v = get(name);
      try {
        size_t used = 0;
        const int x = std::stoi(v, &used);
        if (used == v.size()) return x;
      } catch (const std::exception&) {
      }
      throw InputError(where + ": column '" + name + "' is not an integer: '" + printable(v) + "'");
    };
    auto real = [&](const char* name) {
      const std::string v = get(name);
      if (v.empty()) return std::numeric_limits<double>::quiet_NaN();
      try {
        size_t used = 0;
        const double x = std::stod(v, &used);
        if (used == v.size()) return x;
      } catch (const std::exception&) {
      }
      throw InputError(where + ": column '" + name + "' is not a number: '" + printable(v) + "'");
    };
    auto resolve = [&](const std::string& p) {
      if (p.empty()) return p;
      const fs::path fp(p);
      return (fp.is_absolute() ? fp : root / fp).lexically_normal().string();
    };
    ManifestEntry e;
    e.fabric = integer("fabric");
    e.name = get("name");
    e.material = get("material");
    e.weave = get("weave");
    e.density_kg_m2 = real("density_kg_m2");
    e.thickness_mm = real("thickness_mm");
    e.sample = integer("sample");
    e.capture = integer("capture");
    e.silhouette = resolve(get("silhouette"));
    e.mesh = resolve(get("mesh"));
    if (e.silhouette.empty()) throw InputError(where + ": empty 'silhouette' path");
    if (check_files) {
      // A path the system cannot look up (a name too long, a loop of links, no permission) is not found.
      auto found = [](const std::string& p) {
        std::error_code ec;
        return fs::exists(p, ec);
      };
      if (!found(e.silhouette))
        throw InputError(where + ": silhouette file not found: " + printable(e.silhouette, 300));
      if (!e.mesh.empty() && !found(e.mesh))
        throw InputError(where + ": mesh file not found: " + printable(e.mesh, 300));
    }
    entries.push_back(std::move(e));
  }
  return entries;
}

}  // namespace drapelab
