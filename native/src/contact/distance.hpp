// Unsigned distances between mesh primitives and to the Cusick support disk, with exact derivatives.
//
// As in IPC (Li et al. 2020, sec. 4.1 and its ipc-toolkit), a pair's closest-feature *type* is chosen in
// floating point first (point-point, point-edge, point-plane; line-line for two edges), then the squared
// distance is the smooth formula of that type, so that every formula is differentiated where it applies and
// the distance is C1 across type changes. Kernels are templated on the scalar so that jets (util/jet.hpp)
// give gradients and Hessians exact by construction; `distance_gradient_hessian` does that for any kernel.
// All lengths in metres, squared distances in m^2.
//
// Known approximation: two nearly parallel edges whose closest points are interior fall back to the nearest
// point-edge type (ipc-toolkit instead multiplies their barrier by a mollifier); the distance is still
// exact, only its derivative jumps where the fallback switches on (|e0 x e1|^2 < 1e-10 |e0|^2 |e1|^2).
#pragma once
#include <Eigen/Core>
#include <algorithm>
#include <array>

#include "util/jet.hpp"

namespace drapelab {

template <class T>
using Vec3 = std::array<T, 3>;

template <class T>
Vec3<T> sub(const Vec3<T>& a, const Vec3<T>& b) { return {a[0] - b[0], a[1] - b[1], a[2] - b[2]}; }
template <class T>
T dot(const Vec3<T>& a, const Vec3<T>& b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
template <class T>
Vec3<T> cross(const Vec3<T>& a, const Vec3<T>& b) {
  return {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
}

// Squared distances of the smooth types.
template <class T>
T point_point_distance2(const Vec3<T>& p, const Vec3<T>& a) {
  const Vec3<T> d = sub(p, a);
  return dot(d, d);
}
// To the infinite line through a, b.
template <class T>
T point_line_distance2(const Vec3<T>& p, const Vec3<T>& a, const Vec3<T>& b) {
  const Vec3<T> e = sub(b, a), c = cross(e, sub(p, a));
  return dot(c, c) / dot(e, e);
}
// To the plane through a, b, c.
template <class T>
T point_plane_distance2(const Vec3<T>& p, const Vec3<T>& a, const Vec3<T>& b, const Vec3<T>& c) {
  const Vec3<T> n = cross(sub(b, a), sub(c, a));
  const T s = dot(n, sub(p, a));
  return s * s / dot(n, n);
}
// Between the infinite lines through (a0, b0) and (a1, b1) (not parallel).
template <class T>
T line_line_distance2(const Vec3<T>& a0, const Vec3<T>& b0, const Vec3<T>& a1, const Vec3<T>& b1) {
  const Vec3<T> n = cross(sub(b0, a0), sub(b1, a1));
  const T s = dot(n, sub(a1, a0));
  return s * s / dot(n, n);
}

// Closest-feature types. Point-triangle: the point against vertex A/B/C, edge AB/BC/CA or the face.
enum class PointTriangleType { kA, kB, kC, kAB, kBC, kCA, kFace };
// Edge-edge (edges a0b0 and a1b1): line-line, or one edge's endpoint against the other edge (as a point-edge
// or point-point pair).
enum class EdgeEdgeType {
  kLineLine,
  kA0_E1, kB0_E1, kA1_E0, kB1_E0,          // endpoint against the other edge's interior
  kA0_A1, kA0_B1, kB0_A1, kB0_B1           // endpoint against endpoint
};

PointTriangleType point_triangle_type(const Eigen::Vector3d& p, const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                                      const Eigen::Vector3d& c);
EdgeEdgeType edge_edge_type(const Eigen::Vector3d& a0, const Eigen::Vector3d& b0, const Eigen::Vector3d& a1,
                            const Eigen::Vector3d& b1);

// Squared distance of a point-triangle pair of the given type; x = (p, a, b, c) as 12 scalars.
template <class T>
T point_triangle_distance2(PointTriangleType type, const T* x) {
  const Vec3<T> p{x[0], x[1], x[2]}, a{x[3], x[4], x[5]}, b{x[6], x[7], x[8]}, c{x[9], x[10], x[11]};
  switch (type) {
    case PointTriangleType::kA: return point_point_distance2(p, a);
    case PointTriangleType::kB: return point_point_distance2(p, b);
    case PointTriangleType::kC: return point_point_distance2(p, c);
    case PointTriangleType::kAB: return point_line_distance2(p, a, b);
    case PointTriangleType::kBC: return point_line_distance2(p, b, c);
    case PointTriangleType::kCA: return point_line_distance2(p, c, a);
    case PointTriangleType::kFace: break;
  }
  return point_plane_distance2(p, a, b, c);
}
// Squared distance of an edge-edge pair of the given type; x = (a0, b0, a1, b1) as 12 scalars.
template <class T>
T edge_edge_distance2(EdgeEdgeType type, const T* x) {
  const Vec3<T> a0{x[0], x[1], x[2]}, b0{x[3], x[4], x[5]}, a1{x[6], x[7], x[8]}, b1{x[9], x[10], x[11]};
  switch (type) {
    case EdgeEdgeType::kLineLine: break;
    case EdgeEdgeType::kA0_E1: return point_line_distance2(a0, a1, b1);
    case EdgeEdgeType::kB0_E1: return point_line_distance2(b0, a1, b1);
    case EdgeEdgeType::kA1_E0: return point_line_distance2(a1, a0, b0);
    case EdgeEdgeType::kB1_E0: return point_line_distance2(b1, a0, b0);
    case EdgeEdgeType::kA0_A1: return point_point_distance2(a0, a1);
    case EdgeEdgeType::kA0_B1: return point_point_distance2(a0, b1);
    case EdgeEdgeType::kB0_A1: return point_point_distance2(b0, a1);
    case EdgeEdgeType::kB0_B1: return point_point_distance2(b0, b1);
  }
  return line_line_distance2(a0, b0, a1, b1);
}

// The Cusick support disk as a solid: a flat disk of radius R - rho in the plane z = z_top - rho, swept by a
// ball of radius rho (a plate of thickness 2 rho whose rim is a half torus of radius rho). Distance of a point
// outside it to its surface [m]: C1 everywhere off the plate's axis.
struct SupportDisk {
  double radius = 0.09;       // R [m]: the support disk's radius (Cusick: 18 cm diameter)
  double rim_radius = 0.002;  // rho [m]: the rounding of its edge (half its thickness)
  double top = 0.0;           // z of its upper face [m]
};
template <class T>
T support_disk_distance(const SupportDisk& disk, const T* x) {
  using std::abs;
  using std::sqrt;
  const double inner = disk.radius - disk.rim_radius, zc = disk.top - disk.rim_radius;
  const T dz = x[2] - zc;
  const T r2 = x[0] * x[0] + x[1] * x[1];
  if (value_of(r2) <= inner * inner) return (value_of(dz) >= 0 ? dz : -dz) - disk.rim_radius;
  const T dr = sqrt(r2) - inner;
  return sqrt(dr * dr + dz * dz) - disk.rim_radius;
}

// Value, gradient (N) and Hessian (N x N, row-major) of f(x) for a kernel f templated on the scalar.
template <int N, class F>
void distance_gradient_hessian(const F& f, const double* x, double& value, double* gradient, double* hessian) {
  using Inner = Jet<double, N>;
  using Outer = Jet<Inner, N>;
  Outer xs[N];
  for (int i = 0; i < N; ++i) {
    xs[i] = Outer(Inner(x[i], i), i);
  }
  const Outer r = f(xs);
  value = r.a.a;
  for (int i = 0; i < N; ++i) {
    gradient[i] = r.a.v[i];
    for (int j = 0; j < N; ++j) hessian[i * N + j] = r.v[i].v[j];
  }
}

}  // namespace drapelab
