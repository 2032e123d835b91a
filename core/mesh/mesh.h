// The indexed triangle mesh every engine produces. No gRPC, no protobuf.
#pragma once

#include <array>
#include <cstdint>
#include <vector>

#include "core/util/geometry.h"

namespace surfacer {

using Triangle = std::array<std::uint32_t, 3>;

// Indexed triangle mesh. Triangles are counter-clockwise seen from outside (normal = (b-a) x (c-a) points out).
struct Mesh {
  std::vector<Vec3> vertices;
  std::vector<Triangle> triangles;
  std::vector<Vec3> normals;  // empty, or one unit normal per vertex

  bool empty() const { return triangles.empty(); }
};

}  // namespace surfacer
