#include "client/frame_assembler.h"

#include <algorithm>
#include <cstdio>

#include "client/exit_codes.h"
#include "core/util/crc32.h"
#include "core/util/format.h"
#include "wire/output.h"

namespace surfacer::client {
namespace {

[[noreturn]] void integrity(int frame, const std::string& what) {
  throw CliError(ExitCode::kIntegrity, "frame " + std::to_string(frame) + ": " + what);
}

}  // namespace

std::optional<ReceivedFrame> FrameAssembler::on_header(const v1::FrameHeader& header) {
  const int index = header.frame_index();
  if (index < 0) integrity(index, "negative frame index in FrameHeader");
  if (pending_.count(index) != 0) integrity(index, "a second FrameHeader arrived before the frame's last chunk");
  if (header.num_chunks() < 0) integrity(index, "FrameHeader.num_chunks is negative");
  const std::uint64_t capacity = static_cast<std::uint64_t>(header.num_chunks()) * kMaxChunkBytes;
  if (header.total_bytes() > capacity) {
    integrity(index, "FrameHeader says " + std::to_string(header.total_bytes()) + " bytes in " +
                         std::to_string(header.num_chunks()) + " chunks of at most 1 MiB");
  }
  Pending& pending = pending_[index];
  pending.header = header;
  if (header.num_chunks() == 0) return finish(index, pending);
  // total_bytes comes from the server: reserve at most one chunk's worth; the buffer grows as chunks arrive.
  pending.bytes.reserve(static_cast<std::size_t>(std::min<std::uint64_t>(header.total_bytes(), kMaxChunkBytes)));
  return std::nullopt;
}

std::optional<ReceivedFrame> FrameAssembler::on_chunk(const v1::FrameChunk& chunk) {
  const int index = chunk.frame_index();
  auto it = pending_.find(index);
  if (it == pending_.end())
    integrity(index, "FrameChunk " + std::to_string(chunk.chunk_index()) + " without a FrameHeader");
  Pending& pending = it->second;
  const std::string where = "chunk " + std::to_string(chunk.chunk_index()) + ": ";
  if (chunk.chunk_index() != pending.chunks) {
    integrity(index, where + "expected chunk " + std::to_string(pending.chunks) + " (chunks arrive in order)");
  }
  if (chunk.data().size() > kMaxChunkBytes) {
    integrity(index, where + std::to_string(chunk.data().size()) + " bytes exceed the 1 MiB chunk limit");
  }
  const std::uint32_t crc = crc32_of(chunk.data());
  if (crc != chunk.crc32()) {
    integrity(index, where + "CRC-32 mismatch: computed " + hex32(crc) + ", chunk says " + hex32(chunk.crc32()));
  }
  if (pending.bytes.size() + chunk.data().size() > pending.header.total_bytes()) {
    integrity(index,
              where + "more bytes than FrameHeader.total_bytes (" + std::to_string(pending.header.total_bytes()) + ")");
  }
  pending.bytes += chunk.data();
  pending.crc = crc32_concat(pending.crc, crc, chunk.data().size());  // each byte is read once
  ++pending.chunks;
  const bool should_be_last = pending.chunks == pending.header.num_chunks();
  if (chunk.last() != should_be_last) {
    integrity(index,
              where + (chunk.last()
                           ? "marked last, but FrameHeader.num_chunks is " + std::to_string(pending.header.num_chunks())
                           : "FrameHeader.num_chunks is " + std::to_string(pending.header.num_chunks()) +
                                 " but this chunk is not marked last"));
  }
  if (!should_be_last) return std::nullopt;
  return finish(index, pending);
}

ReceivedFrame FrameAssembler::finish(int index, Pending& pending) {
  const v1::FrameHeader& header = pending.header;
  if (pending.bytes.size() != header.total_bytes()) {
    integrity(index, "received " + std::to_string(pending.bytes.size()) + " bytes, FrameHeader.total_bytes is " +
                         std::to_string(header.total_bytes()));
  }
  if (pending.crc != header.crc32()) {
    integrity(index, "whole-frame CRC-32 mismatch: computed " + hex32(pending.crc) + ", FrameHeader says " +
                         hex32(header.crc32()));
  }
  ReceivedFrame frame;
  frame.index = index;
  const std::optional<FrameCodec> codec = wire::frame_codec(header.encoding());
  if (!codec) integrity(index, "unknown MeshEncoding " + std::to_string(header.encoding()));
  frame.encoding = wire::mesh_encoding(*codec);
  frame.bytes = std::move(pending.bytes);
  frame.stats = header.stats();
  pending_.erase(index);
  return frame;
}

}  // namespace surfacer::client
