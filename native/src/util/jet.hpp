// Forward-mode dual numbers ("jets"), nestable: Jet<Jet<double, 1>, 12> gives Hessian-vector products.
//
// Used to derive every per-element derivative (gradient, Hessian, parameter gradients, and the
// x-derivative of the step matrix needed by the adjoint) from one templated energy per term, so
// that each derivative is exact by construction and checked once by finite differences.
#pragma once
#include <array>
#include <cmath>
#include <type_traits>

namespace drapelab {

template <class T, int N>
struct Jet {
  T a{};                 // value
  std::array<T, N> v{};  // derivatives along N seeded directions

  Jet() = default;
  Jet(const T& x) : a(x) {}  // NOLINT: constants promote implicitly
  template <class U = T, class = std::enable_if_t<!std::is_same<U, double>::value>>
  Jet(double x) : a(x) {}  // NOLINT
  Jet(const T& x, int k) : a(x) { v[k] = T(1.0); }
  static Jet variable(const T& x, int k) { return Jet(x, k); }
};

template <class T>
struct is_jet : std::false_type {};
template <class T, int N>
struct is_jet<Jet<T, N>> : std::true_type {};

inline double value_of(double x) { return x; }
template <class T, int N>
double value_of(const Jet<T, N>& x) { return value_of(x.a); }

#define DRAPELAB_JET_BINARY(OP, AEXPR, VEXPR)                                 \
  template <class T, int N>                                                   \
  Jet<T, N> operator OP(const Jet<T, N>& x, const Jet<T, N>& y) {             \
    Jet<T, N> r;                                                              \
    r.a = AEXPR;                                                              \
    for (int i = 0; i < N; ++i) r.v[i] = VEXPR;                               \
    return r;                                                                 \
  }
DRAPELAB_JET_BINARY(+, x.a + y.a, x.v[i] + y.v[i])
DRAPELAB_JET_BINARY(-, x.a - y.a, x.v[i] - y.v[i])
DRAPELAB_JET_BINARY(*, x.a * y.a, x.v[i] * y.a + x.a * y.v[i])
#undef DRAPELAB_JET_BINARY

template <class T, int N>
Jet<T, N> operator/(const Jet<T, N>& x, const Jet<T, N>& y) {
  Jet<T, N> r;
  const T inv = T(1.0) / y.a;
  r.a = x.a * inv;
  for (int i = 0; i < N; ++i) r.v[i] = (x.v[i] - r.a * y.v[i]) * inv;
  return r;
}
template <class T, int N>
Jet<T, N> operator-(const Jet<T, N>& x) {
  Jet<T, N> r;
  r.a = -x.a;
  for (int i = 0; i < N; ++i) r.v[i] = -x.v[i];
  return r;
}
// Mixed with plain doubles.
template <class T, int N>
Jet<T, N> operator+(const Jet<T, N>& x, double y) { Jet<T, N> r = x; r.a = r.a + y; return r; }
template <class T, int N>
Jet<T, N> operator+(double y, const Jet<T, N>& x) { return x + y; }
template <class T, int N>
Jet<T, N> operator-(const Jet<T, N>& x, double y) { Jet<T, N> r = x; r.a = r.a - y; return r; }
template <class T, int N>
Jet<T, N> operator-(double y, const Jet<T, N>& x) { return -(x - y); }
template <class T, int N>
Jet<T, N> operator*(const Jet<T, N>& x, double y) {
  Jet<T, N> r;
  r.a = x.a * y;
  for (int i = 0; i < N; ++i) r.v[i] = x.v[i] * y;
  return r;
}
template <class T, int N>
Jet<T, N> operator*(double y, const Jet<T, N>& x) { return x * y; }
template <class T, int N>
Jet<T, N> operator/(const Jet<T, N>& x, double y) { return x * (1.0 / y); }
template <class T, int N>
Jet<T, N> operator/(double y, const Jet<T, N>& x) { return Jet<T, N>(y) / x; }

template <class T, int N, class U>
Jet<T, N>& operator+=(Jet<T, N>& x, const U& y) { return x = x + y; }
template <class T, int N, class U>
Jet<T, N>& operator-=(Jet<T, N>& x, const U& y) { return x = x - y; }
template <class T, int N, class U>
Jet<T, N>& operator*=(Jet<T, N>& x, const U& y) { return x = x * y; }

// Chain rule helper: f(x) with f'(x) = d.
template <class T, int N>
Jet<T, N> chain(const Jet<T, N>& x, const T& f, const T& d) {
  Jet<T, N> r;
  r.a = f;
  for (int i = 0; i < N; ++i) r.v[i] = d * x.v[i];
  return r;
}

using std::atan2;
using std::cos;
using std::sin;
using std::sqrt;

template <class T, int N>
Jet<T, N> sin(const Jet<T, N>& x) { return chain(x, sin(x.a), cos(x.a)); }
template <class T, int N>
Jet<T, N> cos(const Jet<T, N>& x) { return chain(x, cos(x.a), -sin(x.a)); }
template <class T, int N>
Jet<T, N> sqrt(const Jet<T, N>& x) {
  const T s = sqrt(x.a);
  return chain(x, s, T(0.5) / s);
}
template <class T, int N>
Jet<T, N> atan2(const Jet<T, N>& y, const Jet<T, N>& x) {
  // d atan2(y, x) = (x dy - y dx) / (x^2 + y^2)
  Jet<T, N> r;
  r.a = atan2(y.a, x.a);
  const T inv = T(1.0) / (x.a * x.a + y.a * y.a);
  for (int i = 0; i < N; ++i) r.v[i] = (x.a * y.v[i] - y.a * x.v[i]) * inv;
  return r;
}

// C1 blend of a fraction f in [0, 1]: s(0) = 0, s(1) = 1, s'(0) = s'(1) = 0.
template <class T>
T smoothstep(const T& f) {
  return f * f * (3.0 - 2.0 * f);
}

}  // namespace drapelab
