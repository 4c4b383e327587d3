#include "geometry/obj.hpp"

#include <cstdio>
#include <fstream>
#include <iomanip>
#include <sstream>
#include <vector>

#include "util/error.hpp"
#include "util/text.hpp"

namespace drapelab {

namespace {
// Parses "i", "i/j", "i//k", "i/j/k" -> (vertex index, texcoord index or 0). 1-based, negatives relative.
bool parse_face_vertex(const std::string& tok, long nv, long nvt, long& vi, long& ti) {
  ti = 0;
  const size_t s1 = tok.find('/');
  try {
    vi = std::stol(tok.substr(0, s1));
    if (s1 != std::string::npos) {
      const size_t s2 = tok.find('/', s1 + 1);
      const std::string t = tok.substr(s1 + 1, s2 == std::string::npos ? std::string::npos : s2 - s1 - 1);
      if (!t.empty()) ti = std::stol(t);
    }
  } catch (...) {
    return false;
  }
  if (vi < 0) vi = nv + vi + 1;
  if (ti < 0) ti = nvt + ti + 1;
  return true;
}
}  // namespace

TriangleMesh read_obj(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw InputError(path + ": cannot open OBJ file");
  return read_obj(in, path);
}

TriangleMesh read_obj(std::istream& in, const std::string& source) {
  std::vector<Eigen::Vector3d> v;
  std::vector<Eigen::Vector2d> vt;
  std::vector<Eigen::Vector3i> f;
  std::string line;
  long lineno = 0;
  while (std::getline(in, line)) {
    ++lineno;
    std::istringstream ls(line);
    std::string tag;
    if (!(ls >> tag)) continue;
    if (tag == "v") {
      Eigen::Vector3d p;
      if (!(ls >> p.x() >> p.y() >> p.z()))
        throw InputError(source + ":" + std::to_string(lineno) + ": malformed vertex line");
      v.push_back(p);
    } else if (tag == "vt") {
      Eigen::Vector2d t;
      if (!(ls >> t.x() >> t.y()))
        throw InputError(source + ":" + std::to_string(lineno) + ": malformed texture coordinate line");
      vt.push_back(t);
    } else if (tag == "f") {
      std::vector<long> idx;
      std::string tok;
      while (ls >> tok) {
        long vi, ti;
        if (!parse_face_vertex(tok, static_cast<long>(v.size()), static_cast<long>(vt.size()), vi, ti))
          throw InputError(source + ":" + std::to_string(lineno) + ": malformed face entry '" + printable(tok) + "'");
        if (vi < 1 || vi > static_cast<long>(v.size()))
          throw InputError(source + ":" + std::to_string(lineno) + ": face refers to missing vertex " +
                           std::to_string(vi));
        idx.push_back(vi - 1);
      }
      if (idx.size() < 3) throw InputError(source + ":" + std::to_string(lineno) + ": face with fewer than 3 vertices");
      for (size_t k = 1; k + 1 < idx.size(); ++k) {
        f.emplace_back(idx[0], idx[k], idx[k + 1]);
      }
    }
  }
  if (v.empty()) throw InputError(source + ": OBJ file has no vertices (empty or not an OBJ)");
  if (f.empty()) throw InputError(source + ": OBJ file has no faces");
  TriangleMesh mesh;
  mesh.positions.resize(static_cast<Eigen::Index>(v.size()), 3);
  for (size_t i = 0; i < v.size(); ++i) mesh.positions.row(static_cast<Eigen::Index>(i)) = v[i].transpose();
  mesh.faces.resize(static_cast<Eigen::Index>(f.size()), 3);
  for (size_t i = 0; i < f.size(); ++i) mesh.faces.row(static_cast<Eigen::Index>(i)) = f[i].transpose();
  // The rest pattern of a flat specimen is its (x, y); `vt` is written for tools but not read back as
  // metres (texture space is unitless). Garments with their own patterns come with the garment module.
  mesh.uv = mesh.positions.leftCols<2>();
  return mesh;
}

void write_obj(const std::string& path, const MatrixX3d& positions, const MatrixX3i& faces, const MatrixX2d* uv) {
  const std::string tmp = path + ".tmp";
  {
    std::ofstream out(tmp);
    if (!out) throw InputError(path + ": cannot write OBJ file (directory missing or not writable)");
    out << std::setprecision(12);
    out << "# drapelab " << DRAPELAB_VERSION << "\n";
    for (Eigen::Index i = 0; i < positions.rows(); ++i)
      out << "v " << positions(i, 0) << ' ' << positions(i, 1) << ' ' << positions(i, 2) << '\n';
    if (uv)
      for (Eigen::Index i = 0; i < uv->rows(); ++i) out << "vt " << (*uv)(i, 0) << ' ' << (*uv)(i, 1) << '\n';
    for (Eigen::Index i = 0; i < faces.rows(); ++i) {
      out << 'f';
      for (int k = 0; k < 3; ++k) {
        out << ' ' << faces(i, k) + 1;
        if (uv) out << '/' << faces(i, k) + 1;
      }
      out << '\n';
    }
    out.close();  // the last buffer is written here: a full disk shows only now
    if (!out) {
      std::remove(tmp.c_str());  // never leave a half-written file behind
      throw InputError(path + ": write failed (disk full?)");
    }
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0) {
    std::remove(tmp.c_str());
    throw InputError(path + ": cannot move the written OBJ into place");
  }
}

}  // namespace drapelab
