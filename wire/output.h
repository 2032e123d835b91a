// OutputOptions -> how every frame of a job is encoded.
#pragma once

#include <string>

#include "core/mesh/mesh_codec.h"
#include "surfacer/v1/surfacer.pb.h"

namespace surfacer::wire {

struct FrameEncoding {
  v1::MeshEncoding encoding = v1::MESH_ENCODING_DRACO;  // DRACO or PLY (UNSPECIFIED resolved)
  // Draco's settings; quantization_bounds is always set: one grid for the whole job (no cracks or jitter between
  // frames). `normals` says whether frames carry per-vertex normals (for PLY too).
  DracoOptions draco;
};

// Resolves `options` (at `path`, e.g. "spec.output"); `job_bounds` is the default quantization box. Only the fields
// the request sets override DracoOptions' defaults. Throws InvalidInput naming the field (an unknown encoding, bits
// out of range, a bad box).
FrameEncoding frame_encoding(const v1::OutputOptions& options, const Aabb& job_bounds, const std::string& path);

}  // namespace surfacer::wire
