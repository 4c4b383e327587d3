// The IPC barrier of one contact pair (point-triangle or edge-edge) as free-function kernels:
//   E(x) = kappa b(d(x)),   d = sqrt(d2(x)) the pair's unsigned distance (contact/distance.hpp, by
//   closest-feature type), b the log barrier of contact/barrier.hpp (divided by dhat^2), kappa [J].
// x: the pair's 4 vertices as 12 scalars ((p, a, b, c) or (a0, b0, a1, b1)). Gradient and Hessian are exact
// (closed-form barrier derivatives chained with the jet-exact distance derivatives); the Hessian can be
// projected onto the PSD cone (util/psd_projection.hpp). Each is checked against central differences in
// tests/native/contact/test_pair_barrier.cpp.
//
// Stiffness parametrised by the activation distance: kappa = c dhat (c [J/m]: contact terms take it from the
// pair's vertex weights, as disk_contact does), so that dhat, the cloth thickness, can be a fitted parameter;
// pair_barrier_dhat_derivatives gives dE/ddhat and d(grad E)/ddhat at fixed x for the parameter adjoints.
//
// Edge-edge pairs take IPC's mollifier (Li et al. 2020, sec. 4.3; ipc-toolkit's edge_edge_mollifier) when
// mollifier_eps > 0: E = m(x) kappa b(d) with c = |e0 x e1|^2 and m = (2 - c/eps) c/eps for c < eps, 1 beyond
// (C1 in c), eps = 1e-3 |e0_rest|^2 |e1_rest|^2. Nearly parallel edges then fade out of the barrier (their
// contact is carried by the point-triangle pairs of their end points), where the line-line distance's
// derivatives blow up and its closest-feature type flips (Newton bounced between them on stacked sheets).
#pragma once
#include <algorithm>
#include <cstdint>

#include "contact/barrier.hpp"

namespace drapelab {

enum class PairKind : uint8_t { kPointTriangle, kEdgeEdge };

// The closest-feature type of the pair at x (a PointTriangleType or EdgeEdgeType as int).
int pair_type(PairKind kind, const double* x);
// Squared distance of the pair at x for a given type [m^2].
double pair_distance2(PairKind kind, int type, const double* x);

// E [J] (+inf when d <= 0, 0 when d >= dhat).
double pair_barrier_energy(PairKind kind, int type, const double* x, double dhat, double kappa,
                   double mollifier_eps = 0);
// g (12) = dE/dx, overwritten.
void pair_barrier_gradient(PairKind kind, int type, const double* x, double dhat, double kappa, double* g,
                   double mollifier_eps = 0);
// H (12 x 12, row-major) = d2E/dx2, overwritten; projected onto the PSD cone if `project`.
void pair_barrier_hessian(PairKind kind, int type, const double* x, double dhat, double kappa, bool project, double* H,
                          double mollifier_eps = 0);
// With kappa = c dhat: dE/ddhat and dg (12) = d(dE/dx)/ddhat at fixed x.
void pair_barrier_dhat_derivatives(PairKind kind, int type, const double* x, double dhat, double c, double& dE,
                                   double* dg, double mollifier_eps = 0);
// The barrier's Gauss-Newton step matrix (the PSD matrix of linearised implicit steps, solver/implicit_euler.hpp):
//   K = s r r^T,  r = grad d (12),  s = m kappa b''(max(d, d_floor)) >= 0   (b'' >= 0 on (0, dhat); m the
// mollifier; d_floor = kGaussNewtonDistanceFloor dhat), dropping kappa b'(d) Hess d and the mollifier's
// derivatives from the exact Hessian. Fills r and s (r = 0, s = 0 beyond dhat).
// The floor: b'' ~ 1/d^2 grows without bound as a pair closes, and a moving obstacle's carry can pinch a pair
// by 90 % per advance (each advance is bounded only by CCD), down to 1e-13 m: s ~ 1e18-1e22 N/m beside the
// inertia M/h^2 ~ 0.3 N/m, a matrix that is PSD but whose Cholesky factorisation fails on round-off (measured on
// a walking skirt, docs/lab/garment-speed.md). Below d_floor the step matrix keeps the curvature at d_floor: still
// PSD, with s / (m / h^2) <= g h^2 / (floor^2 dhat) for a pair whose stiffness is its vertices' weight (about 2e4
// for a garment's 1/96 s steps and 0.56 mm reach); a softer model there, so the move it gives opens the pinched
// pair by about d_floor^2 / d instead of d, and the body's next advance finds room (the gradient stays exact).
// Resting layers sit near dhat / 2 (their barrier carries their weight), far above the floor. Measured floors:
// 1e-4 left the gap cycling below 2e-7 m and a walking skirt's body stuck; 1e-3 and 1e-2 both cleared the pinches,
// 1e-2 in fewer linear solves (docs/lab/garment-speed.md).
constexpr double kGaussNewtonDistanceFloor = 1e-2;  // d_floor / dhat
// b''(max(d, d_floor)) / dhat^2 (barrier_derivatives' scaling): the curvature step matrices use (the body's
// too, garment/revolved_body.hpp).
inline double barrier_step_curvature(double d, double dhat) {
  double b, db, d2b;
  barrier_derivatives(std::max(d, kGaussNewtonDistanceFloor * dhat), dhat, b, db, d2b);
  return d2b;
}
void pair_barrier_gauss_newton(PairKind kind, int type, const double* x, double dhat, double kappa, double* r,
                               double& s, double mollifier_eps = 0);
// With kappa = c dhat, for fixed l and w (12 each): phi = l^T K(x, dhat) w; dphi (12) = dphi/dx, dphi_ddhat.
void pair_barrier_gauss_newton_derivatives(PairKind kind, int type, const double* x, double dhat, double c,
                                           const double* l, const double* w, double* dphi, double& dphi_ddhat,
                                           double mollifier_eps = 0);
// The edge-edge mollifier m(x) in [0, 1] (1 for point-triangle pairs or mollifier_eps <= 0).
double pair_mollifier(PairKind kind, const double* x, double mollifier_eps);

}  // namespace drapelab
