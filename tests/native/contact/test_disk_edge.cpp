// Edge-against-disk contact (contact/disk_edge.hpp and disk_contact.cpp's edge term): the segment's clearance
// against dense sampling, its gradient and Hessian (and those of the minimiser t*) against central differences,
// and a coarse cloth whose edge would cut the rounded rim between two vertices that the vertex barrier alone
// accepts, the edge term rejects and the step bound stops short of.
#include <gtest/gtest.h>

#include <algorithm>
#include <random>
#include <utility>
#include <vector>

#include "../test_support.hpp"
#include "contact/barrier.hpp"
#include "contact/disk_edge.hpp"
#include "contact/distance.hpp"
#include "physics/effect.hpp"
#include "physics/model.hpp"
#include "physics/sparse_pattern.hpp"
#include "solver/implicit_euler.hpp"

namespace drapelab {
namespace {

std::mt19937 rng(11);
double uniform(double a, double b) { return std::uniform_real_distribution<double>(a, b)(rng); }

double sampled_minimum(const SupportDisk& disk, const double* a, const double* b, double* t_best = nullptr) {
  double best = INFINITY;
  const int n = 100000;
  for (int i = 0; i <= n; ++i) {
    const double t = double(i) / n;
    const double x[3] = {a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1]), a[2] + t * (b[2] - a[2])};
    const double d = support_disk_distance(disk, x);
    if (d < best) {
      best = d;
      if (t_best) *t_best = t;
    }
  }
  return best;
}

// A random cloth-sized edge (1-6 mm) near the rim of the default disk (R 9 cm, rim 2 mm, top z = 0), outside it.
void random_edge(const SupportDisk& disk, double* a, double* b) {
  for (;;) {
    const double phi = uniform(0, 6.283), r = uniform(0.085, 0.094), z = uniform(-0.004, 0.002);
    const double len = uniform(0.001, 0.006), th = uniform(0, 6.283), el = uniform(-1.2, 1.2);
    a[0] = r * std::cos(phi);
    a[1] = r * std::sin(phi);
    a[2] = z;
    b[0] = a[0] + len * std::cos(el) * std::cos(th);
    b[1] = a[1] + len * std::cos(el) * std::sin(th);
    b[2] = a[2] + len * std::sin(el);
    if (support_disk_distance(disk, a) > 1e-5 && support_disk_distance(disk, b) > 1e-5) return;
  }
}

// d_e and t* as functions of y = (a, b, rim) for the jets: the minimiser is found at the double values.
template <class T>
T edge_clearance(const SupportDisk& base, const T* y, T* t_out = nullptr) {
  SupportDisk disk = base;
  disk.rim_radius = value_of(y[6]);
  double a[3], b[3];
  for (int k = 0; k < 3; ++k) {
    a[k] = value_of(y[k]);
    b[k] = value_of(y[3 + k]);
  }
  const SegmentDiskMinimum m = segment_support_disk_minimum(disk, a, b);
  T t;
  const T d = segment_support_disk_distance(disk, y, y + 3, y[6], m.t, t);
  if (t_out) *t_out = t;
  return d;
}
double clearance_value(const SupportDisk& base, const double* y, bool want_t = false) {
  SupportDisk disk = base;
  disk.rim_radius = y[6];
  const SegmentDiskMinimum m = segment_support_disk_minimum(disk, y, y + 3);
  return want_t ? m.t : m.distance;
}

TEST(DiskEdge, SegmentMinimumMatchesDenseSampling) {
  SupportDisk disk;
  int interior = 0;
  for (int trial = 0; trial < 300; ++trial) {
    double a[3], b[3], t_best;
    random_edge(disk, a, b);
    const SegmentDiskMinimum m = segment_support_disk_minimum(disk, a, b);
    const double sampled = sampled_minimum(disk, a, b, &t_best);
    EXPECT_LE(m.distance, sampled + 1e-13) << "trial " << trial;
    EXPECT_NEAR(m.distance, sampled, 1e-9) << "trial " << trial;  // the sampling's own error: (1e-5 * 6 mm)^2 / rho
    if (m.interior) {
      ++interior;
      EXPECT_GT(m.t, 0.0);
      EXPECT_LT(m.t, 1.0);
      EXPECT_LT(m.distance, std::min(support_disk_distance(disk, a), support_disk_distance(disk, b)));
    }
  }
  EXPECT_GT(interior, 30) << "too few interior minima to test";
  // A chord of the rim: both ends 0.2 mm off the rounded edge, its middle cuts through it.
  const double c = 0.088, zc = -0.002, rho = 0.0022, half = 0.6;
  const double a[3] = {c + rho * std::cos(half), 0, zc + rho * std::sin(half)};
  const double b[3] = {c + rho * std::cos(-half), 0, zc + rho * std::sin(-half)};
  const SegmentDiskMinimum m = segment_support_disk_minimum(disk, a, b);
  EXPECT_TRUE(m.interior);
  EXPECT_NEAR(support_disk_distance(disk, a), 2e-4, 1e-15);
  EXPECT_LT(m.distance, 0.0) << "the chord's middle lies inside the rim";
}

TEST(DiskEdge, ClearanceAndMinimiserDerivativesMatchCentralDifferences) {
  SupportDisk disk;
  int tested = 0;
  for (int trial = 0; trial < 400 && tested < 40; ++trial) {
    double y[7];
    random_edge(disk, y, y + 3);
    y[6] = uniform(0.001, 0.004);
    SupportDisk d2 = disk;
    d2.rim_radius = y[6];
    const SegmentDiskMinimum m = segment_support_disk_minimum(d2, y, y + 3);
    if (!m.interior || m.t < 0.02 || m.t > 0.98 || m.distance < 1e-5) continue;
    ++tested;
    double v, g[7], H[49], tv, tg[7], tH[49];
    distance_gradient_hessian<7>([&](const auto* yy) { return edge_clearance(disk, yy); }, y, v, g, H);
    distance_gradient_hessian<7>(
        [&](const auto* yy) {
          std::remove_const_t<std::remove_reference_t<decltype(yy[0])>> t;
          edge_clearance(disk, yy, &t);
          return t;
        },
        y, tv, tg, tH);
    EXPECT_NEAR(v, m.distance, 1e-15);
    EXPECT_NEAR(tv, m.t, 1e-12);
    const double h = 1e-7;
    for (int k = 0; k < 7; ++k) {
      double yp[7], ym[7];
      std::copy(y, y + 7, yp);
      std::copy(y, y + 7, ym);
      yp[k] += h;
      ym[k] -= h;
      EXPECT_NEAR(g[k], (clearance_value(disk, yp) - clearance_value(disk, ym)) / (2 * h), 1e-6) << "grad " << k;
      EXPECT_NEAR(tg[k], (clearance_value(disk, yp, true) - clearance_value(disk, ym, true)) / (2 * h),
                  1e-5 * std::max(1.0, std::abs(tg[k])))
          << "dt*/dy " << k;
      // Hessian rows: central differences of the jets' gradient
      double vp, gp[7], Hp[49], vm, gm[7], Hm[49];
      distance_gradient_hessian<7>([&](const auto* yy) { return edge_clearance(disk, yy); }, yp, vp, gp, Hp);
      distance_gradient_hessian<7>([&](const auto* yy) { return edge_clearance(disk, yy); }, ym, vm, gm, Hm);
      for (int j = 0; j < 7; ++j) {
        const double fd = (gp[j] - gm[j]) / (2 * h);
        EXPECT_NEAR(H[k * 7 + j], fd, 1e-5 * std::max(1.0, std::abs(fd))) << "Hess " << k << "," << j;
        EXPECT_NEAR(H[k * 7 + j], H[j * 7 + k], 1e-9 * std::max(1.0, std::abs(fd)));
      }
      distance_gradient_hessian<7>(
          [&](const auto* yy) {
            std::remove_const_t<std::remove_reference_t<decltype(yy[0])>> t;
            edge_clearance(disk, yy, &t);
            return t;
          },
          yp, vp, gp, Hp);
      distance_gradient_hessian<7>(
          [&](const auto* yy) {
            std::remove_const_t<std::remove_reference_t<decltype(yy[0])>> t;
            edge_clearance(disk, yy, &t);
            return t;
          },
          ym, vm, gm, Hm);
      for (int j = 0; j < 7; ++j) {
        const double fd = (gp[j] - gm[j]) / (2 * h);
        EXPECT_NEAR(tH[k * 7 + j], fd, 1e-4 * std::max(1.0, std::abs(fd))) << "Hess t* " << k << "," << j;
      }
    }
  }
  EXPECT_GE(tested, 40);
}

TEST(DiskEdge, DipWeightIsASmoothStep) {
  using J = Jet<Jet<double, 1>, 1>;
  for (double s : {-0.1, 0.0, 0.2, 0.5, 0.9, 1.0, 1.3}) {
    const J w = dip_weight(J(Jet<double, 1>(s * 1e-4, 0), 0), 1e-4);
    const double h = 1e-6;
    const double fd = (dip_weight((s + h) * 1e-4, 1e-4) - dip_weight((s - h) * 1e-4, 1e-4)) / (2 * h * 1e-4);
    EXPECT_NEAR(w.v[0].a, fd, 1e-6 * std::max(1.0, std::abs(fd)) + 1e-3) << s;
    EXPECT_GE(w.a.a, 0.0);
    EXPECT_LE(w.a.a, 1.0);
  }
  EXPECT_EQ(dip_weight(0.0, 1e-4), 0.0);
  EXPECT_EQ(dip_weight(1e-4, 1e-4), 1.0);
}

TEST(DiskEdge, RelativeDipWeightIsASmoothStepOverAScaleThatShrinksWithTheClearance) {
  // q(dip / scale), 1 / scale = 1 / cap + 1 / d: derivatives in dip and d against central differences.
  const double cap = 1e-4;
  using J = Jet<double, 2>;
  for (double d : {1e-8, 1e-6, 5e-5, 4e-4})
    for (double s : {-0.1, 0.0, 0.2, 0.5, 0.9, 1.3}) {
      const double scale = cap * d / (cap + d), dip = s * scale;
      const J w = edge_dip_weight(J(dip, 0), J(d, 1), cap);
      const double hd = 1e-6 * scale, hs = 1e-6 * d;
      const double fd_dip = (edge_dip_weight(dip + hd, d, cap) - edge_dip_weight(dip - hd, d, cap)) / (2 * hd);
      const double fd_d = (edge_dip_weight(dip, d + hs, cap) - edge_dip_weight(dip, d - hs, cap)) / (2 * hs);
      EXPECT_NEAR(w.v[0], fd_dip, 1e-5 * std::abs(fd_dip) + 1e-6 / scale) << d << " " << s;
      EXPECT_NEAR(w.v[1], fd_d, 1e-5 * std::abs(fd_d) + 1e-6 / d) << d << " " << s;
      EXPECT_GE(w.a, 0.0);
      EXPECT_LE(w.a, 1.0);
    }
  EXPECT_EQ(edge_dip_weight(0.0, 1e-6, cap), 0.0);  // the minimum at an end: the vertex term's case
  EXPECT_EQ(edge_dip_weight(1e-6, 1e-6, cap), 1.0);   // near contact it counts fully once it dips by d
  EXPECT_NEAR(edge_dip_weight(0.5e-4, 1.0, cap), dip_weight(0.5e-4, cap), 1e-3);  // far: about the fixed scale
}

// The clearance of the segment (a + tau da, b + tau db) by its exact minimum (segment_support_disk_minimum, itself
// checked against dense sampling above).
double moved_clearance(const SupportDisk& disk, const double* a, const double* b, const double* da, const double* db,
                       double tau) {
  double ya[3], yb[3];
  for (int k = 0; k < 3; ++k) {
    ya[k] = a[k] + tau * da[k];
    yb[k] = b[k] + tau * db[k];
  }
  return segment_support_disk_minimum(disk, ya, yb).distance;
}

// The old edge advancement (before helper R): Lipschitz constant max(|da|, |db|), 64 rounds.
double lipschitz_advance(const SupportDisk& disk, const double* a, const double* b, const double* da,
                         const double* db, double floor) {
  const double len = std::max(std::sqrt(da[0] * da[0] + da[1] * da[1] + da[2] * da[2]),
                              std::sqrt(db[0] * db[0] + db[1] * db[1] + db[2] * db[2]));
  double t = 0;
  for (int it = 0; it < 64 && t < 1; ++it) {
    const double dist = moved_clearance(disk, a, b, da, db, t);
    if (dist <= floor) break;
    t = std::min(1.0, t + (dist - floor) / len);
  }
  return t;
}

// Collision detection's bounds (support_disk_point_advance, support_disk_segment_advance) never promise more
// than the true clearance: along every certified move the clearance, sampled densely in tau (segments: their
// exact minimum at each tau), stays above the floor. And they are tight: the certified fraction against the
// true first crossing of the floor.
TEST(DiskEdge, AdvanceBoundsAreConservative) {
  SupportDisk disk;
  int cut_points = 0, cut_segments = 0, whole = 0, trials = 0;
  std::vector<double> tightness;
  for (int trial = 0; trial < 600; ++trial) {
    double a[3], b[3], da[3], db[3];
    random_edge(disk, a, b);
    const double d0 = segment_support_disk_minimum(disk, a, b).distance;
    if (!(d0 > 1e-7)) continue;  // a move starts clear of the disk (random_edge may cut the rim between its ends)
    // moves of 0.3-30 times the clearance (at most 2 mm): a common translation plus a differential part
    // (rotations, tilts), in random directions, many towards the disk
    const double size = std::min(2e-3, d0 * std::exp(uniform(std::log(0.3), std::log(30.0))));
    for (int k = 0; k < 3; ++k) {
      const double common = uniform(-1, 1), diff = uniform(-1, 1) * uniform(0, 1);
      da[k] = size * (common - diff);
      db[k] = size * (common + diff);
    }
    ++trials;
    const double d0p = support_disk_distance(disk, a);
    const double tp = support_disk_point_advance(disk, a, da, 1.0, 0.1 * d0p);
    EXPECT_GE(tp, 0.0);
    EXPECT_LE(tp, 1.0);
    for (int i = 0; i <= 2000; ++i) {
      const double tau = tp * i / 2000.0;
      const double y[3] = {a[0] + tau * da[0], a[1] + tau * da[1], a[2] + tau * da[2]};
      ASSERT_GE(support_disk_distance(disk, y), 0.1 * d0p * (1 - 1e-9)) << "point trial " << trial << " tau " << tau;
    }
    if (tp < 1) ++cut_points;
    const double floor = 0.1 * d0;
    const double t = support_disk_segment_advance(disk, a, b, da, db, 1.0, floor);
    EXPECT_GE(t, 0.0);
    EXPECT_LE(t, 1.0);
    for (int i = 0; i <= 400; ++i) {
      const double tau = t * i / 400.0;
      ASSERT_GE(moved_clearance(disk, a, b, da, db, tau), floor * (1 - 1e-9)) << "segment trial " << trial << " tau "
                                                                             << tau;
    }
    // dense sampling along the segment too at the certified end
    double ya[3], yb[3];
    for (int k = 0; k < 3; ++k) {
      ya[k] = a[k] + t * da[k];
      yb[k] = b[k] + t * db[k];
    }
    ASSERT_GE(sampled_minimum(disk, ya, yb), floor * (1 - 1e-9)) << "segment trial " << trial;
    if (t < 1) {
      ++cut_segments;
      double crossing = 1;  // the true first crossing of the floor (scan, then bisection)
      for (int i = 1; i <= 1000; ++i)
        if (moved_clearance(disk, a, b, da, db, i / 1000.0) < floor) {
          double lo = (i - 1) / 1000.0, hi = i / 1000.0;
          for (int k = 0; k < 50; ++k) {
            const double mid = 0.5 * (lo + hi);
            (moved_clearance(disk, a, b, da, db, mid) < floor ? hi : lo) = mid;
          }
          crossing = lo;
          break;
        }
      EXPECT_LE(t, crossing * (1 + 1e-9) + 1e-12) << "segment trial " << trial;
      tightness.push_back(t / crossing);
    } else {
      ++whole;
    }
  }
  std::sort(tightness.begin(), tightness.end());
  ASSERT_FALSE(tightness.empty());
  const double median = tightness[tightness.size() / 2], low = tightness[tightness.size() / 10];
  std::printf("advance bounds: %d / %d point moves and %d / %d segment moves cut; segments: certified / true "
              "crossing median %.3f, 10th percentile %.3f\n",
              cut_points, trials, cut_segments, trials, median, low);
  EXPECT_GE(cut_segments, 20);  // the random moves do reach the floor often
  EXPECT_GE(whole, 20);
  EXPECT_GT(median, 0.5);
}

// An edge pressed onto the rounded rim and rolling over it (its ends moving on the tangents of their circles about
// the tube's centre: every point keeps its distance to first order and gains at second) takes the whole move,
// which the Lipschitz advancement (64 rounds of 0.9 d0 / max |d end|) cuts to a fraction.
TEST(DiskEdge, EdgeRollingOverTheRimTakesTheWholeMove) {
  SupportDisk disk;
  const double rho = disk.rim_radius, inner = disk.radius - rho, zc = disk.top - rho;
  for (double psi : {0.3, 0.8, 1.2})  // the contact's angle on the tube from the horizontal
    for (double d0 : {3e-7, 1e-6}) {
      const double n[3] = {std::cos(psi), 0, std::sin(psi)}, e[3] = {-std::sin(psi), 0, std::cos(psi)};
      const double half = 2.5e-3, omega = 0.05;  // a 5 mm edge, turned by 0.05 rad about the tube's centre line
      double a[3], b[3], da[3], db[3];
      const double centre[3] = {inner, 0, zc};
      for (int k = 0; k < 3; ++k) {
        a[k] = centre[k] + (rho + d0) * n[k] - half * e[k];
        b[k] = centre[k] + (rho + d0) * n[k] + half * e[k];
      }
      // rotation about the y axis through the centre: d = omega y x (q - centre)
      for (const auto& [q, dq] : {std::pair<double*, double*>{a, da}, std::pair<double*, double*>{b, db}}) {
        const double rx = q[0] - centre[0], rz = q[2] - centre[2];
        dq[0] = omega * rz;
        dq[1] = 0;
        dq[2] = -omega * rx;
      }
      const double start = segment_support_disk_minimum(disk, a, b).distance;
      ASSERT_NEAR(start, d0, 1e-12);
      const double floor = 0.1 * start;
      EXPECT_EQ(support_disk_segment_advance(disk, a, b, da, db, 1.0, floor), 1.0) << psi << " " << d0;
      EXPECT_GT(moved_clearance(disk, a, b, da, db, 1.0), start);  // it really gains clearance
      EXPECT_LT(lipschitz_advance(disk, a, b, da, db, floor), 0.5) << psi << " " << d0;
      // a point on the rim sliding along its tangent: the whole move as well
      const double p0[3] = {centre[0] + (rho + d0) * n[0], 0, centre[2] + (rho + d0) * n[2]};
      const double dp[3] = {3e-4 * e[0], 0, 3e-4 * e[2]};
      EXPECT_EQ(support_disk_point_advance(disk, p0, dp, 1.0, floor), 1.0);
    }
}

const Term* find_term(const Model& model, const std::string& name) {
  for (const auto& t : model.terms())
    if (t->name() == name) return t.get();
  return nullptr;
}

// circle1 (coarse: ~1 cm edges) bent over the rounded rim: the flat part `gap` above the face, the part beyond
// R - rho wrapped a quarter turn around the rim's centre circle at radius rho + gap, the rest hanging straight
// down (arc length kept), so every vertex is at least `gap` from the disk while a chord between two neighbours
// across the bend sags towards the rim.
Eigen::VectorXd wrapped_over_rim(const Model& model, double rim, double gap, double top) {
  Eigen::VectorXd x = model.rest_positions();
  const double inner = model.options().support_radius - rim, zc = top - rim, R = rim + gap;
  for (int i = 0; i < model.num_vertices(); ++i) {
    const double r = x.segment<2>(3 * i).norm();
    if (r <= inner) {
      x[3 * i + 2] = top + gap;
      continue;
    }
    const double s = r - inner, quarter = 0.5 * M_PI * R;
    double rr, z;
    if (s < quarter) {
      rr = inner + R * std::sin(s / R);
      z = zc + R * std::cos(s / R);
    } else {
      rr = inner + R;
      z = zc - (s - quarter);
    }
    x[3 * i] *= rr / r;
    x[3 * i + 1] *= rr / r;
    x[3 * i + 2] = z;
  }
  return x;
}

double worst_chord(const Model& model, const Eigen::VectorXd& x, const SupportDisk& disk) {
  double worst = INFINITY;
  for (int f = 0; f < model.mesh().num_faces(); ++f)
    for (int k = 0; k < 3; ++k) {
      const int a = model.mesh().faces(f, k), b = model.mesh().faces(f, (k + 1) % 3);
      if (model.mesh().uv.row(a).norm() < 0.02 || model.mesh().uv.row(b).norm() < 0.02) continue;
      worst = std::min(worst, segment_support_disk_minimum(disk, x.data() + 3 * a, x.data() + 3 * b).distance);
    }
  return worst;
}

// circle1 wrapped over the rim at the smallest gap at which its chords stay 0.1-0.4 mm off it (within the 0.5 mm
// reach); empty when no gap below 3 cm does.
Eigen::VectorXd wrapped_within_reach(const Model& model, double rim, double top) {
  SupportDisk disk;
  disk.radius = model.options().support_radius;
  disk.rim_radius = rim;
  disk.top = top;
  for (double gap = 2e-4; gap < 3e-2; gap += 5e-5) {
    Eigen::VectorXd x = wrapped_over_rim(model, rim, gap, top);
    const double w = worst_chord(model, x, disk);
    if (w > 1e-4 && w < 4e-4) return x;
  }
  return {};
}

TEST(DiskEdge, CoarseClothCannotCutTheRimBetweenTwoVertices) {
  ModelOptions o;
  o.effects["disk_contact"] = {{"clamp_radius_m", 0.02}};
  const Model model(load_cusick_template(1, testing::template_dir()), o);
  Eigen::VectorXd p = model.default_parameters();
  const double rim = p[model.layout().block("disk_contact.rim_radius_m").offset];
  const double top = model.rest_positions()[2] - 5e-4;  // the disk's top face (0.5 mm below the rest plane)
  const Term* vertex_term = find_term(model, "disk_contact");
  const Term* edge_term = find_term(model, "disk_edge_contact");
  ASSERT_NE(vertex_term, nullptr);
  ASSERT_NE(edge_term, nullptr);
  // Every vertex 0.2 mm off the rim: the vertex barrier is finite, but circle1's chords cut into the rim.
  const Eigen::VectorXd cut = wrapped_over_rim(model, rim, 2e-4, top);
  SupportDisk disk;
  disk.radius = model.options().support_radius;
  disk.rim_radius = rim;
  disk.top = top;
  double worst_vertex = INFINITY;
  for (int i = 0; i < model.num_vertices(); ++i)
    if (model.mesh().uv.row(i).norm() >= 0.02) worst_vertex = std::min(worst_vertex, support_disk_distance(disk, cut.data() + 3 * i));
  const double worst_edge = worst_chord(model, cut, disk);
  EXPECT_NEAR(worst_vertex, 2e-4, 1e-9);
  EXPECT_LT(worst_edge, 0.0) << "the test state should have an edge through the rim";
  EXPECT_TRUE(std::isfinite(vertex_term->energy(cut, p))) << "the vertex barrier alone accepts the cut";
  EXPECT_FALSE(std::isfinite(edge_term->energy(cut, p))) << "the edge barrier rejects it";
  // A safe state (every chord clear of the rim): the cloth wrapped 2 cm off it; the step towards the cut state
  // is bounded.
  const Eigen::VectorXd safe = wrapped_over_rim(model, rim, 2e-2, top);
  const double safe_edge = worst_chord(model, safe, disk);
  ASSERT_GT(safe_edge, 0.0);
  EXPECT_TRUE(std::isfinite(edge_term->energy(safe, p)));
  const Eigen::VectorXd dx = cut - safe;
  // The vertex bound alone lets the step through to a state whose chords cut the rim.
  const double alpha_vertex = vertex_term->max_step(safe, dx, p);
  const Eigen::VectorXd vertex_stop = safe + alpha_vertex * dx;
  const double vertex_stop_edge = worst_chord(model, vertex_stop, disk);
  EXPECT_LT(vertex_stop_edge, 0.0) << "without the edge term the step would cut the rim";
  const double alpha = edge_term->max_step(safe, dx, p);
  EXPECT_LT(alpha, 1.0);
  EXPECT_GT(alpha, 0.0);
  const Eigen::VectorXd stop = safe + alpha * dx;
  const double stop_edge = worst_chord(model, stop, disk);
  EXPECT_GT(stop_edge, 0.0) << "the bounded step keeps every edge off the rim";
  EXPECT_TRUE(std::isfinite(edge_term->energy(stop, p)));
  std::printf("coarse cloth over the rim (circle1, rim %.1f mm): vertex clearance %.3f mm, worst chord %.3f mm; vertex "
              "CCD alone: alpha %.3f, chord clearance %.3f mm; with the edge CCD: alpha %.3f, chord clearance %.4f mm\n",
              rim * 1e3, worst_vertex * 1e3, worst_edge * 1e3, alpha_vertex, vertex_stop_edge * 1e3, alpha, stop_edge * 1e3);
}

}  // namespace
}  // namespace drapelab

namespace drapelab {
namespace {

// The edge term alone on circle1 wrapped over the rim with a gap where its chords dip into the barrier's reach
// (and on the registry suite's state, tests/native/physics/test_effects.cpp, to show the suite exercises it):
// energy, gradient, Hessian products and the rim radius derivative against central differences.
TEST(DiskEdge, EdgeTermDerivativesMatchCentralDifferencesOverTheRim) {
  ModelOptions o;
  o.effects["disk_contact"] = {{"clamp_radius_m", 0.02}};
  const Model model(load_cusick_template(1, testing::template_dir()), o);
  const Eigen::VectorXd p = model.default_parameters();
  const int rim_index = model.layout().block("disk_contact.rim_radius_m").offset;
  const double rim = p[rim_index];
  const double top = model.rest_positions()[2] - 5e-4;
  const Term* edge_term = find_term(model, "disk_edge_contact");
  ASSERT_NE(edge_term, nullptr);
  Eigen::VectorXd x = wrapped_within_reach(model, rim, top);
  ASSERT_GT(x.size(), 0) << "no gap puts the chords within reach";
  std::mt19937 g(3);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  for (int i = 0; i < x.size(); ++i) x[i] += 2e-5 * u(g);
  const double E = edge_term->energy(x, p);
  ASSERT_TRUE(std::isfinite(E));
  ASSERT_GT(E, 0.0) << "no edge within the barrier's reach: move the state";
  const int n = static_cast<int>(x.size());
  const Eigen::VectorXd dir = testing::random_vector(n, 5);
  Eigen::VectorXd grad = Eigen::VectorXd::Zero(n);
  edge_term->add_gradient(x, p, grad);
  const double eps = 1e-9;
  const double fd = (edge_term->energy(x + eps * dir, p) - edge_term->energy(x - eps * dir, p)) / (2 * eps);
  EXPECT_NEAR(grad.dot(dir), fd, 1e-5 * std::abs(fd));
  Eigen::VectorXd Hd = Eigen::VectorXd::Zero(n), gp = Eigen::VectorXd::Zero(n), gm = Eigen::VectorXd::Zero(n);
  edge_term->add_hessian_product(x, p, dir, Hd);
  edge_term->add_gradient(x + eps * dir, p, gp);
  edge_term->add_gradient(x - eps * dir, p, gm);
  const Eigen::VectorXd fdH = (gp - gm) / (2 * eps);
  EXPECT_LT((Hd - fdH).norm(), 1e-4 * fdH.norm());
  Eigen::VectorXd dEdp = Eigen::VectorXd::Zero(p.size());
  edge_term->add_energy_parameter_gradient(x, p, dEdp);
  const double h = 1e-9;
  Eigen::VectorXd pp = p, pm = p;
  pp[rim_index] += h;
  pm[rim_index] -= h;
  const double fdp = (edge_term->energy(x, pp) - edge_term->energy(x, pm)) / (2 * h);
  EXPECT_NEAR(dEdp[rim_index], fdp, 1e-5 * std::abs(fdp));
  std::printf("edge term over the rim: E %.4g J, dE/drim %.4g (fd %.4g)\n", E, dEdp[rim_index], fdp);

  // The registry suite's contact state (make_cusick_specimen(60), every vertex lowered 0.1-0.3 mm): some edges
  // straddling R - rho dip below their ends within reach, so the suite's central differences cover the term.
  ModelOptions mo;
  mo.effects["disk_contact"] = {{"clamp_radius_m", 0.02}};
  const Model specimen(make_cusick_specimen(60), mo);
  Eigen::VectorXd y = specimen.rest_positions();
  std::mt19937 rng5(5);
  std::uniform_real_distribution<double> u01(0.0, 1.0);
  for (int i = 0; i < specimen.num_vertices(); ++i) {
    y[3 * i] += 1e-4 * (u01(rng5) - 0.5);
    y[3 * i + 1] += 1e-4 * (u01(rng5) - 0.5);
    y[3 * i + 2] -= 1e-4 + 2e-4 * u01(rng5);
  }
  const Term* suite_term = find_term(specimen, "disk_edge_contact");
  ASSERT_NE(suite_term, nullptr);
  EXPECT_GT(suite_term->energy(y, specimen.default_parameters()), 0.0);
}

// The edge term's adjoint and step system visit only the edges active at x (disk_contact.cpp NearDiskEdges):
// on circle1 wrapped over the rim with some chords within reach (and most edges out of it), they equal Term's
// generic composition of the term's full-loop passes bit for bit.
// A disk barrier term's adjoint and step system, which visit only the elements within reach (NearDiskEdges,
// NearDiskVertices), against Term::add_step_adjoint's composition of the term's full loops: equal bit for bit.
void expect_active_passes_equal_full_loops(const Model& model, const Term& term, const Eigen::VectorXd& x,
                                           const Eigen::VectorXd& p, int rim_index) {
  ASSERT_GT(term.energy(x, p), 0.0) << "no element within the barrier's reach";
  const int n = static_cast<int>(x.size());
  const Eigen::VectorXd lambda = testing::random_vector(n, 11), w = testing::random_vector(n, 12),
                        v = testing::random_vector(n, 13), gx0 = testing::random_vector(n, 14),
                        gv0 = testing::random_vector(n, 15);
  const double h = 0.05;
  // the term's own (active elements only)
  Eigen::VectorXd gx = gx0, gv = gv0, gp = Eigen::VectorXd::Zero(p.size());
  ASSERT_TRUE(term.add_step_adjoint(x, p, lambda, w, h, gx, gv, gp));
  // Term::add_step_adjoint's composition, with the term's full loops
  Eigen::VectorXd gx_ref = gx0, gv_ref = gv0, gp_ref = Eigen::VectorXd::Zero(p.size()), Hl = Eigen::VectorXd::Zero(n);
  term.add_hessian_product(x, p, lambda, Hl);
  gx_ref -= h * Hl;
  term.add_step_matrix_derivatives(x, p, lambda, w, -h * h, gx_ref, gp_ref);
  term.add_gradient_parameter_product(x, p, lambda, -h, gp_ref);
  ASSERT_TRUE(term.add_step_matrix_product(x, p, lambda, -h * h, gv_ref));
  EXPECT_GT((gx - gx0).norm(), 0.0) << "the active elements contributed nothing";
  EXPECT_NE(gp[rim_index], 0.0);
  EXPECT_EQ((gx - gx_ref).lpNorm<Eigen::Infinity>(), 0.0);
  EXPECT_EQ((gv - gv_ref).lpNorm<Eigen::Infinity>(), 0.0);
  EXPECT_EQ((gp - gp_ref).lpNorm<Eigen::Infinity>(), 0.0);
  // the step system: matrix, K v and gradient
  const int nnz = model.pattern().nnz();
  Eigen::VectorXd A = Eigen::VectorXd::Zero(nnz), Kv = Eigen::VectorXd::Zero(n), grad = Eigen::VectorXd::Zero(n);
  ASSERT_TRUE(term.add_step_system(x, p, v, h * h, A, Kv, grad));
  Eigen::VectorXd A_ref = Eigen::VectorXd::Zero(nnz), Kv_ref = Eigen::VectorXd::Zero(n),
                  grad_ref = Eigen::VectorXd::Zero(n);
  term.add_step_matrix(x, p, h * h, A_ref);
  term.add_gradient(x, p, grad_ref);
  ASSERT_TRUE(term.add_step_matrix_product(x, p, v, h * h, Kv_ref));
  EXPECT_GT(grad.norm(), 0.0);
  EXPECT_EQ((A - A_ref).lpNorm<Eigen::Infinity>(), 0.0);
  EXPECT_EQ((Kv - Kv_ref).lpNorm<Eigen::Infinity>(), 0.0);
  EXPECT_EQ((grad - grad_ref).lpNorm<Eigen::Infinity>(), 0.0);
}

TEST(DiskEdge, ActiveEdgeAndVertexPassesEqualTheFullLoops) {
  ModelOptions o;
  o.effects["disk_contact"] = {{"clamp_radius_m", 0.02}};
  const Model model(load_cusick_template(1, testing::template_dir()), o);
  const Eigen::VectorXd p = model.default_parameters();
  const int rim_index = model.layout().block("disk_contact.rim_radius_m").offset;
  const double rim = p[rim_index];
  const double top = model.rest_positions()[2] - 5e-4;
  Eigen::VectorXd x = wrapped_within_reach(model, rim, top);
  ASSERT_GT(x.size(), 0) << "no gap puts the chords within reach";
  std::mt19937 g(7);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  for (int i = 0; i < x.size(); ++i) x[i] += 2e-5 * u(g);
  const Term* edge_term = find_term(model, "disk_edge_contact");
  ASSERT_NE(edge_term, nullptr);
  expect_active_passes_equal_full_loops(model, *edge_term, x, p, rim_index);
  // the vertex barrier (NearDiskVertices): the flat state lowered into the barrier's reach for half of the
  // vertices, and a few of those beyond the rim's start moved just outside the rounded rim
  const Term* vertex_term = find_term(model, "disk_contact");
  ASSERT_NE(vertex_term, nullptr);
  Eigen::VectorXd y = model.rest_positions();
  const double inner = 0.09 - rim, zc = top - rim;
  int over_rim = 0;
  for (int i = 0; i < model.num_vertices(); ++i) {
    const double r = std::hypot(y[3 * i], y[3 * i + 1]);
    if (u(g) < 0) continue;
    y[3 * i + 2] -= 2e-4 * (1.0 + 0.5 * u(g));
    if (r > 0.07 && over_rim < 6) {
      const double psi = 0.7 * (1.0 + u(g)), gap = 2e-4 * (1.5 + u(g));  // on the tube, 0.1-0.5 mm off it
      y[3 * i] *= (inner + (rim + gap) * std::cos(psi)) / r;
      y[3 * i + 1] *= (inner + (rim + gap) * std::cos(psi)) / r;
      y[3 * i + 2] = zc + (rim + gap) * std::sin(psi);
      ++over_rim;
    }
  }
  ASSERT_EQ(over_rim, 6);
  expect_active_passes_equal_full_loops(model, *vertex_term, y, p, rim_index);
}

// The edge term's fused adjoint (disk_contact.cpp DiskEdgeBarrierTerm::add_step_adjoint: one pass over the active
// edges, each edge's minimiser found once) against Term's generic composition of the four products, bit for bit, on
// several random states of circle1 wrapped over the rim (edges within reach, at various dips and clearances) and
// at several rim radii (the rim part of gp); also on a state with no edge active (everything zero).
TEST(DiskEdge, FusedEdgeAdjointEqualsTheGenericProductsOnRandomStates) {
  ModelOptions o;
  o.effects["disk_contact"] = {{"clamp_radius_m", 0.02}};
  const Model model(load_cusick_template(1, testing::template_dir()), o);
  const int rim_index = model.layout().block("disk_contact.rim_radius_m").offset;
  const double top = model.rest_positions()[2] - 5e-4;
  const Term* edge_term = find_term(model, "disk_edge_contact");
  ASSERT_NE(edge_term, nullptr);
  int states = 0;
  for (const double rim : {0.0015, 0.002, 0.003}) {
    Eigen::VectorXd p = model.default_parameters();
    p[rim_index] = rim;
    const Eigen::VectorXd wrapped = wrapped_within_reach(model, rim, top);
    ASSERT_GT(wrapped.size(), 0) << "no gap puts the chords within reach (rim " << rim << ")";
    for (const unsigned seed : {1u, 2u, 3u}) {
      std::mt19937 g(seed);
      std::uniform_real_distribution<double> u(-1.0, 1.0);
      Eigen::VectorXd x = wrapped;
      const double jitter = 1e-5 * seed;
      for (int i = 0; i < x.size(); ++i) x[i] += jitter * u(g);
      if (!std::isfinite(edge_term->energy(x, p))) continue;  // a jitter that cut the rim: not a state
      expect_active_passes_equal_full_loops(model, *edge_term, x, p, rim_index);
      ++states;
    }
  }
  EXPECT_GE(states, 6);
  // nothing within reach: the rest state (the flat cloth 0.5 mm above the disk)
  const Eigen::VectorXd p = model.default_parameters(), x = model.rest_positions();
  const int n = static_cast<int>(x.size());
  Eigen::VectorXd gx = Eigen::VectorXd::Zero(n), gv = Eigen::VectorXd::Zero(n), gp = Eigen::VectorXd::Zero(p.size());
  ASSERT_TRUE(edge_term->add_step_adjoint(x, p, testing::random_vector(n, 1), testing::random_vector(n, 2), 0.05, gx,
                                          gv, gp));
  EXPECT_EQ(gx.norm() + gv.norm() + gp.norm(), 0.0);
}

// The disk friction's adjoint, start adjoint and step system visit only the vertices with a lagged normal force
// (disk_contact.cpp FrictionVertices): on a state with some vertices within the barrier's reach (and many not),
// they equal the full loops bit for bit.
TEST(DiskEdge, ActiveFrictionPassesEqualTheFullLoops) {
  ModelOptions o;
  o.effects["disk_contact"] = {{"clamp_radius_m", 0.02}};
  const Model model(make_cusick_specimen(60), o);
  const Eigen::VectorXd p = model.default_parameters();
  Term* friction = nullptr;
  for (const auto& t : model.terms())
    if (t->name() == "disk_friction") friction = t.get();
  ASSERT_NE(friction, nullptr);
  const int n = model.num_dofs();
  Eigen::VectorXd x = model.rest_positions();
  std::mt19937 rng(9);
  std::uniform_real_distribution<double> u01(0.0, 1.0);
  for (int i = 0; i < model.num_vertices(); ++i)
    if (u01(rng) < 0.5) x[3 * i + 2] -= 1e-4 + 2e-4 * u01(rng);  // half of them within reach
  const double h = 0.05;
  friction->begin_step(x, p, h);
  const Eigen::VectorXd y = x + 1e-4 * testing::random_vector(n, 21);  // slipped within the step
  const Eigen::VectorXd lambda = testing::random_vector(n, 22), w = testing::random_vector(n, 23),
                        v = testing::random_vector(n, 24), gx0 = testing::random_vector(n, 25);
  Eigen::VectorXd gx = gx0, gv = Eigen::VectorXd::Zero(n), gp = Eigen::VectorXd::Zero(p.size());
  ASSERT_TRUE(friction->add_step_adjoint(y, p, lambda, w, h, gx, gv, gp));
  Eigen::VectorXd gx_ref = gx0, gv_ref = Eigen::VectorXd::Zero(n), gp_ref = Eigen::VectorXd::Zero(p.size()),
                  Hl = Eigen::VectorXd::Zero(n);
  friction->add_hessian_product(y, p, lambda, Hl);
  gx_ref -= h * Hl;
  friction->add_step_matrix_derivatives(y, p, lambda, w, -h * h, gx_ref, gp_ref);
  friction->add_gradient_parameter_product(y, p, lambda, -h, gp_ref);
  ASSERT_TRUE(friction->add_step_matrix_product(y, p, lambda, -h * h, gv_ref));
  EXPECT_GT((gx - gx0).norm(), 0.0) << "no vertex with a normal force";
  EXPECT_NE(gp.norm(), 0.0);
  EXPECT_EQ((gx - gx_ref).lpNorm<Eigen::Infinity>(), 0.0);
  EXPECT_EQ((gv - gv_ref).lpNorm<Eigen::Infinity>(), 0.0);
  EXPECT_EQ((gp - gp_ref).lpNorm<Eigen::Infinity>(), 0.0);
  const int nnz = model.pattern().nnz();
  Eigen::VectorXd A = Eigen::VectorXd::Zero(nnz), Kv = Eigen::VectorXd::Zero(n), grad = Eigen::VectorXd::Zero(n);
  ASSERT_TRUE(friction->add_step_system(y, p, v, h * h, A, Kv, grad));
  Eigen::VectorXd A_ref = Eigen::VectorXd::Zero(nnz), Kv_ref = Eigen::VectorXd::Zero(n),
                  grad_ref = Eigen::VectorXd::Zero(n);
  friction->add_step_matrix(y, p, h * h, A_ref);
  friction->add_gradient(y, p, grad_ref);
  ASSERT_TRUE(friction->add_step_matrix_product(y, p, v, h * h, Kv_ref));
  EXPECT_GT(grad.norm(), 0.0);
  EXPECT_EQ((A - A_ref).lpNorm<Eigen::Infinity>(), 0.0);
  EXPECT_EQ((Kv - Kv_ref).lpNorm<Eigen::Infinity>(), 0.0);
  EXPECT_EQ((grad - grad_ref).lpNorm<Eigen::Infinity>(), 0.0);
}

}  // namespace
}  // namespace drapelab
