// Forward-mode dual numbers with three derivative components (d/dx, d/dy, d/dz), for exact field gradients.
//
// A field node written once as a template over its scalar type T evaluates with T = double (value only) or
// T = Dual (value and gradient). Helpers value_of, tmin, tmax and select work for both, so templated code never
// compares Duals directly. Non-differentiable points get a one-sided choice: sqrt(0) has derivative 0 (the
// caller's formula then picks another term), abs(0) and min/max ties take the first argument's derivative.
#pragma once

#include <cmath>

// Forces inlining of the tiny arithmetic helpers: GCC otherwise leaves some of them out of line in deep templates,
// which costs several times the arithmetic itself.
#if defined(__GNUC__)
#define SURFACER_FORCE_INLINE inline __attribute__((always_inline))
#else
#define SURFACER_FORCE_INLINE inline
#endif

namespace surfacer {

struct Dual {
  double v = 0.0;
  double d[3] = {0.0, 0.0, 0.0};

  constexpr Dual() = default;
  constexpr Dual(double value) : v(value) {}  // NOLINT(google-explicit-constructor): constants mix freely
  constexpr Dual(double value, double dx, double dy, double dz) : v(value), d{dx, dy, dz} {}

  // The independent variable number `axis` (0, 1 or 2) at `value`.
  static constexpr Dual variable(double value, int axis) {
    return Dual(value, axis == 0 ? 1.0 : 0.0, axis == 1 ? 1.0 : 0.0, axis == 2 ? 1.0 : 0.0);
  }

  Dual& operator+=(const Dual& o);
  Dual& operator-=(const Dual& o);
  Dual& operator*=(const Dual& o);
  Dual& operator*=(double s);
};

// Applies the chain rule for a unary function with value `fv` and derivative `df` at a.v.
SURFACER_FORCE_INLINE Dual chain(const Dual& a, double fv, double df) {
  return Dual(fv, df * a.d[0], df * a.d[1], df * a.d[2]);
}

// Every operation builds its result from four scalars (no loops over d[], no in-place partial writes): this keeps
// Duals in registers and avoids store-forwarding stalls when they are copied.
SURFACER_FORCE_INLINE Dual operator-(const Dual& a) { return Dual(-a.v, -a.d[0], -a.d[1], -a.d[2]); }
SURFACER_FORCE_INLINE Dual operator+(const Dual& a, const Dual& b) {
  return Dual(a.v + b.v, a.d[0] + b.d[0], a.d[1] + b.d[1], a.d[2] + b.d[2]);
}
SURFACER_FORCE_INLINE Dual operator-(const Dual& a, const Dual& b) {
  return Dual(a.v - b.v, a.d[0] - b.d[0], a.d[1] - b.d[1], a.d[2] - b.d[2]);
}
SURFACER_FORCE_INLINE Dual operator*(const Dual& a, const Dual& b) {
  return Dual(a.v * b.v, a.d[0] * b.v + a.v * b.d[0], a.d[1] * b.v + a.v * b.d[1], a.d[2] * b.v + a.v * b.d[2]);
}
SURFACER_FORCE_INLINE Dual operator/(const Dual& a, const Dual& b) {
  const double inv = 1.0 / b.v;
  const double q = a.v * inv;
  return Dual(q, (a.d[0] - q * b.d[0]) * inv, (a.d[1] - q * b.d[1]) * inv, (a.d[2] - q * b.d[2]) * inv);
}
SURFACER_FORCE_INLINE Dual operator+(const Dual& a, double b) { return Dual(a.v + b, a.d[0], a.d[1], a.d[2]); }
SURFACER_FORCE_INLINE Dual operator+(double a, const Dual& b) { return Dual(a + b.v, b.d[0], b.d[1], b.d[2]); }
SURFACER_FORCE_INLINE Dual operator-(const Dual& a, double b) { return Dual(a.v - b, a.d[0], a.d[1], a.d[2]); }
SURFACER_FORCE_INLINE Dual operator-(double a, const Dual& b) { return Dual(a - b.v, -b.d[0], -b.d[1], -b.d[2]); }
SURFACER_FORCE_INLINE Dual operator*(const Dual& a, double b) {
  return Dual(a.v * b, a.d[0] * b, a.d[1] * b, a.d[2] * b);
}
SURFACER_FORCE_INLINE Dual operator*(double a, const Dual& b) { return b * a; }
SURFACER_FORCE_INLINE Dual operator/(const Dual& a, double b) { return a * (1.0 / b); }
SURFACER_FORCE_INLINE Dual operator/(double a, const Dual& b) { return Dual(a) / b; }

SURFACER_FORCE_INLINE Dual& Dual::operator+=(const Dual& o) { return *this = *this + o; }
SURFACER_FORCE_INLINE Dual& Dual::operator-=(const Dual& o) { return *this = *this - o; }
SURFACER_FORCE_INLINE Dual& Dual::operator*=(const Dual& o) { return *this = *this * o; }
SURFACER_FORCE_INLINE Dual& Dual::operator*=(double s) { return *this = *this * s; }

SURFACER_FORCE_INLINE Dual sqrt(const Dual& a) {
  const double s = std::sqrt(a.v);
  return chain(a, s, s > 0.0 ? 0.5 / s : 0.0);
}
SURFACER_FORCE_INLINE Dual sin(const Dual& a) { return chain(a, std::sin(a.v), std::cos(a.v)); }
SURFACER_FORCE_INLINE Dual cos(const Dual& a) { return chain(a, std::cos(a.v), -std::sin(a.v)); }
SURFACER_FORCE_INLINE Dual exp(const Dual& a) {
  const double e = std::exp(a.v);
  return chain(a, e, e);
}
SURFACER_FORCE_INLINE Dual abs(const Dual& a) { return a.v < 0.0 ? -a : a; }

// Scalar-generic helpers (T = double or Dual).
SURFACER_FORCE_INLINE double value_of(double a) { return a; }
SURFACER_FORCE_INLINE double value_of(const Dual& a) { return a.v; }

template <class T>
SURFACER_FORCE_INLINE T tmin(const T& a, const T& b) {
  return value_of(a) <= value_of(b) ? a : b;
}
template <class T>
SURFACER_FORCE_INLINE T tmax(const T& a, const T& b) {
  return value_of(a) >= value_of(b) ? a : b;
}
template <class T>
SURFACER_FORCE_INLINE T tabs(const T& a) {
  using std::abs;
  return abs(a);
}
template <class T>
SURFACER_FORCE_INLINE T tsqrt(const T& a) {
  using std::sqrt;
  return sqrt(a);
}
template <class T>
SURFACER_FORCE_INLINE T tclamp(const T& a, double lo, double hi) {
  if (value_of(a) < lo) return T(lo);
  if (value_of(a) > hi) return T(hi);
  return a;
}

}  // namespace surfacer
