// Small meshes for the contact tests: a square grid sheet and an icosphere.
#pragma once
#include <Eigen/Core>
#include <map>
#include <random>
#include <utility>

#include "contact/diagnostics.hpp"
#include "geometry/mesh.hpp"

namespace drapelab::testing {

// n x n vertices over [-size/2, size/2]^2 at height z (uv = xy).
inline TriangleMesh grid_mesh(int n, double size, double z = 0.0) {
  TriangleMesh m;
  m.positions.resize(n * n, 3);
  m.uv.resize(n * n, 2);
  for (int j = 0; j < n; ++j)
    for (int i = 0; i < n; ++i) {
      const double u = size * (double(i) / (n - 1) - 0.5), v = size * (double(j) / (n - 1) - 0.5);
      m.positions.row(j * n + i) << u, v, z;
      m.uv.row(j * n + i) << u, v;
    }
  m.faces.resize(2 * (n - 1) * (n - 1), 3);
  int f = 0;
  for (int j = 0; j + 1 < n; ++j)
    for (int i = 0; i + 1 < n; ++i) {
      const int a = j * n + i, b = a + 1, c = a + n, d = c + 1;
      m.faces.row(f++) << a, b, d;
      m.faces.row(f++) << a, d, c;
    }
  return m;
}

inline ObstacleMesh icosphere(int subdivisions, double radius, const Eigen::Vector3d& centre) {
  const double t = (1.0 + std::sqrt(5.0)) / 2.0;
  std::vector<Eigen::Vector3d> v = {{-1, t, 0}, {1, t, 0}, {-1, -t, 0}, {1, -t, 0}, {0, -1, t}, {0, 1, t},
                                    {0, -1, -t}, {0, 1, -t}, {t, 0, -1}, {t, 0, 1}, {-t, 0, -1}, {-t, 0, 1}};
  std::vector<std::array<int, 3>> f = {{0, 11, 5}, {0, 5, 1}, {0, 1, 7}, {0, 7, 10}, {0, 10, 11}, {1, 5, 9}, {5, 11, 4},
                                       {11, 10, 2}, {10, 7, 6}, {7, 1, 8}, {3, 9, 4}, {3, 4, 2}, {3, 2, 6}, {3, 6, 8},
                                       {3, 8, 9}, {4, 9, 5}, {2, 4, 11}, {6, 2, 10}, {8, 6, 7}, {9, 8, 1}};
  for (auto& p : v) p.normalize();
  for (int s = 0; s < subdivisions; ++s) {
    std::map<std::pair<int, int>, int> mid;
    auto midpoint = [&](int a, int b) {
      const auto key = std::minmax(a, b);
      const auto it = mid.find(key);
      if (it != mid.end()) return it->second;
      v.push_back((v[a] + v[b]).normalized());
      return mid[key] = static_cast<int>(v.size()) - 1;
    };
    std::vector<std::array<int, 3>> g;
    for (const auto& q : f) {
      const int a = midpoint(q[0], q[1]), b = midpoint(q[1], q[2]), c = midpoint(q[2], q[0]);
      g.push_back({q[0], a, c});
      g.push_back({q[1], b, a});
      g.push_back({q[2], c, b});
      g.push_back({a, b, c});
    }
    f = g;
  }
  ObstacleMesh m;
  m.positions.resize(v.size(), 3);
  for (size_t i = 0; i < v.size(); ++i) m.positions.row(i) = (centre + radius * v[i]).transpose();
  m.faces.resize(f.size(), 3);
  for (size_t i = 0; i < f.size(); ++i) m.faces.row(i) << f[i][0], f[i][1], f[i][2];
  return m;
}

}  // namespace drapelab::testing
