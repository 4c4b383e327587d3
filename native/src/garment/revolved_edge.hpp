// Clearance of a cloth edge (segment a b) to one part of a revolved body (garment/revolved_body.hpp), with exact
// derivatives: the edge's minimum over the segment of the part's clearance g (radial distance from the axis minus
// the profile radius; beyond an apex the distance to it), in the part's rest frame.
//
// Along the segment y(t) = y_a + t (y_b - y_a), t in [0, 1], the height s(t) on the axis is linear, so the
// profile's samples s_j cut [0, 1] into intervals on each of which one formula ("piece") holds:
//   piece 0 (s < s_0) and piece n (s > s_{n-1}): g = |y - apex|          (convex: a norm of an affine map)
//   piece j in 1..n-1 (s_{j-1} <= s <= s_j):     g = rho(t) - r_j(s(t))   (convex: rho is a norm of an affine
//                                                                         map, r_j is linear in s, so in t)
// g is continuous across the samples (r = 0 at the apexes), so the segment's minimum is the least of the
// intervals' minima, each of a convex smooth function: safeguarded Newton on g_t inside a sign-change bracket,
// or an interval end when g_t does not change sign. The minimiser t* is then
//   at t = 0 or 1 (kEnd):       a vertex's clearance, which the vertex barrier covers (no edge term),
//   inside an interval (kSmooth): g_t = 0 with g_tt > 0; value, gradient and Hessian from two Newton corrections
//                                 of t* evaluated in jets (as contact/disk_edge.hpp: t2 has the derivatives of the
//                                 implicit minimiser, g(x, t2) those of the minimum: the envelope theorem and
//                                 g_xx - g_xt g_tt^-1 g_tx),
//   at a sample s_j (kKink):     the segment's crossing of the circle's plane s = s_j, t_j = (s_j - s_a)/(s_b - s_a)
//                                 (an exact function of the ends, in jets) and g = rho(t_j) - r_j there.
#pragma once
#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <vector>

#include "util/jet.hpp"

namespace drapelab {

struct RevolvedPart;  // garment/revolved_body.hpp

// The profile of a part, as the segment code reads it.
struct ProfileView {
  const double* origin;  // 3: the top apex of the axis (rest frame)
  const double* s;       // n samples, increasing
  const double* r;       // n radii, r[0] = r[n-1] = 0 for a closed part (not required)
  int n;
};

// The piece (0 .. n) holding height s: 0 above the first sample, n below the last, else j with s_{j-1} <= s <= s_j.
inline int profile_piece(const ProfileView& P, double s) {
  if (s < P.s[0]) return 0;
  if (s > P.s[P.n - 1]) return P.n;
  const int j = static_cast<int>(std::upper_bound(P.s, P.s + P.n, s) - P.s);
  return std::clamp(j, 1, P.n - 1);
}

// g of a point y (rest frame) with the formula of `piece`, for any scalar.
template <class T>
T piece_clearance(const ProfileView& P, int piece, const T* y) {
  using std::sqrt;
  const T dx = y[0] - P.origin[0], dy = y[1] - P.origin[1], dz = y[2] - P.origin[2];
  if (piece == 0 || piece == P.n) {
    const double s_apex = piece == 0 ? P.s[0] : P.s[P.n - 1];
    const T w = dz + s_apex;  // y - apex, apex = origin - (0, 0, s_apex)
    return sqrt(dx * dx + dy * dy + w * w);
  }
  const int j = piece;
  const double slope = (P.r[j] - P.r[j - 1]) / (P.s[j] - P.s[j - 1]);
  const T s = -dz;
  return sqrt(dx * dx + dy * dy) - (P.r[j - 1] + slope * (s - P.s[j - 1]));
}

// g, g_t and g_tt along the segment ya yb at t with the formula of `piece`.
template <class T>
void piece_along(const ProfileView& P, int piece, const T* ya, const T* yb, const T& t, T& g, T& gt, T& gtt) {
  using std::sqrt;
  const T ex = yb[0] - ya[0], ey = yb[1] - ya[1], ez = yb[2] - ya[2];
  const T dx = ya[0] + t * ex - P.origin[0], dy = ya[1] + t * ey - P.origin[1], dz = ya[2] + t * ez - P.origin[2];
  if (piece == 0 || piece == P.n) {
    const double s_apex = piece == 0 ? P.s[0] : P.s[P.n - 1];
    const T w = dz + s_apex;
    const T n = sqrt(dx * dx + dy * dy + w * w);
    g = n;
    gt = (dx * ex + dy * ey + w * ez) / n;
    gtt = (ex * ex + ey * ey + ez * ez - gt * gt) / n;
    return;
  }
  const int j = piece;
  const double slope = (P.r[j] - P.r[j - 1]) / (P.s[j] - P.s[j - 1]);
  const T rho = sqrt(dx * dx + dy * dy);
  const T rt = (dx * ex + dy * ey) / rho;
  g = rho - (P.r[j - 1] + slope * (-dz - P.s[j - 1]));
  gt = rt + slope * ez;  // ds/dt = -e_z
  gtt = (ex * ex + ey * ey - rt * rt) / rho;
}

struct SegmentPartMinimum {
  enum Kind { kEnd = 0, kSmooth = 1, kKink = 2 };
  double t = 0;          // minimiser in [0, 1]
  double clearance = 0;  // min_t g (ends included) [m]
  int kind = kEnd;
  int piece = 0;         // kSmooth: the piece at t; kKink: the profile sample j (s = s_j at t)
};

// The segment's minimum (ya, yb: 3 doubles each, the part's rest frame).
inline SegmentPartMinimum segment_part_minimum(const ProfileView& P, const double* ya, const double* yb) {
  const double sa = P.origin[2] - ya[2], sb = P.origin[2] - yb[2];
  // The interval ends: 0, every sample crossed strictly inside, 1 (with the sample index at each inner end).
  double ts[130];
  int sample[130];
  std::vector<double> ts_big;
  std::vector<int> sample_big;
  double* tv = ts;
  int* sv = sample;
  int m = 0;
  const double lo_s = std::min(sa, sb), hi_s = std::max(sa, sb);
  const int j0 = static_cast<int>(std::upper_bound(P.s, P.s + P.n, lo_s) - P.s);
  const int j1 = static_cast<int>(std::lower_bound(P.s, P.s + P.n, hi_s) - P.s);  // samples j0 .. j1-1 inside
  const int inner = std::max(0, j1 - j0);
  if (inner + 2 > 130) {
    ts_big.resize(inner + 2);
    sample_big.resize(inner + 2);
    tv = ts_big.data();
    sv = sample_big.data();
  }
  tv[m] = 0.0;
  sv[m++] = -1;
  if (sb != sa) {
    const bool up = sb > sa;
    for (int q = 0; q < inner; ++q) {
      const int j = up ? j0 + q : j1 - 1 - q;
      const double t = (P.s[j] - sa) / (sb - sa);
      if (t > tv[m - 1] && t < 1.0) {
        tv[m] = t;
        sv[m++] = j;
      }
    }
  }
  tv[m] = 1.0;
  sv[m++] = -1;
  SegmentPartMinimum best;
  best.clearance = std::numeric_limits<double>::infinity();
  double best_gtt = 0;
  int where = -1;  // the interval end index of the best (or -1: interior)
  for (int q = 0; q + 1 < m; ++q) {
    const double lo = tv[q], hi = tv[q + 1];
    const int piece = profile_piece(P, sa + 0.5 * (lo + hi) * (sb - sa));
    double g, gt_lo, gt_hi, gtt;
    piece_along(P, piece, ya, yb, lo, g, gt_lo, gtt);
    const double g_lo = g;
    piece_along(P, piece, ya, yb, hi, g, gt_hi, gtt);
    const double g_hi = g;
    double t, value, curv = 0;
    int end = -1;
    if (!(gt_lo < 0)) {
      t = lo, value = g_lo, end = q;
    } else if (!(gt_hi > 0)) {
      t = hi, value = g_hi, end = q + 1;
    } else {
      double a = lo, b = hi;
      t = 0.5 * (lo + hi);
      for (int it = 0; it < 100; ++it) {
        double gt;
        piece_along(P, piece, ya, yb, t, g, gt, gtt);
        if (gt == 0) break;
        (gt < 0 ? a : b) = t;
        double next = gtt > 0 ? t - gt / gtt : 0.5 * (a + b);
        if (!(next > a && next < b)) next = 0.5 * (a + b);
        const double change = std::abs(next - t);
        t = next;
        if (change <= 1e-15 || b - a <= 1e-15) break;
      }
      double gt;
      piece_along(P, piece, ya, yb, t, g, gt, gtt);
      value = g, curv = gtt;
    }
    if (!std::isfinite(value)) value = -std::numeric_limits<double>::infinity();  // through the axis: inside
    if (value < best.clearance) {
      best.clearance = value;
      best.t = t;
      best.piece = piece;
      best_gtt = curv;
      where = end;
    }
  }
  if (where == 0 || where == m - 1) {
    best.kind = SegmentPartMinimum::kEnd;
  } else if (where > 0) {
    best.kind = SegmentPartMinimum::kKink;
    best.piece = sv[where];
  } else {
    best.kind = best_gtt > 0 && best.t > 0 && best.t < 1 ? SegmentPartMinimum::kSmooth : SegmentPartMinimum::kEnd;
  }
  return best;
}

// The minimum's value at the ends ya, yb (T: jets) for a minimum `m` found for the same (double) values: exact
// value, gradient and Hessian (kSmooth, kKink; kEnd is not an edge minimum).
template <class T>
T segment_part_clearance(const ProfileView& P, const T* ya, const T* yb, const SegmentPartMinimum& m) {
  using std::sqrt;
  if (m.kind == SegmentPartMinimum::kKink) {
    const int j = m.piece;
    const T sa = P.origin[2] - ya[2], sb = P.origin[2] - yb[2];
    const T t = (P.s[j] - sa) / (sb - sa);
    const T dx = ya[0] + t * (yb[0] - ya[0]) - P.origin[0], dy = ya[1] + t * (yb[1] - ya[1]) - P.origin[1];
    return sqrt(dx * dx + dy * dy) - P.r[j];
  }
  T t(m.t), g, gt, gtt;
  for (int k = 0; k < 2; ++k) {
    piece_along(P, m.piece, ya, yb, t, g, gt, gtt);
    t = t - gt / gtt;
  }
  piece_along(P, m.piece, ya, yb, t, g, gt, gtt);
  return g;
}

// A lower bound of g over the axis-aligned box [lo, hi] (rest frame): the box's distance from the axis minus the
// largest radius over its heights (beyond an apex g >= rho, r = 0); and the Lipschitz constant of g over the box,
// sqrt(1 + the largest |r'| of the pieces its heights reach).
inline double box_clearance_bound(const ProfileView& P, const double* lo, const double* hi, double* lipschitz) {
  const double cx = std::clamp(P.origin[0], lo[0], hi[0]), cy = std::clamp(P.origin[1], lo[1], hi[1]);
  const double ux = P.origin[0] - cx, uy = P.origin[1] - cy;
  const double dxy = std::sqrt(ux * ux + uy * uy);  // (not std::hypot: this runs per edge and part, hypot is slow)
  const double smin = P.origin[2] - hi[2], smax = P.origin[2] - lo[2];
  double rmax = 0, slope = 0;
  if (smax >= P.s[0] && smin <= P.s[P.n - 1]) {
    auto radius = [&](double s) {
      const int j = std::clamp(static_cast<int>(std::upper_bound(P.s, P.s + P.n, s) - P.s), 1, P.n - 1);
      const double u = std::clamp((s - P.s[j - 1]) / (P.s[j] - P.s[j - 1]), 0.0, 1.0);
      return P.r[j - 1] + u * (P.r[j] - P.r[j - 1]);
    };
    const double a = std::max(smin, P.s[0]), b = std::min(smax, P.s[P.n - 1]);
    rmax = std::max(radius(a), radius(b));
    const int j0 = std::clamp(static_cast<int>(std::upper_bound(P.s, P.s + P.n, a) - P.s), 1, P.n - 1);
    const int j1 = std::clamp(static_cast<int>(std::lower_bound(P.s, P.s + P.n, b) - P.s), 1, P.n - 1);
    for (int j = j0; j <= j1; ++j) {
      if (P.s[j] <= b) rmax = std::max(rmax, P.r[j]);
      slope = std::max(slope, std::abs(P.r[j] - P.r[j - 1]) / (P.s[j] - P.s[j - 1]));
    }
  }
  if (lipschitz) *lipschitz = std::sqrt(1.0 + slope * slope);
  return dxy - rmax;
}

}  // namespace drapelab
