#include "contact/disk_edge.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <queue>
#include <vector>

namespace drapelab {

namespace {
// f_t and f_tt of the segment's distance at t (both regions; f_tt = 0 over the flat face, where f is linear).
void distance_slope(const SupportDisk& disk, const double* a, const double* b, double t, double& ft, double& ftt,
                    bool& over_rim) {
  const double inner = disk.radius - disk.rim_radius, zc = disk.top - disk.rim_radius;
  const double x = a[0] + t * (b[0] - a[0]), y = a[1] + t * (b[1] - a[1]), z = a[2] + t * (b[2] - a[2]);
  over_rim = x * x + y * y > inner * inner;
  if (!over_rim) {
    ft = (z - zc >= 0 ? 1.0 : -1.0) * (b[2] - a[2]);
    ftt = 0;
    return;
  }
  double f;
  rim_distance_along(a, b, t, inner, zc, disk.rim_radius, f, ft, ftt);
}

double distance_at(const SupportDisk& disk, const double* a, const double* b, double t) {
  const double x[3] = {a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1]), a[2] + t * (b[2] - a[2])};
  return support_disk_distance(disk, x);
}
}  // namespace

SegmentDiskMinimum segment_support_disk_minimum(const SupportDisk& disk, const double* a, const double* b) {
  SegmentDiskMinimum m;
  double ft0, ft1, ftt;
  bool rim0, rim1;
  distance_slope(disk, a, b, 0.0, ft0, ftt, rim0);
  distance_slope(disk, a, b, 1.0, ft1, ftt, rim1);
  // f is convex: f' is nondecreasing, so a minimum at an end unless f' changes sign inside.
  if (!(ft0 < 0)) {
    m.t = 0;
    m.distance = distance_at(disk, a, b, 0.0);
    return m;
  }
  if (!(ft1 > 0)) {
    m.t = 1;
    m.distance = distance_at(disk, a, b, 1.0);
    return m;
  }
  double lo = 0, hi = 1, t = 0.5;
  bool over_rim = false;
  for (int it = 0; it < 200; ++it) {
    double ft;
    distance_slope(disk, a, b, t, ft, ftt, over_rim);
    if (ft == 0) break;
    (ft < 0 ? lo : hi) = t;
    double next = (ftt > 0) ? t - ft / ftt : 0.5 * (lo + hi);
    if (!(next > lo && next < hi)) next = 0.5 * (lo + hi);
    const double change = std::abs(next - t);
    t = next;
    if (change <= 1e-15 || hi - lo <= 1e-15) break;
  }
  distance_slope(disk, a, b, t, ft0, ftt, over_rim);
  m.t = t;
  m.distance = distance_at(disk, a, b, t);
  m.interior = over_rim && ftt > 0 && t > 0 && t < 1;
  return m;
}

double support_disk_clearance_normal(const SupportDisk& disk, const double* y, double* n) {
  const double inner = disk.radius - disk.rim_radius, zc = disk.top - disk.rim_radius;
  const double dz = y[2] - zc, r2 = y[0] * y[0] + y[1] * y[1];
  if (r2 <= inner * inner) {  // over (under) the flat face: phi = |z - zc|
    n[0] = n[1] = 0;
    n[2] = dz >= 0 ? 1.0 : -1.0;
    return std::abs(dz) - disk.rim_radius;
  }
  const double r = std::sqrt(r2), dr = r - inner, g = std::sqrt(dr * dr + dz * dz);
  n[0] = dr / g * y[0] / r;
  n[1] = dr / g * y[1] / r;
  n[2] = dz / g;
  return g - disk.rim_radius;
}

double support_disk_point_advance(const SupportDisk& disk, const double* x, const double* dx, double t_end,
                                  double floor) {
  double t = 0, n[3];
  for (int round = 0; round < kDiskAdvanceRounds; ++round) {
    const double y[3] = {x[0] + t * dx[0], x[1] + t * dx[1], x[2] + t * dx[2]};
    const double c = support_disk_clearance_normal(disk, y, n);
    if (!(c > floor)) return t;
    const double rate = -(n[0] * dx[0] + n[1] * dx[1] + n[2] * dx[2]);  // (1): the clearance falls at most this fast
    if (!(rate > 0)) return t_end;
    t += (c - floor) / rate;
    if (t >= t_end) return t_end;
  }
  return t;
}

namespace {
struct AdvanceInterval {
  double tau, s0, s1;
  bool refinable;  // halving could raise tau much (the Lipschitz part of k's bound is large against k)
  bool operator<(const AdvanceInterval& o) const { return tau > o.tau; }  // std::priority_queue: smallest tau first
};
}  // namespace

double support_disk_segment_advance(const SupportDisk& disk, const double* a, const double* b, const double* da,
                                    const double* db, double t_end, double floor) {
  const double rho = disk.rim_radius;
  double dd[3], norm_dd = 0;
  for (int k = 0; k < 3; ++k) {
    dd[k] = db[k] - da[k];
    norm_dd += dd[k] * dd[k];
  }
  norm_dd = std::sqrt(norm_dd);
  double t = 0;
  for (int round = 0; round < kDiskAdvanceRounds; ++round) {
    double A[3], B[3], e[3];
    for (int k = 0; k < 3; ++k) {
      A[k] = a[k] + t * da[k];
      B[k] = b[k] + t * db[k];
      e[k] = B[k] - A[k];
    }
    const double len = std::sqrt(e[0] * e[0] + e[1] * e[1] + e[2] * e[2]);
    const SegmentDiskMinimum minimum = segment_support_disk_minimum(disk, A, B);
    if (!(minimum.distance > floor)) return t;
    const double need = t_end - t;
    auto speed = [&](double s) {
      const double u0 = da[0] + s * dd[0], u1 = da[1] + s * dd[1], u2 = da[2] + s * dd[2];
      return std::sqrt(u0 * u0 + u1 * u1 + u2 * u2);
    };
    // The bound of (2) over s in [s0, s1]: how far (in tau from this round's start) it certifies; `refinable`
    // tells whether halving the interval could raise it much (the Lipschitz part of k's bound dominates).
    auto bound = [&](double s0, double s1, bool& refinable) -> double {
      refinable = false;
      double n[3];
      const double c = std::min(std::max(minimum.t, s0), s1);
      const double yc[3] = {A[0] + c * e[0], A[1] + c * e[1], A[2] + c * e[2]};
      const double gc = support_disk_clearance_normal(disk, yc, n) + rho;  // phi at c
      const double slope = n[0] * e[0] + n[1] * e[1] + n[2] * e[2];        // g'(c)
      const double m = gc + std::min({0.0, slope * (s0 - c), slope * (s1 - c)});
      const double slack = m - rho - floor;
      if (!(slack > 0) || !(m > 0)) return 0.0;
      const double sm = 0.5 * (s0 + s1), w = s1 - s0;
      const double ym[3] = {A[0] + sm * e[0], A[1] + sm * e[1], A[2] + sm * e[2]};
      support_disk_clearance_normal(disk, ym, n);
      const double k = n[0] * (da[0] + sm * dd[0]) + n[1] * (da[1] + sm * dd[1]) + n[2] * (da[2] + sm * dd[2]);
      const double umax = std::max(speed(s0), speed(s1));
      const double spread = 0.5 * w * (norm_dd + umax * len / m);  // L_I w / 2
      const double rate = std::max(k - spread, -umax);
      if (!(rate < 0)) return std::numeric_limits<double>::infinity();
      refinable = spread > 0.25 * std::max(0.0, -k);
      return slack / -rate;
    };
    // Branch and bound over s: halve the interval with the smallest bound while it falls short of the move.
    std::priority_queue<AdvanceInterval> heap;
    auto push = [&](double s0, double s1) {
      bool refinable;
      const double tau = bound(s0, s1, refinable);
      heap.push({tau, s0, s1, refinable});
    };
    push(0.0, 1.0);
    for (int split = 0; split < kDiskAdvanceSplits; ++split) {
      const AdvanceInterval worst = heap.top();
      if (worst.tau >= need || !worst.refinable) break;
      heap.pop();
      const double mid = 0.5 * (worst.s0 + worst.s1);
      push(worst.s0, mid);
      push(mid, worst.s1);
    }
    const double certified = heap.top().tau;  // the smallest interval bound: it holds for the whole segment
    if (certified >= need) return t_end;
    if (!(certified > 0)) return t;  // at the floor (to round-off): further rounds cannot advance
    t += certified;
  }
  return t;
}

}  // namespace drapelab
