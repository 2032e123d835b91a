#include "server/upload_assembler.h"

#include <algorithm>
#include <string>

#include "core/util/crc32.h"
#include "server/status_map.h"
#include "wire/protocol.h"

namespace surfacer::server {
namespace {
constexpr std::uint64_t kReserveAtMost = std::uint64_t{4} << 20;
}  // namespace

UploadAssembler::UploadAssembler(std::int64_t max_bytes, std::string limit_hint, MemoryBudget* budget)
    : max_bytes_(std::max<std::int64_t>(0, max_bytes)), limit_hint_(std::move(limit_hint)), budget_(budget) {
  if (budget_) reservation_ = budget_->reserve(0, "upload");
}

grpc::Status UploadAssembler::fail(grpc::Status status) {
  error_ = status;
  blob_.reset();
  reservation_.release();
  return status;
}

grpc::Status UploadAssembler::grow_buffer(std::uint64_t capacity) {
  try {
    reservation_.grow_to(static_cast<std::int64_t>(capacity),
                         "an upload being received (" + std::to_string(blob_->bytes.size()) + " bytes so far)");
  } catch (...) {
    return fail(status_from_exception(std::current_exception()));
  }
  blob_->bytes.reserve(capacity);
  return grpc::Status::OK;
}

grpc::Status UploadAssembler::over_limit(std::uint64_t bytes) const {
  return {grpc::StatusCode::RESOURCE_EXHAUSTED, "upload of " + std::to_string(bytes) + " bytes exceeds the limit of " +
                                                    std::to_string(max_bytes_) + " bytes; " + limit_hint_};
}

grpc::Status UploadAssembler::add(const v1::UploadChunk& chunk) {
  if (!error_.ok()) return error_;
  if (finished_ || !blob_) {
    return fail({grpc::StatusCode::FAILED_PRECONDITION, "chunk after the end of the upload"});
  }
  const std::string chunk_name = "chunk " + std::to_string(chunks_);
  if (chunk.data().size() > wire::kMaxChunkBytes) {
    return fail({grpc::StatusCode::INVALID_ARGUMENT, chunk_name + ": data is " + std::to_string(chunk.data().size()) +
                                                         " bytes; a chunk carries at most " +
                                                         std::to_string(wire::kMaxChunkBytes) + " (1 MiB)"});
  }
  if (chunks_ == 0) indexed_ = chunk.has_chunk_index();
  if (indexed_ && (!chunk.has_chunk_index() || chunk.chunk_index() != static_cast<std::uint32_t>(chunks_))) {
    return fail({grpc::StatusCode::DATA_LOSS,
                 chunk_name + ": chunk_index is " +
                     (chunk.has_chunk_index() ? std::to_string(chunk.chunk_index()) : std::string("missing")) +
                     " (a chunk was lost or reordered, or the index left out); resend the upload"});
  }
  if (chunks_ == 0) {
    if (chunk.name().size() > wire::kMaxNameBytes) {
      return fail({grpc::StatusCode::INVALID_ARGUMENT,
                   "name is " + std::to_string(chunk.name().size()) + " bytes; the limit is " +
                       std::to_string(wire::kMaxNameBytes) + " bytes (it is a label; send a short file name)"});
    }
    blob_->name = chunk.name();
    expected_ = chunk.total_bytes();
    if (expected_ > static_cast<std::uint64_t>(max_bytes_)) return fail(over_limit(expected_));
    // The announced size is the client's word: reserve no more than a few chunks up front (the string grows as
    // data arrives), so a tiny first chunk announcing gigabytes costs nothing.
    if (expected_ > 0) {
      if (grpc::Status status = grow_buffer(std::min<std::uint64_t>(expected_, kReserveAtMost)); !status.ok()) {
        return status;
      }
    }
  }
  const std::string& data = chunk.data();
  if (chunk.has_crc32() && crc32_of(data.data(), data.size()) != chunk.crc32()) {
    return fail({grpc::StatusCode::DATA_LOSS, chunk_name + ": crc32 does not match its data; resend the upload"});
  }
  const std::uint64_t total = blob_->bytes.size() + data.size();
  if (total > static_cast<std::uint64_t>(max_bytes_)) return fail(over_limit(total));
  if (expected_ != 0 && total > expected_) {
    return fail({grpc::StatusCode::DATA_LOSS,
                 "total_bytes: the first chunk announced " + std::to_string(expected_) + " bytes but more arrived"});
  }
  if (total > blob_->bytes.capacity()) {
    // Grown here rather than by the string, so that the budget holds the buffer's real size: doubling (as the
    // string would), but never past the announced total.
    std::uint64_t capacity = std::max<std::uint64_t>(total, 2 * blob_->bytes.capacity());
    if (expected_ != 0) capacity = std::min(capacity, expected_);
    if (grpc::Status status = grow_buffer(capacity); !status.ok()) return status;
  }
  crc_ = crc32_of(data.data(), data.size(), crc_);
  blob_->bytes += data;
  ++chunks_;
  return grpc::Status::OK;
}

grpc::Status UploadAssembler::finish() {
  if (!error_.ok()) return error_;
  if (finished_ || !blob_) return fail({grpc::StatusCode::FAILED_PRECONDITION, "upload already finished"});
  if (chunks_ == 0) {
    return fail({grpc::StatusCode::INVALID_ARGUMENT,
                 "the upload ended before its first chunk; send at least one (an empty upload is one empty chunk)"});
  }
  if (expected_ != 0 && expected_ != blob_->bytes.size()) {
    return fail({grpc::StatusCode::DATA_LOSS, "total_bytes: the first chunk announced " + std::to_string(expected_) +
                                                  " bytes but " + std::to_string(blob_->bytes.size()) + " arrived"});
  }
  blob_->crc32 = crc_;
  finished_ = true;
  return grpc::Status::OK;
}

std::shared_ptr<UploadBlob> UploadAssembler::take() {
  if (!finished_ || !error_.ok()) return nullptr;
  return std::move(blob_);
}

}  // namespace surfacer::server
