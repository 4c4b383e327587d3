// Clearance of a cloth edge (segment a b) to the Cusick support disk (contact/distance.hpp SupportDisk: a flat
// disk of radius R - rho at z = top - rho swept by a ball of radius rho), with exact derivatives.
//
// Along the segment x(t) = a + t (b - a), t in [0, 1], f(t) = dist(x(t), flat disk) - rho is convex (the
// distance to a convex set along a line) and C1; the edge's clearance is d_e = min_t f(t). Over the flat face
// f is linear in t (f'' = 0); over the rounded rim (r > R - rho) it is the torus distance
//   f = sqrt((r(t) - (R - rho))^2 + (z(t) - z_c)^2) - rho,
// with f'' > 0 there for a non-degenerate edge. `segment_support_disk_minimum` finds t* in floating point
// (safeguarded Newton on f'(t) inside a sign-change bracket). An interior minimum lies over the rim (over the
// face f is linear and its minimum is an end); a minimum at t = 0 or 1 is a vertex's distance, which the
// vertex barrier covers, so the edge term counts interior minima only.
//
// Derivatives: with t* held as a constant, two Newton corrections t1 = t* - f_t/f_tt, t2 = t1 - f_t/f_tt
// evaluated in the caller's scalar (jets) give a t2(x, rho) whose value is t* and whose first AND second
// derivatives are those of the implicit minimiser t*(x, rho) (Newton converges quadratically: the error of t_k
// as a function of the inputs is O(|dx|^(2^k))). Then f(x, t2) has the exact value, gradient (the envelope
// theorem: f_t = 0) and Hessian (f_xx - f_xt f_tt^-1 f_tx) of d_e (one correction would do for those; the second
// makes t2's own Hessian exact too, for callers that build on t).
#pragma once
#include <cmath>

#include "contact/distance.hpp"
#include "util/jet.hpp"

namespace drapelab {

// f, f_t, f_tt along the segment at t in the rim (torus) region, for any scalar; inner = R - rho,
// zc = top - rho. Valid where r(t) > 0 and the torus distance is positive.
template <class T>
void rim_distance_along(const T* a, const T* b, const T& t, const T& inner, const T& zc, const T& rim, T& f, T& ft,
                        T& ftt) {
  using std::sqrt;
  const T ex = b[0] - a[0], ey = b[1] - a[1], ez = b[2] - a[2];
  const T x = a[0] + t * ex, y = a[1] + t * ey, z = a[2] + t * ez;
  const T r = sqrt(x * x + y * y);
  const T rt = (x * ex + y * ey) / r;
  const T rtt = (ex * ex + ey * ey - rt * rt) / r;
  const T dr = r - inner, dz = z - zc;
  const T g = sqrt(dr * dr + dz * dz);
  const T gt = (dr * rt + dz * ez) / g;
  f = g - rim;
  ft = gt;
  ftt = (rt * rt + dr * rtt + ez * ez - gt * gt) / g;
}

struct SegmentDiskMinimum {
  double t = 0;         // minimiser t* in [0, 1]
  double distance = 0;  // min_t f(t) [m] (the segment's clearance, ends included)
  bool interior = false;  // t* in (0, 1) over the rim with f_tt > 0 (the edge term's case)
};

// The minimum of f(t) over the segment a b (3 doubles each) for the disk `disk`.
SegmentDiskMinimum segment_support_disk_minimum(const SupportDisk& disk, const double* a, const double* b);

// d_e(a, b, rho) at an interior minimum t* found by segment_support_disk_minimum for the same (double) values,
// with exact first and second derivatives through jets; t_out receives t2 (value t*, derivatives of t*).
// ftt_out (optional) receives f_tt at t2 (> 0 at an interior minimum; exact value and first derivatives).
template <class T>
T segment_support_disk_distance(const SupportDisk& disk, const T* a, const T* b, const T& rim, double tstar,
                                T& t_out, T* ftt_out = nullptr) {
  const T inner = disk.radius - rim, zc = disk.top - rim;
  T t(tstar), f, ft, ftt;
  for (int k = 0; k < 2; ++k) {
    rim_distance_along(a, b, t, inner, zc, rim, f, ft, ftt);
    t = t - ft / ftt;
  }
  rim_distance_along(a, b, t, inner, zc, rim, f, ft, ftt);
  t_out = t;
  if (ftt_out) *ftt_out = ftt;
  return f;
}

// Collision detection against the disk (conservative advancement, the step bounds of disk_contact.cpp): the
// largest t in [0, t_end] such that the clearance of a point x + tau dx (of the segment with ends a + tau da,
// b + tau db) stays above `floor` for every tau in [0, t] (t_end if the whole move does), given a start clearance
// above `floor`; at most kDiskAdvanceRounds rounds, each certifying a further stretch from where the last ended.
//
// Why it holds. Let phi(y) be the distance to the flat disk C (the plate's mid-disk of radius R - rho), so the
// clearance is phi - rho. C is convex, hence phi is convex on R^3, 1-Lipschitz, and outside C differentiable with
// unit gradient n(y) that is Lipschitz with constant 1 / m on {phi >= m} (Hess phi has eigenvalues in
// [0, 1 / phi] wherever it exists). A point moving on a line therefore satisfies, for every tau >= 0,
//   phi(y + tau u) >= phi(y) + tau n(y) . u                                                          (1)
// (the gradient inequality of a convex function): the clearance falls no faster than the move's component
// against the normal, and a sliding point (n . u >= 0) may take the whole move. A round from y certifies
// tau <= (phi(y) - rho - floor) / max(0, -n(y) . u) (the next round starts there: Newton's method on a convex
// function from below, which never passes the root). For the segment, every point x(s, tau) = x(s) + tau u(s),
// u(s) = (1 - s) da + s db, moves on a line, so by (1)
//   min_s phi(x(s, tau)) >= min_s [phi(x(s)) + tau k(s)],   k(s) = n(x(s)) . u(s).                   (2)
// On an interval I = [s0, s1] of s (width w): phi(x(s)) is convex in s, so it is at least
// m_I = g(c) + min(0, g'(c) (s0 - c), g'(c) (s1 - c)) with c the clamp of the segment's minimiser into I (the
// tangent line at c); and |k'(s)| = |n . (db - da) + u . Hess phi (b - a)| <= |db - da| + max_I |u| |b - a| / m_I,
// so k(s) >= k(mid) - L_I w / 2 on I (and k >= -max_I |u| always, the 1-Lipschitz bound). With c_I the larger of
// the two, min over I of the right side of (2) is at least m_I + tau c_I, certified until
// m_I + tau c_I = rho + floor. The smallest interval bound holds for the segment; intervals whose bound falls
// short of the remaining move are halved (at most kDiskAdvanceSplits halvings per round), so an edge that slides
// or rolls over the rim, whose points each keep their distance to first order (k(s) ~ 0 along the edge), takes
// the whole move, while the bound near the minimiser stays exact to first order for an edge that approaches.
constexpr int kDiskAdvanceRounds = 64;
constexpr int kDiskAdvanceSplits = 48;
double support_disk_point_advance(const SupportDisk& disk, const double* x, const double* dx, double t_end,
                                  double floor);
double support_disk_segment_advance(const SupportDisk& disk, const double* a, const double* b, const double* da,
                                    const double* db, double t_end, double floor);
// Clearance phi(y) - rho of a point to the disk and the unit gradient n of phi (the outward normal).
double support_disk_clearance_normal(const SupportDisk& disk, const double* y, double* n);

// The edge term's weight (disk_contact.cpp): q(s) = s^3 (10 - 15 s + 6 s^2) of s = dip / scale clamped to
// [0, 1] (the quintic smoothstep: 0 at s = 0 with zero first and second derivatives, 1 from s = 1 on). The dip
// of an interior minimum below an end, f(end) - d_e >= 0, is continuous in the positions and vanishes when the
// minimum reaches that end or when f is flat from that end to the minimum (an edge lying level over the face).
template <class T>
T dip_weight(const T& dip, double scale) {
  const double s = value_of(dip) / scale;
  if (s <= 0) return T(0.0);
  if (s >= 1) return T(1.0);
  const T u = dip / scale;
  return u * u * u * (10.0 + u * (-15.0 + 6.0 * u));
}

// The disk's edge term's weight of one end: the smooth step q of the dip over a scale that shrinks with the
// edge's clearance d > 0, s = dip / scale with 1 / scale = 1 / cap + 1 / d (scale ~ cap far from the disk, ~ d
// near contact). At a fixed scale (dip_weight(dip, cap)) an edge whose minimum dips only a little below an end
// (a long edge pressed onto the rim near one end: dip ~ um against cap = 0.1 mm) has a weight ~ 10 (dip/cap)^3,
// i.e. 1e-5, so its barrier balances the cloth's load only at a clearance ~ 1e-5 of the vertex barrier's (nm),
// and the linearised steps march it there, each move cut by collision detection. Relative to the clearance the
// edge counts fully once it dips below its end by its own clearance. q(s) as dip_weight's: 0 at dip = 0 (the
// minimum at an end: the vertex term's case), C2, 1 from s = 1 on.
template <class T>
T edge_dip_weight(const T& dip, const T& d, double cap) {
  const double s = value_of(dip) * (cap + value_of(d)) / (cap * value_of(d));
  if (s <= 0) return T(0.0);
  if (s >= 1) return T(1.0);
  const T u = dip * (cap + d) / (cap * d);
  return u * u * u * (10.0 + u * (-15.0 + 6.0 * u));
}

}  // namespace drapelab
