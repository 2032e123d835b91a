// Plain geometry types shared by every engine. No gRPC, no protobuf.
#pragma once

#include <Eigen/Core>

#include <array>
#include <cstdint>
#include <vector>

namespace surfacer {

using Vec3 = Eigen::Vector3d;

// Axis-aligned box; valid when min < max on every axis.
struct Aabb {
  Vec3 min = Vec3::Zero();
  Vec3 max = Vec3::Zero();

  Vec3 size() const { return max - min; }
  bool valid() const { return (max.array() > min.array()).all(); }
  bool contains(const Vec3& p) const { return (p.array() >= min.array()).all() && (p.array() <= max.array()).all(); }
};

using Triangle = std::array<std::uint32_t, 3>;

// Indexed triangle mesh. Triangles are counter-clockwise seen from outside (normal = (b-a) x (c-a) points out).
struct Mesh {
  std::vector<Vec3> vertices;
  std::vector<Triangle> triangles;
  std::vector<Vec3> normals;  // empty, or one unit normal per vertex

  bool empty() const { return triangles.empty(); }
};

}  // namespace surfacer
