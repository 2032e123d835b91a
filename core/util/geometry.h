// Plain geometry types shared by every room of core: a point and an axis-aligned box. No gRPC, no protobuf.
#pragma once

#include <Eigen/Core>
#include <iterator>
#include <limits>
#include <string>

#include "core/util/format.h"

namespace surfacer {

using Vec3 = Eigen::Vector3d;

// Axis-aligned box; valid when min < max on every axis.
struct Aabb {
  Vec3 min = Vec3::Zero();
  Vec3 max = Vec3::Zero();

  Vec3 size() const { return max - min; }
  bool valid() const { return (max.array() > min.array()).all(); }
  bool finite() const { return min.allFinite() && max.allFinite(); }
  bool contains(const Vec3& p) const { return (p.array() >= min.array()).all() && (p.array() <= max.array()).all(); }
  // Grows the box to hold `other` / `p`; returns *this.
  Aabb& merge(const Aabb& other) {
    min = min.cwiseMin(other.min);
    max = max.cwiseMax(other.max);
    return *this;
  }
  Aabb& merge(const Vec3& p) {
    min = min.cwiseMin(p);
    max = max.cwiseMax(p);
    return *this;
  }
  // Shrinks the box to its overlap with `other` (invalid when they do not overlap); returns *this.
  Aabb& intersect(const Aabb& other) {
    min = min.cwiseMax(other.min);
    max = max.cwiseMin(other.max);
    return *this;
  }
  // The box that holds nothing (min = +inf, max = -inf): merging anything into it gives that thing's box.
  static Aabb empty() {
    const double inf = std::numeric_limits<double>::infinity();
    return {Vec3::Constant(inf), Vec3::Constant(-inf)};
  }
  // The box grown by `pad` on every side.
  Aabb padded(double pad) const { return {min.array() - pad, max.array() + pad}; }

  // The smallest box holding every point of a non-empty range (an empty range gives an empty, invalid box at 0).
  template <class Points>
  static Aabb of(const Points& points) {
    auto it = std::begin(points);
    if (it == std::end(points)) return {};
    Aabb box{*it, *it};
    for (; it != std::end(points); ++it) box.merge(Vec3(*it));
    return box;
  }
};

// "(x, y, z)" with format_number.
inline std::string format_point(const Vec3& p) {
  std::string out(1, '(');  // appended: GCC 12 warns falsely (-Wrestrict) on "literal" + std::string temporaries
  out += format_number(p.x());
  out += ", ";
  out += format_number(p.y());
  out += ", ";
  out += format_number(p.z());
  out += ')';
  return out;
}

// The smallest box holding both.
inline Aabb merged(Aabb a, const Aabb& b) { return a.merge(b); }

}  // namespace surfacer
