// The indexed triangle mesh every engine produces. No gRPC, no protobuf.
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "core/util/geometry.h"

namespace surfacer {

using Triangle = std::array<std::uint32_t, 3>;

// A named array of `components` float32 values per element (per vertex of a mesh, per particle of a frame),
// element-major: values[i * components + c]. components is 1 (a scalar such as density) to kMaxComponents (vectors
// such as velocity): what PLY properties, VTK point arrays, Draco generic attributes and glTF accessors all carry.
struct Attribute {
  static constexpr int kMaxComponents = 4;
  std::string name;
  int components = 1;
  std::vector<float> values;

  std::size_t count() const { return components > 0 ? values.size() / static_cast<std::size_t>(components) : 0; }
};

// Indexed triangle mesh. Triangles are counter-clockwise seen from outside (normal = (b-a) x (c-a) points out).
struct Mesh {
  std::vector<Vec3> vertices;
  std::vector<Triangle> triangles;
  std::vector<Vec3> normals;          // empty, or one unit normal per vertex
  std::vector<Attribute> attributes;  // named per-vertex arrays (one element per vertex each), distinct names

  bool empty() const { return triangles.empty(); }
};

}  // namespace surfacer
