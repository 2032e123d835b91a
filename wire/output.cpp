#include "wire/output.h"

#include "core/util/errors.h"
#include "wire/scene.h"

namespace surfacer::wire {

FrameEncoding frame_encoding(const v1::OutputOptions& options, const Aabb& job_bounds, const std::string& path) {
  FrameEncoding out;
  switch (options.encoding()) {
    case v1::MESH_ENCODING_UNSPECIFIED:
    case v1::MESH_ENCODING_DRACO:
      out.encoding = v1::MESH_ENCODING_DRACO;
      break;
    case v1::MESH_ENCODING_PLY:
      out.encoding = v1::MESH_ENCODING_PLY;
      break;
    default:
      throw InvalidInput(path + ".encoding", path + ".encoding (" + std::to_string(options.encoding()) +
                                                 ") is not a mesh encoding; use MESH_ENCODING_DRACO or "
                                                 "MESH_ENCODING_PLY");
  }
  DracoOptions& draco = out.draco;
  if (options.has_quantization_bits()) draco.quantization_bits = options.quantization_bits();
  if (options.has_draco_speed()) draco.speed = options.draco_speed();
  draco.quantization_bounds = options.has_quantization_bounds()
                                  ? to_aabb(options.quantization_bounds(), path + ".quantization_bounds")
                                  : job_bounds;
  draco.normals = options.normals();
  // The engine's names for the two fields the request names differently.
  try {
    validate(draco);
  } catch (const Error& e) {
    if (e.kind() != ErrorKind::kInvalidInput) throw;
    throw at_path(e.field() == "speed" ? Error(e.kind(), "draco_speed", std::string("draco_") + e.what()) : e, path);
  }
  return out;
}

}  // namespace surfacer::wire
