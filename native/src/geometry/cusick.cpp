#include "geometry/cusick.hpp"

#include <cmath>
#include <fstream>

#include "geometry/obj.hpp"
#include "util/error.hpp"

namespace drapelab {

int cusick_template_vertices(int level) {
  static const int counts[] = {297, 1205, 2699, 4766, 7496};
  if (level < 1 || level > 5) throw InputError("Cusick template level must be 1..5, got " + std::to_string(level));
  return counts[level - 1];
}

TriangleMesh make_cusick_specimen(int target_vertices, const CusickGeometry& g) {
  if (target_vertices < 7) throw InputError("Cusick specimen: need at least 7 vertices");
  if (!(g.specimen_radius > g.support_radius && g.support_radius > 0))
    throw InputError("Cusick specimen: need 0 < support radius < specimen radius");
  // Rings k = 1..K hold about 2*pi*k vertices each: 1 + pi K (K + 1) ~= target.
  const int K = std::max(1, static_cast<int>(std::lround((-M_PI + std::sqrt(M_PI * M_PI + 4 * M_PI * (target_vertices - 1))) / (2 * M_PI))));
  // Ring sizes ~ 2 pi k, then adjusted one vertex per ring (outermost first) to hit the target exactly.
  std::vector<int> ring_size(K + 1, 1);
  int total = 1;
  for (int k = 1; k <= K; ++k) {
    ring_size[k] = std::max(6, static_cast<int>(std::lround(2 * M_PI * k)));
    total += ring_size[k];
  }
  for (int pass = 0; total != target_vertices && pass < 8; ++pass)
    for (int k = K; k >= 1 && total != target_vertices; --k) {
      const int step = total < target_vertices ? 1 : -1;
      if (ring_size[k] + step < 6) continue;
      ring_size[k] += step;
      total += step;
    }
  std::vector<std::vector<int>> rings(K + 1);
  std::vector<Eigen::Vector2d> pts;
  pts.emplace_back(0.0, 0.0);
  rings[0] = {0};
  for (int k = 1; k <= K; ++k) {
    const int n = ring_size[k];
    const double r = g.specimen_radius * k / K;
    const double offset = (k % 2) * M_PI / n;  // stagger rings for better triangles
    for (int i = 0; i < n; ++i) {
      const double t = offset + 2 * M_PI * i / n;
      rings[k].push_back(static_cast<int>(pts.size()));
      pts.emplace_back(r * std::cos(t), r * std::sin(t));
    }
  }
  std::vector<Eigen::Vector3i> faces;
  // Ring 0 -> 1: a fan.
  for (size_t i = 0; i < rings[1].size(); ++i)
    faces.emplace_back(0, rings[1][i], rings[1][(i + 1) % rings[1].size()]);
  // Ring k -> k+1: zip the two rings by increasing angle (each ring starts within half a spacing of 0).
  for (int k = 1; k < K; ++k) {
    const auto& in = rings[k];
    const auto& out = rings[k + 1];
    const int ni = static_cast<int>(in.size()), no = static_cast<int>(out.size());
    const double off_in = (k % 2) * M_PI / ni, off_out = ((k + 1) % 2) * M_PI / no;
    int i = 0, o = 0;
    while (i < ni || o < no) {
      const double next_in = off_in + 2 * M_PI * (i + 1) / ni;
      const double next_out = off_out + 2 * M_PI * (o + 1) / no;
      if (o == no || (i < ni && next_in < next_out)) {
        faces.emplace_back(in[i % ni], out[o % no], in[(i + 1) % ni]);
        ++i;
      } else {
        faces.emplace_back(in[i % ni], out[o % no], out[(o + 1) % no]);
        ++o;
      }
    }
  }
  TriangleMesh mesh;
  mesh.positions.setZero(static_cast<Eigen::Index>(pts.size()), 3);
  mesh.uv.resize(static_cast<Eigen::Index>(pts.size()), 2);
  for (size_t i = 0; i < pts.size(); ++i) {
    mesh.positions(static_cast<Eigen::Index>(i), 0) = pts[i].x();
    mesh.positions(static_cast<Eigen::Index>(i), 1) = pts[i].y();
    mesh.uv.row(static_cast<Eigen::Index>(i)) = pts[i].transpose();
  }
  mesh.faces.resize(static_cast<Eigen::Index>(faces.size()), 3);
  for (size_t i = 0; i < faces.size(); ++i) mesh.faces.row(static_cast<Eigen::Index>(i)) = faces[i].transpose();
  orient_faces_ccw(mesh);
  return mesh;
}

TriangleMesh load_cusick_template(int level, const std::string& template_dir) {
  const int n = cusick_template_vertices(level);
  const std::string path = template_dir + "/circle" + std::to_string(level) + ".obj";
  if (template_dir.empty() || !std::ifstream(path).good())
    throw InputError("Cusick template circle" + std::to_string(level) + ": cannot read " + path);
  TriangleMesh m = read_obj(path);
  if (m.num_vertices() != n)
    throw InputError("Cusick template " + path + ": expected " + std::to_string(n) + " vertices, got " +
                     std::to_string(m.num_vertices()));
  orient_faces_ccw(m);
  return m;
}

}  // namespace drapelab
