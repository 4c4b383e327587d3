#include "contact/broad_phase.hpp"

#include <algorithm>
#include <cmath>

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
  return group_a == 0 || group_b == 0;  // never obstacle-obstacle
}

// Uniform grid over the scene's bounding box: boxes are binned into every cell they touch, in compressed rows
// (cell -> ids, by a counting sort), so a query visits its cells in O(1) each. Duplicate hits (a primitive in
// several of the query's cells) are dropped with a per-id stamp.
class HashGrid {
 public:
  HashGrid(const Eigen::Array3d& lo, const Eigen::Array3d& hi, double cell, int num_ids)
      : origin_(lo), inv_(1.0 / cell), stamp_(num_ids, -1) {
    dims_ = ((hi - lo) * inv_).floor().cast<int>() + 1;
    dims_ = dims_.max(1);
  }
  Eigen::Array3i cell_of(const Eigen::Array3d& p) const {
    return ((p - origin_) * inv_).floor().cast<int>().max(0).min(dims_ - 1);
  }
  long key(int i, int j, int k) const { return (static_cast<long>(k) * dims_[1] + j) * dims_[0] + i; }
  void insert(const Box& b, int id) {
    const Eigen::Array3i lo = cell_of(b.lo), hi = cell_of(b.hi);
    for (int k = lo[2]; k <= hi[2]; ++k)
      for (int j = lo[1]; j <= hi[1]; ++j)
        for (int i = lo[0]; i <= hi[0]; ++i) entries_.push_back({key(i, j, k), id});
  }
  void finish() {
    const long cells = static_cast<long>(dims_[0]) * dims_[1] * dims_[2];
    dense_ = cells <= 8 * static_cast<long>(entries_.size()) + (1 << 16);
    if (!dense_) {
      std::sort(entries_.begin(), entries_.end());
      return;
    }
    start_.assign(cells + 1, 0);
    for (const auto& e : entries_) ++start_[e.first + 1];
    for (long c = 0; c < cells; ++c) start_[c + 1] += start_[c];
    ids_.resize(entries_.size());
    std::vector<int> fill(start_.begin(), start_.end() - 1);
    for (const auto& e : entries_) ids_[fill[e.first]++] = e.second;
    entries_.clear();
  }
  // Ids binned in any cell of the box, each once, into `out`; `query_id` must differ between calls.
  void query(const Box& b, int query_id, std::vector<int>& out) {
    out.clear();
    const Eigen::Array3i lo = cell_of(b.lo), hi = cell_of(b.hi);
    auto take = [&](int id) {
      if (stamp_[id] != query_id) {
        stamp_[id] = query_id;
        out.push_back(id);
      }
    };
    for (int k = lo[2]; k <= hi[2]; ++k)
      for (int j = lo[1]; j <= hi[1]; ++j)
        for (int i = lo[0]; i <= hi[0]; ++i) {
          const long c = key(i, j, k);
          if (dense_) {
            for (int m = start_[c]; m < start_[c + 1]; ++m) take(ids_[m]);
          } else {
            auto it = std::lower_bound(entries_.begin(), entries_.end(), std::pair<long, int>{c, -1});
            for (; it != entries_.end() && it->first == c; ++it) take(it->second);
          }
        }
  }

 private:
  Eigen::Array3d origin_;
  double inv_;
  Eigen::Array3i dims_;
  bool dense_ = false;
  std::vector<std::pair<long, int>> entries_;
  std::vector<int> start_, ids_, stamp_;
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
  // Never more than ~200 cells per axis (a swept box spanning the scene stays cheap), never a zero cell.
  cell = std::max({cell, (hi - lo).maxCoeff() / 200, 1e-9});
  std::vector<int> hits;
  {
    HashGrid grid(lo, hi, cell, nf);
    for (int f = 0; f < nf; ++f) grid.insert(fbox[f], f);
    grid.finish();
    for (int v = 0; v < nv; ++v) {
      grid.query(vbox[v], v, hits);
      for (int f : hits) {
        if (!keep(filter, s.vertex_group[v], s.face_group(f))) continue;
        if (share_vertex(std::array<int, 1>{v}, s.faces[f])) continue;
        if (overlap(vbox[v], fbox[f])) out.point_triangle.push_back({v, f});
      }
    }
  }
  {
    HashGrid grid(lo, hi, cell, ne);
    for (int e = 0; e < ne; ++e) grid.insert(ebox[e], e);
    grid.finish();
    for (int e = 0; e < ne; ++e) {
      grid.query(ebox[e], e, hits);
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
  cell = std::max({cell, (hi - lo).maxCoeff() / 200, 1e-9});
  HashGrid grid(lo, hi, cell, nf);
  for (int f = 0; f < nf; ++f) grid.insert(fbox[f], f);
  grid.finish();
  std::vector<int> hits;
  for (int f = 0; f < nf; ++f) {
    grid.query(fbox[f], f, hits);
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
