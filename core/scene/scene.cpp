// Primitives, CSG and affine transforms (core/scene/scene.h). Blobs: blobs.cpp; sampled grids: sampled_grid.cpp.
//
// Each primitive is written once as a template over its scalar type; value() runs it with double and
// value_and_gradient() with the forward-mode Dual of core/scene/dual.h, so both share one formula and the gradient is
// exact. Interior nodes (CSG, transforms) combine their children's values and gradients with the chain rule.
#include "core/scene/scene.h"

#include <Eigen/LU>
#include <Eigen/SVD>
#include <algorithm>
#include <array>
#include <cmath>
#include <numbers>
#include <string>
#include <utility>

#include "core/scene/dual.h"
#include "core/util/checks.h"
#include "core/util/errors.h"

namespace surfacer {
namespace {

// --- A tiny 3-vector over the scalar type ------------------------------------------------------------------
template <class T>
struct V3 {
  T x, y, z;
};

template <class T>
SURFACER_FORCE_INLINE V3<T> operator-(const V3<T>& a, const Vec3& b) {
  return {a.x - b.x(), a.y - b.y(), a.z - b.z()};
}
template <class T>
SURFACER_FORCE_INLINE V3<T> operator-(const V3<T>& a, const V3<T>& b) {
  return {a.x - b.x, a.y - b.y, a.z - b.z};
}
template <class T>
SURFACER_FORCE_INLINE V3<T> scaled(const Vec3& v, const T& s) {  // v * s
  return {s * v.x(), s * v.y(), s * v.z()};
}
template <class T>
SURFACER_FORCE_INLINE T dot(const V3<T>& a, const Vec3& b) {
  return a.x * b.x() + a.y * b.y() + a.z * b.z();
}
template <class T>
SURFACER_FORCE_INLINE T length(const V3<T>& a) {
  return tsqrt(a.x * a.x + a.y * a.y + a.z * a.z);
}
template <class T>
SURFACER_FORCE_INLINE T length2(const T& a, const T& b) {
  return tsqrt(a * a + b * b);
}

// Signed distance of a box-like shape from per-axis offsets q_i = |p_i| - half_i (any number of axes): inside,
// the largest offset (a face plane); outside, the length of the positive offsets. Branching (rather than
// length(max(q,0)) + min(max q, 0)) keeps the gradient right on the surface itself.
template <class T, std::size_t N>
SURFACER_FORCE_INLINE T box_like(const std::array<T, N>& q) {
  bool outside = false;
  for (const T& qi : q) outside = outside || value_of(qi) > 0.0;
  if (!outside) {
    T m = q[0];
    for (std::size_t i = 1; i < N; ++i) m = tmax(m, q[i]);
    return m;
  }
  T s(0.0);
  for (const T& qi : q) {
    if (value_of(qi) > 0.0) s = s + qi * qi;
  }
  return tsqrt(s);
}

// Shared plumbing: Derived provides `template <class T> T eval(const V3<T>& p) const`.
template <class Derived>
class TemplatedField : public SceneField {
 public:
  double value(const Vec3& p) const final {
    return static_cast<const Derived*>(this)->eval(V3<double>{p.x(), p.y(), p.z()});
  }
  double value_and_gradient(const Vec3& p, Vec3& gradient) const final {
    const V3<Dual> q{Dual::variable(p.x(), 0), Dual::variable(p.y(), 1), Dual::variable(p.z(), 2)};
    const Dual r = static_cast<const Derived*>(this)->eval(q);
    gradient = Vec3(r.d[0], r.d[1], r.d[2]);
    return r.v;
  }
  // The primitives are signed distances, whose value grows without bound away from the solid (plane and gyroid
  // excepted).
  double sublevel_limit() const override { return std::numeric_limits<double>::infinity(); }
};

// Box of a disk of radius r centred at c, perpendicular to the unit vector u.
Aabb disk_box(const Vec3& c, const Vec3& u, double r) {
  Vec3 e;
  for (int i = 0; i < 3; ++i) e[i] = r * std::sqrt(std::max(0.0, 1.0 - u[i] * u[i]));
  return Aabb{c - e, c + e};
}

// --- Primitives ----------------------------------------------------------------------------------------------
class Sphere final : public TemplatedField<Sphere> {
 public:
  std::optional<double> lipschitz_bound() const override { return 1.0; }  // exact signed distance
  Sphere(const Vec3& c, double r) : center_(c), radius_(r) {}
  template <class T>
  T eval(const V3<T>& p) const {
    return length(p - center_) - radius_;
  }
  // Exact signed distances: {value <= level} is the solid grown by level.
  std::optional<Aabb> sublevel_bounds(double level) const override {
    return Aabb{center_.array() - radius_, center_.array() + radius_}.padded(level);
  }

 private:
  Vec3 center_;
  double radius_;
};

// Rounded box with outer half extents h and edge radius r (r = 0: sharp box). Quilez, "sdRoundBox".
class RoundedBox final : public TemplatedField<RoundedBox> {
 public:
  std::optional<double> lipschitz_bound() const override { return 1.0; }  // exact signed distance
  RoundedBox(const Vec3& c, const Vec3& h, double r) : center_(c), half_size_(h), radius_(r) {}
  template <class T>
  T eval(const V3<T>& p) const {
    const V3<T> d = p - center_;
    return box_like(std::array<T, 3>{tabs(d.x) - (half_size_.x() - radius_), tabs(d.y) - (half_size_.y() - radius_),
                                     tabs(d.z) - (half_size_.z() - radius_)}) -
           radius_;
  }
  std::optional<Aabb> sublevel_bounds(double level) const override {
    return Aabb{center_ - half_size_, center_ + half_size_}.padded(level);
  }

 private:
  Vec3 center_, half_size_;
  double radius_;
};

// Capped cylinder: a 2-D box in (radial distance, axial offset from the middle).
class Cylinder final : public TemplatedField<Cylinder> {
 public:
  std::optional<double> lipschitz_bound() const override { return 1.0; }  // exact signed distance
  Cylinder(const Vec3& a, const Vec3& b, double r)
      : end0_(a),
        end1_(b),
        middle_((a + b) * 0.5),
        axis_((b - a).normalized()),
        half_(0.5 * (b - a).norm()),
        radius_(r) {}
  template <class T>
  T eval(const V3<T>& p) const {
    const V3<T> w = p - middle_;
    const T y = dot(w, axis_);
    const T radial = length(w - scaled(axis_, y));
    return box_like(std::array<T, 2>{radial - radius_, tabs(y) - half_});
  }
  std::optional<Aabb> sublevel_bounds(double level) const override {
    return merged(disk_box(end0_, axis_, radius_), disk_box(end1_, axis_, radius_)).padded(level);
  }

 private:
  Vec3 end0_, end1_, middle_, axis_;
  double half_, radius_;
};

// Capped truncated cone. In the half-plane (r = radial distance >= 0, y = axial coordinate from a) the solid is
// the trapezoid (0,0) (ra,0) (rb,L) (0,L), whose mirror image across r = 0 makes it convex; so the exact signed
// distance is the largest edge-line distance inside and the distance to the nearest of the three edges
// (bottom cap, side, top cap) outside. Equivalent to Quilez's sdCappedCone but linear near each face, which keeps
// the gradient defined on the surface.
class Cone final : public TemplatedField<Cone> {
 public:
  std::optional<double> lipschitz_bound() const override { return 1.0; }  // exact signed distance
  Cone(const Vec3& a, const Vec3& b, double ra, double rb)
      : end0_(a), end1_(b), axis_((b - a).normalized()), len_((b - a).norm()), ra_(ra), rb_(rb) {
    const double side = std::hypot(len_, ra_ - rb_);
    nr_ = len_ / side;  // outward side normal (r, y components)
    ny_ = (ra_ - rb_) / side;
    er_ = rb_ - ra_;  // side edge direction (ra,0) -> (rb,L)
    ey_ = len_;
    inv_ee_ = 1.0 / (er_ * er_ + ey_ * ey_);
  }
  template <class T>
  T eval(const V3<T>& p) const {
    const V3<T> w = p - end0_;
    const T y = dot(w, axis_);
    const T r = length(w - scaled(axis_, y));
    const T d_bottom = -y;
    const T d_top = y - len_;
    const T d_side = (r - ra_) * nr_ + y * ny_;
    if (value_of(d_bottom) <= 0.0 && value_of(d_top) <= 0.0 && value_of(d_side) <= 0.0) {
      return tmax(tmax(d_bottom, d_top), d_side);
    }
    const T bottom = value_of(r) <= ra_ ? tabs(y) : length2(r - ra_, y);
    const T top = value_of(r) <= rb_ ? tabs(d_top) : length2(r - rb_, d_top);
    const double t = ((value_of(r) - ra_) * er_ + value_of(y) * ey_) * inv_ee_;
    const T side = t <= 0.0 ? length2(r - ra_, y) : (t >= 1.0 ? length2(r - rb_, d_top) : tabs(d_side));
    return tmin(tmin(bottom, top), side);
  }
  std::optional<Aabb> sublevel_bounds(double level) const override {
    return merged(disk_box(end0_, axis_, ra_), disk_box(end1_, axis_, rb_)).padded(level);
  }

 private:
  Vec3 end0_, end1_, axis_;
  double len_, ra_, rb_;
  double nr_ = 0, ny_ = 0, er_ = 0, ey_ = 0, inv_ee_ = 0;
};

class Torus final : public TemplatedField<Torus> {
 public:
  std::optional<double> lipschitz_bound() const override { return 1.0; }  // exact signed distance
  Torus(const Vec3& c, const Vec3& axis, double major, double minor)
      : center_(c), axis_(axis.normalized()), major_(major), minor_(minor) {}
  template <class T>
  T eval(const V3<T>& p) const {
    const V3<T> w = p - center_;
    const T h = dot(w, axis_);
    const T rho = length(w - scaled(axis_, h));
    return length2(rho - major_, h) - minor_;
  }
  std::optional<Aabb> sublevel_bounds(double level) const override {
    return disk_box(center_, axis_, major_).padded(minor_ + level);
  }

 private:
  Vec3 center_, axis_;
  double major_, minor_;
};

class Plane final : public TemplatedField<Plane> {
 public:
  std::optional<double> lipschitz_bound() const override { return 1.0; }  // exact signed distance
  Plane(const Vec3& normal, double offset) : normal_(normal.normalized()), offset_(offset / normal.norm()) {}
  template <class T>
  T eval(const V3<T>& p) const {
    return dot(p, normal_) - offset_;
  }
  std::optional<Aabb> sublevel_bounds(double) const override { return std::nullopt; }
  double sublevel_limit() const override { return -std::numeric_limits<double>::infinity(); }

 private:
  Vec3 normal_;
  double offset_;
};

class Capsule final : public TemplatedField<Capsule> {
 public:
  std::optional<double> lipschitz_bound() const override { return 1.0; }  // exact signed distance
  Capsule(const Vec3& a, const Vec3& b, double r) : end0_(a), end1_(b), ba_(b - a), radius_(r) {
    const double baba = ba_.squaredNorm();
    inv_baba_ = baba > 0.0 ? 1.0 / baba : 0.0;
  }
  template <class T>
  T eval(const V3<T>& p) const {
    const V3<T> w = p - end0_;
    const T t = tclamp(dot(w, ba_) * inv_baba_, 0.0, 1.0);
    return length(w - scaled(ba_, t)) - radius_;
  }
  std::optional<Aabb> sublevel_bounds(double level) const override {
    return Aabb{end0_.cwiseMin(end1_), end0_.cwiseMax(end1_)}.padded(radius_ + level);
  }

 private:
  Vec3 end0_, end1_, ba_;
  double radius_, inv_baba_;
};

// Gyroid sheet |g|/k - thickness/2, g = sin(kx)cos(ky) + sin(ky)cos(kz) + sin(kz)cos(kx), k = 2 pi / period.
// |g|/k is a first-order distance estimate to the minimal surface g = 0 (|grad g| <= ~1.2 k), not exact.
class Gyroid final : public TemplatedField<Gyroid> {
 public:
  // |grad g|^2 / k^2 = sum over the three cyclic terms of (cos x cos y - sin x sin z)^2 <= (cos^2 y + sin^2 z)
  // (Cauchy-Schwarz), and those sum to 3: |grad (|g| / k)| <= sqrt(3).
  std::optional<double> lipschitz_bound() const override { return std::sqrt(3.0); }
  Gyroid(double period, double thickness)
      : wavenumber_(2.0 * std::numbers::pi / period), half_thickness_(0.5 * thickness) {}
  template <class T>
  T eval(const V3<T>& p) const {
    using std::cos;
    using std::sin;
    const T x = p.x * wavenumber_, y = p.y * wavenumber_, z = p.z * wavenumber_;
    const T g = sin(x) * cos(y) + sin(y) * cos(z) + sin(z) * cos(x);
    return tabs(g) * (1.0 / wavenumber_) - half_thickness_;
  }
  std::optional<Aabb> sublevel_bounds(double) const override { return std::nullopt; }
  double sublevel_limit() const override { return -std::numeric_limits<double>::infinity(); }

 private:
  double wavenumber_, half_thickness_;
};

// --- CSG -----------------------------------------------------------------------------------------------------
class Csg final : public SceneField {
 public:
  Csg(CsgOp op, std::vector<FieldPtr> children, const CsgOptions& options)
      : op_(op),
        blend_(options.blend),
        blend_radius_(options.radius),
        children_(std::move(children)),
        limit_(compute_limit()) {}

  double value(const Vec3& p) const override {
    double v = children_[0]->value(p);
    for (std::size_t i = 1; i < children_.size(); ++i) v = combine(v, children_[i]->value(p));
    return v;
  }

  double value_and_gradient(const Vec3& p, Vec3& gradient) const override {
    Vec3 g;
    double v = children_[0]->value_and_gradient(p, g);
    Dual acc(v, g.x(), g.y(), g.z());
    for (std::size_t i = 1; i < children_.size(); ++i) {
      v = children_[i]->value_and_gradient(p, g);
      acc = combine(acc, Dual(v, g.x(), g.y(), g.z()));
    }
    gradient = Vec3(acc.d[0], acc.d[1], acc.d[2]);
    return acc.v;
  }

  // Min/max and the polynomial smooth blend have gradients that are convex combinations of the children's
  // ((1 - h/2) grad a + (h/2) grad b for the smooth one): the largest child bound. The R-function's gradient is
  // (1 -+ a/r) grad a + (1 -+ b/r) grad b with r = sqrt(a^2 + b^2), whose weights sum to at most 2 + sqrt(2);
  // children are folded left to right, so the factor applies per fold.
  std::optional<double> lipschitz_bound() const override {
    std::optional<double> acc;
    for (const FieldPtr& c : children_) {
      const std::optional<double> l = c->lipschitz_bound();
      if (!l) return std::nullopt;
      if (!acc) {
        acc = *l;
      } else {
        acc = std::max(*acc, *l) * (blend_ == CsgBlend::kRFunction ? 2.0 + std::numbers::sqrt2 : 1.0);
      }
    }
    return acc;
  }

  // Children are folded left to right, acc_i = combine(acc_(i-1), child_i). Every intersection and difference blend
  // is >= its first argument (and an intersection's >= both), so {acc <= level} lies in the first child's set below
  // the same level (and in every child's). A min or R-function union is at or below `level` only where some child
  // is at or below level * union_factor(). Smooth unions: smooth_union_bounds(). One call per child: nested blends cost
  // linear time.
  std::optional<Aabb> sublevel_bounds(double level) const override {
    switch (op_) {
      case CsgOp::kUnion: {
        if (blend_ == CsgBlend::kSmooth) return smooth_union_bounds(level);
        std::optional<Aabb> box;
        for (const FieldPtr& c : children_) {
          const std::optional<Aabb> b = c->sublevel_bounds(level * union_factor());
          if (!b) return std::nullopt;
          box = box ? merged(*box, *b) : *b;
        }
        return box;
      }
      case CsgOp::kIntersection: {
        // If the boxes do not overlap the set is empty and the returned box is degenerate (min == max on some axis;
        // Aabb::valid() false).
        std::optional<Aabb> box;
        for (const FieldPtr& c : children_) {
          const std::optional<Aabb> b = c->sublevel_bounds(level);
          if (!b) continue;
          box = box ? box->intersect(*b) : *b;
        }
        if (box) box->max = box->max.cwiseMax(box->min);
        return box;
      }
      case CsgOp::kDifference:
        return children_[0]->sublevel_bounds(level);
    }
    return std::nullopt;
  }

 private:
  template <class T>
  T combine(const T& a, const T& b) const {
    switch (op_) {
      case CsgOp::kUnion:
        return join(a, b);
      case CsgOp::kIntersection:
        return meet(a, b);
      case CsgOp::kDifference:
        return meet(a, -b);
    }
    return a;
  }

  // sqrt(a^2 + b^2); above 1e150 a and b are scaled by their larger magnitude first, so that the squares do not
  // overflow. sqrt(0) has derivative 0 (dual.h), so at a = b = 0 the R-function's gradient is grad a + grad b.
  template <class T>
  static T rhypot(const T& a, const T& b) {
    const double m = std::max(std::abs(value_of(a)), std::abs(value_of(b)));
    if (!(m > 1e150) || !std::isfinite(m)) return tsqrt(a * a + b * b);
    const T x = a * (1.0 / m), y = b * (1.0 / m);
    return tsqrt(x * x + y * y) * m;
  }

  template <class T>
  T join(const T& a, const T& b) const {
    switch (blend_) {
      case CsgBlend::kMinMax:
        return tmin(a, b);
      case CsgBlend::kRFunction: {
        // a + b - sqrt(a^2 + b^2). Where a + b > 0 the two terms cancel (a = 1, b = 1e17 gives 0): there it is
        // 2ab / (a + b + sqrt(a^2 + b^2)), written so that no product overflows.
        const T s = a + b;
        const T r = rhypot(a, b);
        return value_of(s) > 0.0 ? 2.0 * a * (b / (s + r)) : s - r;
      }
      case CsgBlend::kSmooth: {
        const T h = tmax(T(blend_radius_) - tabs(a - b), T(0.0)) * (1.0 / blend_radius_);
        return tmin(a, b) - h * h * (kSmoothBlendDepth * blend_radius_);
      }
    }
    return a;
  }

  template <class T>
  T meet(const T& a, const T& b) const {
    switch (blend_) {
      case CsgBlend::kMinMax:
        return tmax(a, b);
      case CsgBlend::kRFunction: {
        // a + b + sqrt(a^2 + b^2), without the cancellation where a + b < 0 (as join).
        const T s = a + b;
        const T r = rhypot(a, b);
        return value_of(s) < 0.0 ? 2.0 * a * (b / (s - r)) : s + r;
      }
      case CsgBlend::kSmooth: {
        const T h = tmax(T(blend_radius_) - tabs(a - b), T(0.0)) * (1.0 / blend_radius_);
        return tmax(a, b) + h * h * (kSmoothBlendDepth * blend_radius_);
      }
    }
    return a;
  }

  // Min: a union at or below a level has a child there. R-function, for positive a and b: 2ab / (a + b +
  // sqrt(a^2 + b^2)) >= (2 - sqrt 2) min(a, b) (equality at a = b), and 1 / R(a, b) <= 1 / a + 1 / b (as
  // sqrt(a^2 + b^2) <= a + b), so over the n - 1 folds the union reaches at least min / min(n, (2 - sqrt 2)^-(n-1)).
  double union_factor() const {
    if (blend_ != CsgBlend::kRFunction) return 1.0;
    const double n = static_cast<double>(children_.size());
    return std::min(n, std::pow(1.0 / (2.0 - std::numbers::sqrt2), n - 1.0));
  }

  // The smooth blend lowers min(acc, child) by at most d = kSmoothBlendDepth k (k: its radius, 4 d), and only where
  // the two are within k of each other. Let L be the level.
  //   - All children at L + min(n - 1, 5) d. Each fold dips at most d: (n - 1) d. Or: where every child is above
  //     W = L + k + d, acc stays above L: a fold leaves min(acc, child) alone unless acc > child - k > W - k, and
  //     then the result is > W - k - d = L.
  //   - Children whose sublevel_limit() says they are unbounded there (blobs tend to their iso far away): split the
  //     children into those, U, and the rest, B. Let V = L + (|U| - 1) d and W = V + 2 k + 2 d. Where every child of
  //     U is above V and every child of B above W: before the first child of U, acc > W - k - d as above; that fold
  //     gives min(acc, u) > V + d when it dips (u > acc - k), so acc > V; each later child of U lowers the bound by d
  //     (it ends at L), and a child b of B only dips where acc > b - k > W - k, leaving acc > W - k - d > V. So U's
  //     children are asked below V, and B's below W.
  // Either way one call per child.
  std::optional<Aabb> smooth_union_bounds(double level) const {
    const double d = kSmoothBlendDepth * blend_radius_;
    const double all = level + smooth_union_depth();
    std::vector<bool> in_u(children_.size(), false);
    std::size_t u = 0;
    for (std::size_t i = 0; i < children_.size(); ++i) {
      if (children_[i]->sublevel_limit() <= all) {
        in_u[i] = true;
        ++u;
      }
    }
    const double v = level + static_cast<double>(u > 0 ? u - 1 : 0) * d, w = v + 2.0 * (blend_radius_ + d);
    std::optional<Aabb> box;
    for (std::size_t i = 0; i < children_.size(); ++i) {
      const std::optional<Aabb> b = children_[i]->sublevel_bounds(u == 0 ? all : (in_u[i] ? v : w));
      if (!b) return std::nullopt;
      box = box ? merged(*box, *b) : *b;
    }
    return box;
  }

  // How far below its children smooth_union_bounds() asks when no child is in U: min(n - 1, 5) d.
  double smooth_union_depth() const {
    return static_cast<double>(std::min<std::size_t>(children_.size() - 1, 5)) * kSmoothBlendDepth * blend_radius_;
  }

  double sublevel_limit() const override { return limit_; }

  // As sublevel_bounds(): the level below which it finds a box, as far as the children's hints tell. Once, when the
  // node is built: smooth unions ask their children's at every sublevel_bounds().
  double compute_limit() const {
    double lowest = std::numeric_limits<double>::infinity(), highest = -lowest;
    for (const FieldPtr& c : children_) {
      const double t = c->sublevel_limit();
      lowest = std::min(lowest, t);
      highest = std::max(highest, t);
    }
    switch (op_) {
      case CsgOp::kUnion:
        if (blend_ != CsgBlend::kSmooth) return lowest / union_factor();
        return lowest - smooth_union_depth();
      case CsgOp::kIntersection:
        return highest;
      case CsgOp::kDifference:
        return children_[0]->sublevel_limit();
    }
    return lowest;
  }

  CsgOp op_;
  CsgBlend blend_;
  double blend_radius_;
  std::vector<FieldPtr> children_;
  double limit_;  // sublevel_limit(), from the children's
};

// --- Transform -----------------------------------------------------------------------------------------------
class Transform final : public SceneField {
 public:
  Transform(FieldPtr child, const Eigen::Matrix3d& a, const Vec3& t, double factor)
      : child_(std::move(child)),
        linear_(a),
        inv_(a.inverse()),
        inv_t_(inv_.transpose()),
        translation_(t),
        factor_(factor) {
    inv_norm_ = Eigen::JacobiSVD<Eigen::Matrix3d>(inv_).singularValues()(0);  // spectral norm of A^-1
  }

  // value(p) = factor child(A^-1 (p - t)): the child's bound times factor times |A^-1| (spectral norm).
  std::optional<double> lipschitz_bound() const override {
    const std::optional<double> l = child_->lipschitz_bound();
    if (!l) return std::nullopt;
    return *l * factor_ * inv_norm_;
  }

  double value(const Vec3& p) const override { return factor_ * child_->value(inv_ * (p - translation_)); }

  double value_and_gradient(const Vec3& p, Vec3& gradient) const override {
    Vec3 g;
    const double v = child_->value_and_gradient(inv_ * (p - translation_), g);
    gradient = factor_ * (inv_t_ * g);
    return factor_ * v;
  }

  double sublevel_limit() const override { return child_->sublevel_limit() * factor_; }

  // value(p) <= level exactly where child(A^-1 (p - t)) <= level / factor: that set's box, carried by A and t.
  std::optional<Aabb> sublevel_bounds(double level) const override {
    const std::optional<Aabb> b = child_->sublevel_bounds(level / factor_);
    if (!b) return std::nullopt;
    Aabb out = Aabb::empty();
    for (int corner = 0; corner < 8; ++corner) {
      const Vec3 c((corner & 1) ? b->max.x() : b->min.x(), (corner & 2) ? b->max.y() : b->min.y(),
                   (corner & 4) ? b->max.z() : b->min.z());
      out.merge(Vec3(linear_ * c + translation_));
    }
    return out;
  }

 private:
  FieldPtr child_;
  Eigen::Matrix3d linear_, inv_, inv_t_;
  Vec3 translation_;
  double factor_;  // s when A = s R, else 1
  double inv_norm_ = 1.0;
};

void require_distinct(const Vec3& a, const Vec3& b, const std::string& what) {
  if ((b - a).norm() <= 1e-12 * std::max(1.0, std::max(a.norm(), b.norm()))) {
    throw InvalidInput("b", "b equals a; the " + what + " needs two distinct end points a and b");
  }
}

void require_nonzero_direction(const std::string& field, const Vec3& v) {
  require_finite(field, v);
  if (!(v.norm() > 0.0)) throw InvalidInput(field, field + " is the zero vector; give a nonzero direction");
}

}  // namespace

// --- Builders ------------------------------------------------------------------------------------------------
FieldPtr make_sphere(const Vec3& center, double radius) {
  require_coordinate("center", center);
  require_length("radius", radius);
  return std::make_shared<Sphere>(center, radius);
}

FieldPtr make_box(const Vec3& center, const Vec3& half_size) {
  require_coordinate("center", center);
  require_length("half_size", half_size, "give half the box's extent along each axis");
  return std::make_shared<RoundedBox>(center, half_size, 0.0);
}

FieldPtr make_rounded_box(const Vec3& center, const Vec3& half_size, double radius) {
  require_coordinate("center", center);
  require_length("half_size", half_size, "give half the box's extent along each axis");
  require_length("radius", radius);
  const double limit = half_size.minCoeff();
  if (radius > limit) {
    throw InvalidInput("radius", "radius (" + format_number(radius) + ") must be <= the smallest half_size (" +
                                     format_number(limit) + "); reduce the edge radius");
  }
  return std::make_shared<RoundedBox>(center, half_size, radius);
}

FieldPtr make_cylinder(const Vec3& a, const Vec3& b, double radius) {
  require_coordinate("a", a);
  require_coordinate("b", b);
  require_length("radius", radius);
  require_distinct(a, b, "cylinder");
  return std::make_shared<Cylinder>(a, b, radius);
}

FieldPtr make_cone(const Vec3& a, const Vec3& b, double radius_a, double radius_b) {
  require_coordinate("a", a);
  require_coordinate("b", b);
  require_coordinate("radius_a", radius_a);
  require_coordinate("radius_b", radius_b);
  if (radius_a < 0.0) {
    throw InvalidInput("radius_a", "radius_a (" + format_number(radius_a) + ") must be >= 0");
  }
  if (radius_b < 0.0) {
    throw InvalidInput("radius_b", "radius_b (" + format_number(radius_b) + ") must be >= 0");
  }
  if (radius_a == 0.0 && radius_b == 0.0) {
    throw InvalidInput("radius_a", "radius_a and radius_b are both 0; give at least one positive radius");
  }
  require_distinct(a, b, "cone");
  return std::make_shared<Cone>(a, b, radius_a, radius_b);
}

FieldPtr make_torus(const Vec3& center, const Vec3& axis, double major_radius, double minor_radius) {
  require_coordinate("center", center);
  require_nonzero_direction("axis", axis);
  require_length("major_radius", major_radius);
  require_length("minor_radius", minor_radius);
  if (minor_radius >= major_radius) {
    throw InvalidInput("minor_radius", "minor_radius (" + format_number(minor_radius) + ") must be < major_radius (" +
                                           format_number(major_radius) + "); the tube would cross the axis");
  }
  return std::make_shared<Torus>(center, axis, major_radius, minor_radius);
}

FieldPtr make_plane(const Vec3& normal, double offset) {
  require_nonzero_direction("normal", normal);
  require_coordinate("offset", offset);
  return std::make_shared<Plane>(normal, offset);
}

FieldPtr make_capsule(const Vec3& a, const Vec3& b, double radius) {
  require_coordinate("a", a);
  require_coordinate("b", b);
  require_length("radius", radius);
  return std::make_shared<Capsule>(a, b, radius);
}

FieldPtr make_gyroid(double period, double thickness) {
  require_length("period", period, "give the length of one gyroid cell");
  require_length("thickness", thickness, "give the sheet thickness");
  return std::make_shared<Gyroid>(period, thickness);
}

FieldPtr make_csg(CsgOp op, std::vector<FieldPtr> children, const CsgOptions& options) {
  if (children.size() < 2) {
    throw InvalidInput(
        "children", "children has " + std::to_string(children.size()) + " node(s); a CSG operation needs at least two");
  }
  for (std::size_t i = 0; i < children.size(); ++i) {
    if (!children[i]) {
      const std::string field = "children[" + std::to_string(i) + "]";
      throw InvalidInput(field, field + " is empty; give a node");
    }
  }
  if (options.blend == CsgBlend::kSmooth) {
    require_length("radius", options.radius, "BLEND_SMOOTH needs a blend radius");
  }
  return std::make_shared<Csg>(op, std::move(children), options);
}

FieldPtr make_transform(FieldPtr child, const Eigen::Matrix3d& linear, const Vec3& translation) {
  if (!child) throw InvalidInput("child", "child is empty; give the node to transform");
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) {
      require_finite("linear(" + std::to_string(r) + "," + std::to_string(c) + ")", linear(r, c));
    }
  }
  require_coordinate("translation", translation);
  // Singular (or numerically so) relative to the matrix's own scale.
  const double norm = linear.norm();
  if (!(norm > 0.0) || std::abs(linear.determinant()) <= 1e-12 * norm * norm * norm) {
    throw InvalidInput("linear", "linear matrix is singular (determinant " + format_number(linear.determinant()) +
                                     "); give an invertible matrix (nonzero scale on every axis)");
  }
  // A = s R exactly when A^T A = s^2 I; then distances scale by s.
  const Eigen::Matrix3d ata = linear.transpose() * linear;
  const double s2 = ata.trace() / 3.0;
  const double deviation = (ata - s2 * Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff();
  const double factor = deviation <= 1e-9 * s2 ? std::sqrt(s2) : 1.0;
  auto transform = std::make_shared<Transform>(std::move(child), linear, translation, factor);
  // The child carried this far must stay within the range of coordinates too.
  if (const std::optional<Aabb> b = transform->bounds()) {
    const double reach = std::max(b->min.cwiseAbs().maxCoeff(), b->max.cwiseAbs().maxCoeff());
    if (!(reach <= kMaxCoordinate)) {
      throw InvalidInput("linear", "linear map and translation carry the child to " + format_number(reach) +
                                       ", beyond +-" + format_number(kMaxCoordinate) +
                                       ", the range of coordinates; scale the scene down");
    }
  }
  return transform;
}

}  // namespace surfacer
