// Plain geometry types shared by every room of core: a point and an axis-aligned box. No gRPC, no protobuf.
#pragma once

#include <Eigen/Core>

#include <iterator>

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

// The smallest box holding both.
inline Aabb merged(Aabb a, const Aabb& b) { return a.merge(b); }

}  // namespace surfacer
