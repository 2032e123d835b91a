// Reassembles one client-streamed upload from its chunks, checking sizes and checksums as they arrive. Pure logic
// (no I/O, no gRPC threads), so the Upload reactor, the tests and the fuzzers drive the same code.
#pragma once

#include <grpcpp/support/status.h>

#include <cstdint>
#include <memory>

#include "server/memory_budget.h"
#include "server/uploads.h"
#include "surfacer/v1/surfacer.pb.h"

namespace surfacer::server {

class UploadAssembler {
 public:
  // max_bytes: the server's --max-upload-bytes (or a tenant's remaining quota, whichever is smaller);
  // limit_hint: what to say about raising it. budget: the server's memory budget, which the bytes held draw from
  // as the buffer grows (null: not accounted).
  explicit UploadAssembler(std::int64_t max_bytes,
                           std::string limit_hint = "start the server with a larger --max-upload-bytes",
                           MemoryBudget* budget = nullptr);

  // Adds the next chunk. A non-OK status ends the upload (RESOURCE_EXHAUSTED past the limit or the memory
  // budget, DATA_LOSS on a bad checksum or a chunk_index out of sequence, INVALID_ARGUMENT on a malformed chunk:
  // more than 1 MiB of data, a name over its limit); later calls return the same status.
  grpc::Status add(const v1::UploadChunk& chunk);
  // The client closed the stream: checks the announced total (and that a chunk came). OK -> take() returns the blob.
  grpc::Status finish();
  std::shared_ptr<UploadBlob> take();
  // The memory-budget bytes the blob holds (its buffer's capacity); moved out with take()'s blob, to be released
  // when the blob is freed.
  MemoryReservation take_reservation() { return std::move(reservation_); }
  // Ends the upload with `status` and frees what it holds (an upload left idle); later calls return `status`.
  void abandon(const grpc::Status& status) { fail(status); }

  std::uint64_t bytes() const { return blob_ ? blob_->bytes.size() : 0; }
  int chunks() const { return chunks_; }

 private:
  grpc::Status fail(grpc::Status status);
  grpc::Status over_limit(std::uint64_t bytes) const;
  // Grows the buffer to `capacity` bytes, drawn from the budget first; RESOURCE_EXHAUSTED when the budget is spent.
  grpc::Status grow_buffer(std::uint64_t capacity);

  const std::int64_t max_bytes_;
  const std::string limit_hint_;
  MemoryBudget* const budget_;
  std::shared_ptr<UploadBlob> blob_ = std::make_shared<UploadBlob>();
  MemoryReservation reservation_;  // covers blob_'s buffer capacity
  grpc::Status error_;
  std::uint64_t expected_ = 0;
  std::uint32_t crc_ = 0;
  int chunks_ = 0;
  bool indexed_ = false;  // the first chunk carried a chunk_index: every chunk must
  bool finished_ = false;
};

}  // namespace surfacer::server
