#include "wire/output.h"

#include "core/util/errors.h"
#include "wire/scene.h"

namespace surfacer::wire {

v1::MeshEncoding mesh_encoding(FrameCodec codec) {
  switch (codec) {
    case FrameCodec::kDraco:
      return v1::MESH_ENCODING_DRACO;
    case FrameCodec::kDracoPieces:
      return v1::MESH_ENCODING_DRACO_PIECES;
    case FrameCodec::kMeshopt:
      return v1::MESH_ENCODING_MESHOPT;
    case FrameCodec::kPly:
      return v1::MESH_ENCODING_PLY;
  }
  return v1::MESH_ENCODING_UNSPECIFIED;
}

std::optional<FrameCodec> frame_codec(v1::MeshEncoding encoding) {
  switch (encoding) {
    case v1::MESH_ENCODING_UNSPECIFIED:
    case v1::MESH_ENCODING_DRACO:
      return FrameCodec::kDraco;
    case v1::MESH_ENCODING_DRACO_PIECES:
      return FrameCodec::kDracoPieces;
    case v1::MESH_ENCODING_MESHOPT:
      return FrameCodec::kMeshopt;
    case v1::MESH_ENCODING_PLY:
      return FrameCodec::kPly;
    default:
      return std::nullopt;
  }
}

v1::MeshEncoding FrameEncoding::mesh_encoding() const { return wire::mesh_encoding(options.codec); }

std::optional<QuantizationGrid> FrameEncoding::grid() const {
  if (options.codec == FrameCodec::kPly) return std::nullopt;
  return QuantizationGrid::of(*options.draco.quantization_bounds, options.draco.quantization_bits);
}

FrameEncoding frame_encoding(const v1::OutputOptions& options, const Aabb& job_bounds, const std::string& path) {
  FrameEncoding out;
  const std::optional<FrameCodec> codec = frame_codec(options.encoding());
  if (!codec) {
    throw InvalidInput(path + ".encoding", path + ".encoding (" + std::to_string(options.encoding()) +
                                               ") is not a mesh encoding; use MESH_ENCODING_DRACO, "
                                               "MESH_ENCODING_DRACO_PIECES, MESH_ENCODING_MESHOPT or "
                                               "MESH_ENCODING_PLY");
  }
  out.options.codec = *codec;
  DracoOptions& draco = out.options.draco;
  if (options.has_quantization_bits()) draco.quantization_bits = options.quantization_bits();
  if (options.has_draco_speed()) draco.speed = options.draco_speed();
  draco.quantization_bounds = options.has_quantization_bounds()
                                  ? to_aabb(options.quantization_bounds(), path + ".quantization_bounds")
                                  : job_bounds;
  draco.normals = options.normals();
  out.decimate.tolerance = options.decimate();
  try {
    validate(out.decimate);
  } catch (const Error& e) {
    if (e.kind() != ErrorKind::kInvalidInput) throw;
    // The engine's "tolerance (...) must be ..." under the request's name.
    const std::string_view message = e.what();
    throw at_path(Error(e.kind(), "decimate", "decimate" + std::string(message.substr(message.find(' ')))), path);
  }
  // The engine's names for the two fields the request names differently.
  try {
    validate(out.options);
  } catch (const Error& e) {
    if (e.kind() != ErrorKind::kInvalidInput) throw;
    throw at_path(e.field() == "speed" ? Error(e.kind(), "draco_speed", std::string("draco_") + e.what()) : e, path);
  }
  return out;
}

}  // namespace surfacer::wire
