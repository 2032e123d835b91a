// Fuzz target: the CLI's frame reassembly (client/frame_assembler) fed an arbitrary sequence of WatchJob events,
// as a hostile or broken server could send them. The input is a list of operations (fuzz/fuzz_input.h reads it):
//   0 a FrameHeader with arbitrary fields      1 a FrameChunk with arbitrary fields (CRC right or arbitrary)
//   2 a well-formed frame (header + chunks, right CRCs) with at most one corruption   3 reset() (a reconnect)
//   4 a chunk one byte over the 1 MiB limit
// Expected failures are CliError(kIntegrity). Properties: every frame handed out has the byte count and CRC-32
// of the header that announced it; a well-formed, uncorrupted frame sent to an idle assembler comes back intact.
#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "client/exit_codes.h"
#include "client/frame_assembler.h"
#include "core/util/crc32.h"
#include "fuzz/fuzz_input.h"

namespace surfacer::fuzz {
namespace {

using client::CliError;
using client::ExitCode;
using client::FrameAssembler;
using client::ReceivedFrame;

class Harness {
 public:
  void header(const v1::FrameHeader& h) {
    const auto frame = assembler_.on_header(h);
    announced_[h.frame_index()] = h;  // reached only when accepted
    check(frame);
  }
  void chunk(const v1::FrameChunk& c) { check(assembler_.on_chunk(c)); }
  void reset() { assembler_.reset(); }
  bool idle() const { return assembler_.idle(); }
  std::optional<ReceivedFrame> last() const { return last_; }
  void forget_last() { last_.reset(); }

 private:
  void check(const std::optional<ReceivedFrame>& frame) {
    if (!frame) return;
    const auto it = announced_.find(frame->index);
    require(it != announced_.end(), "a frame came out that no accepted header announced");
    const v1::FrameHeader& h = it->second;
    require(frame->bytes.size() == h.total_bytes(), "frame size differs from FrameHeader.total_bytes");
    require(crc32_of(frame->bytes) == h.crc32(), "frame CRC-32 differs from FrameHeader.crc32");
    require(frame->encoding == v1::MESH_ENCODING_DRACO || frame->encoding == v1::MESH_ENCODING_PLY ||
                frame->encoding == v1::MESH_ENCODING_DRACO_PIECES || frame->encoding == v1::MESH_ENCODING_MESHOPT,
            "frame with an unknown encoding");
    last_ = frame;
  }

  FrameAssembler assembler_;
  std::map<int, v1::FrameHeader> announced_;
  std::optional<ReceivedFrame> last_;
};

// Mostly small indices (so headers and chunks meet), sometimes any int32.
int index_from(FuzzInput& in) {
  const std::uint8_t b = in.u8();
  return b < 0xF0 ? b % 4 : static_cast<int>(in.u32());
}

v1::MeshEncoding encoding_from(FuzzInput& in) {
  return static_cast<v1::MeshEncoding>(in.u8() % 4);  // 3 is not a MeshEncoding value
}

void well_formed_frame(FuzzInput& in, Harness& h) {
  const int index = index_from(in);
  const v1::MeshEncoding encoding = encoding_from(in);
  const std::string payload = in.bytes(in.u16() % 2048);
  const int chunks = payload.empty() ? (in.flag() ? 0 : 1) : 1 + in.u8() % 4;
  const std::uint8_t corruption = in.u8() % 10;  // 0..2: none
  const int victim = chunks > 0 ? in.u8() % chunks : 0;

  std::vector<v1::FrameChunk> parts;
  const std::size_t step = chunks > 0 ? (payload.size() + chunks - 1) / chunks : 0;
  for (int c = 0; c < chunks; ++c) {
    v1::FrameChunk chunk;
    chunk.set_frame_index(index);
    chunk.set_chunk_index(c);
    chunk.set_last(c + 1 == chunks);
    const std::size_t begin = std::min(payload.size(), step * c);
    chunk.set_data(payload.substr(begin, std::min(step, payload.size() - begin)));
    chunk.set_crc32(crc32_of(chunk.data()));
    parts.push_back(chunk);
  }
  v1::FrameHeader header;
  header.set_frame_index(index);
  header.set_encoding(encoding);
  header.set_total_bytes(payload.size());
  header.set_num_chunks(chunks);
  header.set_crc32(crc32_of(payload));
  header.mutable_stats()->set_vertices(static_cast<std::int64_t>(payload.size()));

  bool corrupted = encoding == 3 || index < 0;
  switch (corruption) {
    case 3:
      if (!parts.empty()) {
        parts[victim].set_crc32(parts[victim].crc32() ^ 1u);
        corrupted = true;
      }
      break;
    case 4:
      header.set_crc32(header.crc32() ^ 0x80000000u);
      corrupted = true;
      break;
    case 5:
      if (!parts.empty()) {
        parts.erase(parts.begin() + victim);
        corrupted = true;
      }
      break;
    case 6:
      if (!parts.empty()) {
        parts.insert(parts.begin() + victim, parts[victim]);
        corrupted = true;
      }
      break;
    case 7:
      if (parts.size() > 1) {
        std::swap(parts[0], parts[1]);
        corrupted = true;
      }
      break;
    case 8:
      header.set_total_bytes(header.total_bytes() + 1 + in.u8());
      corrupted = true;
      break;
    case 9:
      if (!parts.empty()) {
        parts[victim].set_last(!parts[victim].last());
        corrupted = true;
      }
      break;
    default:
      break;
  }

  const bool was_idle = h.idle();
  h.forget_last();
  try {
    h.header(header);
    for (const auto& part : parts) h.chunk(part);
  } catch (const CliError& e) {
    require(e.code() == ExitCode::kIntegrity, "a CliError that is not an integrity error");
    require(corrupted || !was_idle, std::string("a well-formed frame was rejected: ") + e.what());
    return;
  }
  if (was_idle && !corrupted) {
    const auto frame = h.last();
    require(frame.has_value() && frame->index == index, "a well-formed frame did not come out");
    require(frame->bytes == payload, "a well-formed frame came out with different bytes");
    require(frame->stats.vertices() == static_cast<std::int64_t>(payload.size()), "frame stats were not kept");
    require(h.idle(), "the assembler is not idle after the only frame in flight completed");
  }
}

}  // namespace
}  // namespace surfacer::fuzz

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace surfacer;
  fuzz::FuzzInput in(data, size);
  fuzz::Harness h;
  for (int op = 0; op < 64 && !in.empty(); ++op) {
    try {
      switch (in.u8() % 5) {
        case 0: {
          v1::FrameHeader header;
          header.set_frame_index(fuzz::index_from(in));
          header.set_encoding(fuzz::encoding_from(in));
          header.set_total_bytes(in.flag() ? in.u64() : in.u16());
          header.set_num_chunks(in.flag() ? static_cast<int>(in.u32()) : in.u8() % 4);
          header.set_crc32(in.u32());
          h.header(header);
          break;
        }
        case 1: {
          v1::FrameChunk chunk;
          chunk.set_frame_index(fuzz::index_from(in));
          chunk.set_chunk_index(in.flag() ? static_cast<int>(in.u32()) : in.u8() % 4);
          chunk.set_last(in.flag());
          chunk.set_data(in.bytes(in.u8()));
          chunk.set_crc32(in.flag() ? crc32_of(chunk.data()) : in.u32());
          h.chunk(chunk);
          break;
        }
        case 2:
          fuzz::well_formed_frame(in, h);
          break;
        case 3:
          h.reset();
          break;
        default: {
          static v1::FrameChunk oversized = [] {
            v1::FrameChunk c;
            c.set_data(std::string(client::kMaxChunkBytes + 1, 'x'));
            c.set_crc32(crc32_of(c.data()));
            return c;
          }();  // built once: copying 1 MiB per operation would dominate the run time
          oversized.set_frame_index(fuzz::index_from(in));
          oversized.set_chunk_index(in.u8() % 4);
          h.chunk(oversized);
          break;
        }
      }
    } catch (const client::CliError& e) {
      fuzz::require(e.code() == client::ExitCode::kIntegrity, "a CliError that is not an integrity error");
    }
  }
  return 0;
}
