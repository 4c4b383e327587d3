// The IPC log barrier on a distance (Li et al., "Incremental Potential Contact", SIGGRAPH 2020, eq. 6):
//   b(d) = -(d - dhat)^2 ln(d / dhat)   for 0 < d < dhat,   0 for d >= dhat,
// dimensionless after division by dhat^2 (so b is O(1) at d = dhat / 2 whatever dhat is). b is C2 at d = dhat
// (b = b' = b'' = 0 there) and tends to +infinity as d -> 0, so an energy with this barrier stays finite
// only while no contact pair closes: a solver that keeps every step inside the finite region (a CCD step
// bound, contact/ccd.hpp) never lets surfaces pass through each other.
// Templated on the scalar so jets (util/jet.hpp) differentiate it; barrier_derivatives gives the closed
// forms for the hot loops (tested against each other and against central differences).
#pragma once
#include <cmath>

#include "util/jet.hpp"

namespace drapelab {

template <class T>
T log_of(const T& x) {
  using std::log;
  return log(x);
}
template <class T, int N>
Jet<T, N> log_of(const Jet<T, N>& x) {
  return chain(x, log_of(x.a), T(1.0) / x.a);
}

// b(d) / dhat^2 [1] for d > 0 (callers check d < dhat first: 0 beyond).
template <class T>
T barrier(const T& d, double dhat) {
  if (value_of(d) >= dhat) return T(0.0);
  const T s = (d - dhat) / dhat;
  return -(s * s) * log_of(d / dhat);
}

// b, db/dd and d2b/dd2 (all / dhat^2) in closed form.
inline void barrier_derivatives(double d, double dhat, double& b, double& db, double& d2b) {
  if (d >= dhat) {
    b = db = d2b = 0;
    return;
  }
  const double inv2 = 1.0 / (dhat * dhat), l = std::log(d / dhat), e = d - dhat;
  b = -e * e * l * inv2;
  db = (-2.0 * e * l - e * e / d) * inv2;
  d2b = (-2.0 * l - 4.0 * e / d + e * e / (d * d)) * inv2;
}

// The smoothed static/dynamic friction transition of IPC (eq. 14-15): with the tangential slip
// u = |relative tangential displacement| over a step and eps_u = eps_v h,
//   f0(u) = -u^3 / (3 eps_u^2) + u^2 / eps_u + eps_u / 3   for u < eps_u,   u for u >= eps_u,
// whose derivative f1(u) = f0'(u) rises from 0 to 1 over eps_u (Coulomb's law with a smoothed stick zone).
template <class T>
T friction_f0(const T& u, double eps_u) {
  if (value_of(u) >= eps_u) return u;
  return -(u * u * u) / (3.0 * eps_u * eps_u) + (u * u) / eps_u + eps_u / 3.0;
}
// f0 of a slip given by its square u2 = |u|^2, smooth at u = 0: there f0's odd term u^3 / (3 eps_u^2) is below
// round-off, and eps_u / 3 + u2 / eps_u keeps jets of u2 finite.
template <class T>
T friction_f0_of_squared(const T& u2, double eps_u) {
  if (value_of(u2) < 1e-20 * eps_u * eps_u) return eps_u / 3.0 + u2 / eps_u;
  using std::sqrt;
  return friction_f0(sqrt(u2), eps_u);
}
// f1(u) / u, finite at u = 0 (the factor of the friction force along the slip direction).
inline double friction_f1_over_u(double u, double eps_u) {
  if (u >= eps_u) return 1.0 / u;
  return -u / (eps_u * eps_u) + 2.0 / eps_u;
}
// d(f1(u)/u)/du * (1/u): for the friction Hessian along the slip direction (0 beyond eps_u where f1/u = 1/u
// gives -1/u^3, handled by the caller's projection).
inline double friction_f2_term(double u, double eps_u) {
  if (u >= eps_u) return -1.0 / (u * u * u);
  return -1.0 / (eps_u * eps_u * std::max(u, 1e-300));
}

// The friction potential's curvature in the slip u (3 x 3, row-major), per unit mu lambda:
//   S(u) = f1(|u|)/|u| (I - u u^T/|u|^2) + f1'(|u|) u u^T/|u|^2,   PSD since f1 >= 0, f1' >= 0,
// with its limit 2/eps_u I at u = 0 (below round-off of the slip). Templated for jets (step-matrix derivatives).
template <class T>
void friction_curvature(const T* u, double eps, T* S) {
  const T u2 = u[0] * u[0] + u[1] * u[1] + u[2] * u[2];
  for (int k = 0; k < 9; ++k) S[k] = T(0.0);
  if (value_of(u2) < 1e-20 * eps * eps) {
    for (int a = 0; a < 3; ++a) S[4 * a] = T(2.0 / eps);
    return;
  }
  using std::sqrt;
  const T un = sqrt(u2);
  T f1_over_u, df1;
  if (value_of(un) >= eps) {
    f1_over_u = 1.0 / un;
    df1 = T(0.0);
  } else {
    f1_over_u = -un / (eps * eps) + 2.0 / eps;
    df1 = -2.0 * un / (eps * eps) + 2.0 / eps;
  }
  for (int a = 0; a < 3; ++a)
    for (int b = 0; b < 3; ++b) {
      const T rr = u[a] * u[b] / u2;
      S[3 * a + b] = f1_over_u * ((a == b ? 1.0 : 0.0) - rr) + df1 * rr;
    }
}

}  // namespace drapelab
