// Reassembles frames from WatchJob's FrameHeader + FrameChunk events and verifies them: each chunk's CRC-32
// (zlib polynomial), its index and size (<= 1 MiB), and the whole frame's CRC-32, byte count and chunk count.
#pragma once

#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <string_view>

#include "surfacer/v1/surfacer.pb.h"
#include "wire/protocol.h"

namespace surfacer::client {

using wire::kMaxChunkBytes;

struct ReceivedFrame {
  int index = 0;
  v1::MeshEncoding encoding = v1::MESH_ENCODING_DRACO;  // a known encoding; UNSPECIFIED is normalized to DRACO
  std::string bytes;
  v1::FrameStats stats;
};

class FrameAssembler {
 public:
  // Starts a frame. Returns it at once when it has no bytes (num_chunks 0, total_bytes 0).
  // Throws CliError(kIntegrity) for a second header of a frame still being received or impossible sizes.
  std::optional<ReceivedFrame> on_header(const v1::FrameHeader& header);
  // Adds a chunk; returns the frame when this was its last chunk and every check passed.
  // Throws CliError(kIntegrity) naming the frame, the chunk and the mismatch.
  std::optional<ReceivedFrame> on_chunk(const v1::FrameChunk& chunk);
  // Drops partially received frames (after the stream broke; they are sent again on reconnect).
  void reset() { pending_.clear(); }
  bool idle() const { return pending_.empty(); }

 private:
  struct Pending {
    v1::FrameHeader header;
    std::string bytes;
    int chunks = 0;
    std::uint32_t crc = 0;  // of `bytes`, from the chunks' CRCs as each was checked
  };
  ReceivedFrame finish(int index, Pending& pending);

  std::map<int, Pending> pending_;
};

}  // namespace surfacer::client
