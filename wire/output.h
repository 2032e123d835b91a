// OutputOptions -> how every frame of a job is encoded, and the protocol's names for the frame codecs.
#pragma once

#include <optional>
#include <string>

#include "core/mesh/decimate.h"
#include "core/mesh/frame_codec.h"
#include "surfacer/v1/surfacer.pb.h"

namespace surfacer::wire {

struct FrameEncoding {
  // The codec and its settings; options.draco.quantization_bounds is always set: one grid for the whole job (no
  // cracks or jitter between frames). `draco.normals` says whether frames carry per-vertex normals (any codec).
  FrameCodecOptions options;
  // The output option `decimate` (tolerance 0: off), applied by the job runners before encoding.
  DecimateOptions decimate;

  v1::MeshEncoding mesh_encoding() const;
  // The grid every frame's positions are quantized on (every codec but PLY, which is lossless), for engines that
  // keep their triangles from collapsing on it.
  std::optional<QuantizationGrid> grid() const;
};

// Resolves `options` (at `path`, e.g. "spec.output"); `job_bounds` is the default quantization box. Only the fields
// the request sets override FrameCodecOptions' defaults. Throws InvalidInput naming the field (an unknown encoding,
// bits out of range, a bad box).
FrameEncoding frame_encoding(const v1::OutputOptions& options, const Aabb& job_bounds, const std::string& path);

// The protocol's value for a codec, and back (UNSPECIFIED is Draco; nullopt for a value this build does not know).
v1::MeshEncoding mesh_encoding(FrameCodec codec);
std::optional<FrameCodec> frame_codec(v1::MeshEncoding encoding);

}  // namespace surfacer::wire
