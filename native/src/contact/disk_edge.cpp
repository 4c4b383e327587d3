#include "contact/disk_edge.hpp"

#include <algorithm>
#include <cmath>

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

}  // namespace drapelab
