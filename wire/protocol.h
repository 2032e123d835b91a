// Constants of the protocol itself (proto/surfacer/v1/surfacer.proto), shared by both sides.
#pragma once

#include <cstddef>

namespace surfacer::wire {

// The largest payload of one UploadChunk or FrameChunk: every message stays far under gRPC's 4 MiB default.
inline constexpr std::size_t kMaxChunkBytes = std::size_t{1} << 20;

}  // namespace surfacer::wire
