// Fuzz target: the server's upload reassembly (server/upload_assembler.h) fed an arbitrary stream of UploadChunks,
// as a hostile client could send them. The input: the limit (max_bytes), then operations:
//   0 a chunk with arbitrary fields (CRC absent, right or arbitrary)   1 finish()   2 take()
//   3 a well-formed upload (chunks with right CRCs and total_bytes, then finish) with at most one corruption
// Properties: a failed add/finish sticks (later calls return the same code); a finished upload holds exactly the
// bytes of the accepted chunks, within max_bytes and total_bytes, with their CRC-32; a well-formed upload within
// the limit, sent to a fresh assembler, is accepted unchanged.
#include <cstdint>
#include <string>

#include "core/util/crc32.h"
#include "fuzz/fuzz_input.h"
#include "server/upload_assembler.h"
#include "server/uploads.h"

namespace surfacer::fuzz {
namespace {

using server::UploadAssembler;

// max_bytes kept <= 16 MiB: the assembler reserves up to max_bytes for an announced total_bytes.
std::int64_t limit_from(FuzzInput& in) {
  const std::uint8_t kind = in.u8() % 4;
  if (kind == 0) return static_cast<std::int64_t>(in.u8()) - 8;  // tiny, zero or negative
  if (kind == 1) return in.u16();
  return in.u32() % (std::uint32_t{16} << 20);
}

struct Model {
  std::string bytes;  // accepted so far
  std::uint64_t expected = 0;
  int chunks = 0;
  bool failed = false;
  bool finished = false;
  grpc::StatusCode code = grpc::StatusCode::OK;
};

class Harness {
 public:
  explicit Harness(std::int64_t max_bytes) : max_bytes_(max_bytes < 0 ? 0 : max_bytes), assembler_(max_bytes) {}

  grpc::Status add(const v1::UploadChunk& chunk) {
    const grpc::Status status = assembler_.add(chunk);
    observe(status);
    if (status.ok()) {
      require(!model_.finished, "a chunk was accepted after finish()");
      if (model_.chunks == 0) model_.expected = chunk.total_bytes();
      model_.bytes += chunk.data();
      ++model_.chunks;
      require(model_.bytes.size() <= static_cast<std::uint64_t>(max_bytes_), "accepted more than max_bytes");
      require(model_.expected == 0 || model_.bytes.size() <= model_.expected, "accepted more than total_bytes");
      require(!chunk.has_crc32() || chunk.crc32() == crc32_of(chunk.data().data(), chunk.data().size()),
              "a chunk with a wrong crc32 was accepted");
      require(assembler_.bytes() == model_.bytes.size(), "bytes() differs from the accepted data");
      require(assembler_.chunks() == model_.chunks, "chunks() differs from the accepted chunks");
    }
    return status;
  }

  grpc::Status finish() {
    const grpc::Status status = assembler_.finish();
    observe(status);
    if (status.ok()) {
      require(!model_.finished, "finish() succeeded twice");
      require(model_.expected == 0 || model_.bytes.size() == model_.expected, "finished short of total_bytes");
      model_.finished = true;
    }
    return status;
  }

  void take() {
    const auto blob = assembler_.take();
    if (!blob) return;
    require(model_.finished && !model_.failed, "take() returned a blob of an unfinished or failed upload");
    require(blob->bytes == model_.bytes, "the blob differs from the accepted chunks");
    require(blob->crc32 == crc32_of(model_.bytes.data(), model_.bytes.size()), "the blob's crc32 is wrong");
    taken_ = true;
  }

  bool fresh() const { return model_.chunks == 0 && !model_.failed && !model_.finished && !taken_; }
  std::int64_t max_bytes() const { return max_bytes_; }

 private:
  void observe(const grpc::Status& status) {
    if (model_.failed) {
      require(!status.ok() && status.error_code() == model_.code, "a failed upload changed its status");
    } else if (!status.ok()) {
      require(!status.error_message().empty(), "an error status without a message");
      model_.failed = true;
      model_.code = status.error_code();
    }
  }

  std::int64_t max_bytes_;
  UploadAssembler assembler_;
  Model model_;
  bool taken_ = false;
};

void well_formed_upload(FuzzInput& in, Harness& h) {
  const bool fresh = h.fresh();
  const std::string payload = in.bytes(in.u16() % 4096);
  const int chunks = 1 + in.u8() % 4;
  const bool announce = in.flag();
  const bool with_crc = in.flag();
  const std::uint8_t corruption = in.u8() % 6;  // 0..2: none
  const int victim = in.u8() % chunks;
  const std::size_t step = (payload.size() + chunks - 1) / chunks;
  bool corrupted = false;
  bool ok = true;
  for (int c = 0; c < chunks && ok; ++c) {
    v1::UploadChunk chunk;
    if (c == 0) {
      chunk.set_name("fuzz.bin");
      if (announce) chunk.set_total_bytes(payload.size() + (corruption == 3 ? 1 : 0));
      if (announce && corruption == 3) corrupted = true;
    }
    const std::size_t begin = std::min(payload.size(), step * c);
    chunk.set_data(payload.substr(begin, std::min(step, payload.size() - begin)));
    if (with_crc) chunk.set_crc32(crc32_of(chunk.data().data(), chunk.data().size()));
    if (c == victim && corruption == 4) {
      chunk.set_crc32(chunk.crc32() ^ 4u);
      corrupted = true;
    }
    if (c == victim && corruption == 5 && announce && c > 0) {
      chunk.mutable_data()->push_back('!');  // more than announced
      corrupted = true;
    }
    ok = h.add(chunk).ok();
  }
  if (ok) ok = h.finish().ok();
  const bool fits = payload.size() <= static_cast<std::uint64_t>(h.max_bytes());
  if (fresh && !corrupted && fits) require(ok, "a well-formed upload within the limit was rejected");
  h.take();
}

}  // namespace
}  // namespace surfacer::fuzz

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace surfacer;
  fuzz::FuzzInput in(data, size);
  fuzz::Harness h(fuzz::limit_from(in));
  for (int op = 0; op < 64 && !in.empty(); ++op) {
    switch (in.u8() % 4) {
      case 0: {
        v1::UploadChunk chunk;
        if (in.flag()) chunk.set_name(in.bytes(in.flag() ? 2000 : 8));
        if (in.flag()) chunk.set_total_bytes(in.flag() ? in.u64() : in.u16());
        chunk.set_data(in.bytes(in.u8()));
        switch (in.u8() % 3) {
          case 0:
            break;
          case 1:
            chunk.set_crc32(crc32_of(chunk.data().data(), chunk.data().size()));
            break;
          default:
            chunk.set_crc32(in.u32());
            break;
        }
        h.add(chunk);
        break;
      }
      case 1:
        h.finish();
        break;
      case 2:
        h.take();
        break;
      default:
        fuzz::well_formed_upload(in, h);
        break;
    }
  }
  return 0;
}
