#include "contact/broad_phase.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>

namespace drapelab {

namespace {

struct Box {
  Eigen::Array3d lo, hi;
};

template <size_t K>
Box primitive_box(const std::array<int, K>& v, const ContactPositions& x0, const ContactPositions* x1, double pad) {
  Box b;
  b.lo = x0.row(v[0]).transpose().array();
  b.hi = b.lo;
  for (size_t k = 0; k < K; ++k) {
    b.lo = b.lo.min(x0.row(v[k]).transpose().array());
    b.hi = b.hi.max(x0.row(v[k]).transpose().array());
    if (x1) {
      b.lo = b.lo.min(x1->row(v[k]).transpose().array());
      b.hi = b.hi.max(x1->row(v[k]).transpose().array());
    }
  }
  b.lo -= pad;
  b.hi += pad;
  return b;
}

bool overlap(const Box& a, const Box& b) { return (a.lo <= b.hi).all() && (b.lo <= a.hi).all(); }

template <size_t K, size_t L>
bool share_vertex(const std::array<int, K>& a, const std::array<int, L>& b) {
  for (int u : a)
    for (int w : b)
      if (u == w) return true;
  return false;
}

bool keep(PairFilter f, int group_a, int group_b) {
  switch (f) {
    case PairFilter::kSelf: return group_a == 0 && group_b == 0;
    case PairFilter::kCross: return group_a != group_b;
    case PairFilter::kAll: break;
  }
  return true;
}

// Uniform grid: cell keys of boxes, binned by sorting (key, primitive) entries.
class HashGrid {
 public:
  HashGrid(const Eigen::Array3d& origin, double cell) : origin_(origin), inv_(1.0 / cell) {}
  Eigen::Array3i cell_of(const Eigen::Array3d& p) const {
    return ((p - origin_) * inv_).floor().cast<int>().max(0).min(kMaxCell);
  }
  static uint64_t key(int i, int j, int k) {
    return (static_cast<uint64_t>(i) << 42) | (static_cast<uint64_t>(j) << 21) | static_cast<uint64_t>(k);
  }
  void insert(const Box& b, int id) {
    const Eigen::Array3i lo = cell_of(b.lo), hi = cell_of(b.hi);
    for (int i = lo[0]; i <= hi[0]; ++i)
      for (int j = lo[1]; j <= hi[1]; ++j)
        for (int k = lo[2]; k <= hi[2]; ++k) entries_.push_back({key(i, j, k), id});
  }
  void finish() { std::sort(entries_.begin(), entries_.end()); }
  // Ids binned in any cell of the box, deduplicated into `out`.
  void query(const Box& b, std::vector<int>& out) const {
    out.clear();
    const Eigen::Array3i lo = cell_of(b.lo), hi = cell_of(b.hi);
    for (int i = lo[0]; i <= hi[0]; ++i)
      for (int j = lo[1]; j <= hi[1]; ++j)
        for (int k = lo[2]; k <= hi[2]; ++k) {
          const uint64_t c = key(i, j, k);
          auto it = std::lower_bound(entries_.begin(), entries_.end(), std::pair<uint64_t, int>{c, -1});
          for (; it != entries_.end() && it->first == c; ++it) out.push_back(it->second);
        }
    std::sort(out.begin(), out.end());
    out.erase(std::unique(out.begin(), out.end()), out.end());
  }

 private:
  static constexpr int kMaxCell = (1 << 21) - 1;
  Eigen::Array3d origin_;
  double inv_;
  std::vector<std::pair<uint64_t, int>> entries_;
};

}  // namespace

double ContactSurfaces::mean_edge_length(const ContactPositions& x) const {
  if (edges.empty()) return 0;
  double sum = 0;
  for (const auto& e : edges) sum += (x.row(e[0]) - x.row(e[1])).norm();
  return sum / edges.size();
}

std::vector<std::array<int, 2>> unique_edges(const std::vector<std::array<int, 3>>& faces) {
  std::vector<std::array<int, 2>> e;
  e.reserve(3 * faces.size());
  for (const auto& f : faces)
    for (int k = 0; k < 3; ++k) e.push_back({std::min(f[k], f[(k + 1) % 3]), std::max(f[k], f[(k + 1) % 3])});
  std::sort(e.begin(), e.end());
  e.erase(std::unique(e.begin(), e.end()), e.end());
  return e;
}

CandidatePairs broad_phase(const ContactSurfaces& s, const ContactPositions& x0, const ContactPositions* x1,
                           double inflation, PairFilter filter, double cell_size) {
  CandidatePairs out;
  const int nv = s.num_vertices(), nf = static_cast<int>(s.faces.size()), ne = static_cast<int>(s.edges.size());
  if (nv == 0) return out;
  const double pad = 0.5 * inflation;
  std::vector<Box> vbox(nv), fbox(nf), ebox(ne);
  Eigen::Array3d lo = Eigen::Array3d::Constant(INFINITY), hi = -lo;
  for (int i = 0; i < nv; ++i) {
    vbox[i] = primitive_box(std::array<int, 1>{i}, x0, x1, pad);
    lo = lo.min(vbox[i].lo);
    hi = hi.max(vbox[i].hi);
  }
  for (int f = 0; f < nf; ++f) fbox[f] = primitive_box(s.faces[f], x0, x1, pad);
  for (int e = 0; e < ne; ++e) ebox[e] = primitive_box(s.edges[e], x0, x1, pad);
  double cell = cell_size > 0 ? cell_size : s.mean_edge_length(x0);
  // Never more than ~2^21 cells per axis, never a zero cell.
  cell = std::max({cell, (hi - lo).maxCoeff() / 1e6, 1e-9});
  std::vector<int> hits;
  {
    HashGrid grid(lo, cell);
    for (int f = 0; f < nf; ++f) grid.insert(fbox[f], f);
    grid.finish();
    for (int v = 0; v < nv; ++v) {
      grid.query(vbox[v], hits);
      for (int f : hits) {
        if (!keep(filter, s.vertex_group[v], s.face_group(f))) continue;
        if (share_vertex(std::array<int, 1>{v}, s.faces[f])) continue;
        if (overlap(vbox[v], fbox[f])) out.point_triangle.push_back({v, f});
      }
    }
  }
  {
    HashGrid grid(lo, cell);
    for (int e = 0; e < ne; ++e) grid.insert(ebox[e], e);
    grid.finish();
    for (int e = 0; e < ne; ++e) {
      grid.query(ebox[e], hits);
      for (int o : hits) {
        if (o <= e) continue;
        if (!keep(filter, s.edge_group(e), s.edge_group(o))) continue;
        if (share_vertex(s.edges[e], s.edges[o])) continue;
        if (overlap(ebox[e], ebox[o])) out.edge_edge.push_back({e, o});
      }
    }
  }
  return out;
}

std::vector<std::array<int, 2>> triangle_pairs(const ContactSurfaces& s, const ContactPositions& x, double inflation,
                                               PairFilter filter, double cell_size) {
  std::vector<std::array<int, 2>> out;
  const int nf = static_cast<int>(s.faces.size());
  if (nf == 0) return out;
  std::vector<Box> fbox(nf);
  Eigen::Array3d lo = Eigen::Array3d::Constant(INFINITY), hi = -lo;
  for (int f = 0; f < nf; ++f) {
    fbox[f] = primitive_box(s.faces[f], x, nullptr, 0.5 * inflation);
    lo = lo.min(fbox[f].lo);
    hi = hi.max(fbox[f].hi);
  }
  double cell = cell_size > 0 ? cell_size : s.mean_edge_length(x);
  cell = std::max({cell, (hi - lo).maxCoeff() / 1e6, 1e-9});
  HashGrid grid(lo, cell);
  for (int f = 0; f < nf; ++f) grid.insert(fbox[f], f);
  grid.finish();
  std::vector<int> hits;
  for (int f = 0; f < nf; ++f) {
    grid.query(fbox[f], hits);
    for (int g : hits)
      if (g > f && keep(filter, s.face_group(f), s.face_group(g)) && !share_vertex(s.faces[f], s.faces[g]) &&
          overlap(fbox[f], fbox[g]))
        out.push_back({f, g});
  }
  return out;
}

CandidatePairs broad_phase_brute_force(const ContactSurfaces& s, const ContactPositions& x0,
                                       const ContactPositions* x1, double inflation, PairFilter filter) {
  CandidatePairs out;
  const double pad = 0.5 * inflation;
  const int nv = s.num_vertices(), nf = static_cast<int>(s.faces.size()), ne = static_cast<int>(s.edges.size());
  for (int v = 0; v < nv; ++v) {
    const Box bv = primitive_box(std::array<int, 1>{v}, x0, x1, pad);
    for (int f = 0; f < nf; ++f)
      if (keep(filter, s.vertex_group[v], s.face_group(f)) && !share_vertex(std::array<int, 1>{v}, s.faces[f]) &&
          overlap(bv, primitive_box(s.faces[f], x0, x1, pad)))
        out.point_triangle.push_back({v, f});
  }
  for (int e = 0; e < ne; ++e) {
    const Box be = primitive_box(s.edges[e], x0, x1, pad);
    for (int o = e + 1; o < ne; ++o)
      if (keep(filter, s.edge_group(e), s.edge_group(o)) && !share_vertex(s.edges[e], s.edges[o]) &&
          overlap(be, primitive_box(s.edges[o], x0, x1, pad)))
        out.edge_edge.push_back({e, o});
  }
  return out;
}

}  // namespace drapelab
