// Draco frame encoding (the lossless alternative is write_ply(mesh, true) in core/mesh_io.h).
#pragma once

#include <optional>
#include <string>
#include <string_view>

#include "core/mesh.h"

namespace surfacer {

struct DracoOptions {
  int quantization_bits = 14;  // 1..30
  // Quantization box shared by every frame of a job (no cracks or jitter between frames). When absent the mesh's
  // own bounding box is used. Vertices outside the box are an InvalidInput error.
  std::optional<Aabb> quantization_bounds;
  int speed = 7;               // Draco encoder/decoder speed 0..10
  bool normals = true;         // encode mesh.normals when present
  int normal_bits = 10;
};

// Throws InvalidInput for bad options or vertices outside the quantization box, Internal on encoder failure.
std::string encode_draco(const Mesh& mesh, const DracoOptions& options);
// Throws InvalidInput if the bytes are not a Draco triangle mesh.
Mesh decode_draco(std::string_view bytes);

// Largest position error quantization can introduce: half a quantization step along the box's longest side
// times sqrt(3).
double draco_max_error(const Aabb& box, int quantization_bits);

}  // namespace surfacer
