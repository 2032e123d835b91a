#include "client/upload.h"

#include <grpcpp/client_context.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>

#include "client/connection.h"
#include "client/exit_codes.h"
#include "client/progress.h"
#include "client/rpc_error.h"
#include "core/util/crc32.h"
#include "core/util/format.h"

namespace surfacer::client {
namespace {

std::string size_text(std::uint64_t bytes) {
  char buf[32];
  if (bytes < 1024) {
    std::snprintf(buf, sizeof buf, "%llu B", static_cast<unsigned long long>(bytes));
  } else if (bytes < (std::uint64_t{1} << 20)) {
    std::snprintf(buf, sizeof buf, "%.1f KiB", static_cast<double>(bytes) / 1024.0);
  } else {
    std::snprintf(buf, sizeof buf, "%.1f MiB", static_cast<double>(bytes) / (1024.0 * 1024.0));
  }
  return buf;
}

// Sends one upload whose pieces come from `next(buffer, max)` (returns the bytes it put in `buffer`; called until
// `total` bytes were produced).
UploadResult send_upload(v1::Surfacer::Stub& stub, const std::string& name, std::uint64_t total,
                         const std::function<std::string_view(std::size_t max)>& next, const UploadSettings& settings) {
  if (settings.chunk_bytes == 0 || settings.chunk_bytes > kMaxChunkBytes) {
    throw CliError(ExitCode::kInternal, "upload chunk size " + std::to_string(settings.chunk_bytes) +
                                            " is outside 1.." + std::to_string(kMaxChunkBytes));
  }
  grpc::ClientContext context;
  if (settings.deadline != std::chrono::system_clock::time_point::max()) context.set_deadline(settings.deadline);
  v1::UploadResponse response;
  auto writer = stub.Upload(&context, &response);

  std::uint64_t sent = 0;
  std::uint32_t crc = 0;
  std::uint32_t index = 0;
  bool first = true;
  bool stopped = false;
  bool broken = false;
  // The first chunk goes out even for an empty upload: it carries the name.
  while (first || sent < total) {
    if (settings.stop != nullptr && settings.stop->load()) {
      stopped = true;
      context.TryCancel();
      break;
    }
    const std::size_t want = static_cast<std::size_t>(std::min<std::uint64_t>(settings.chunk_bytes, total - sent));
    const std::string_view piece = want == 0 ? std::string_view() : next(want);
    if (piece.size() != want) {
      throw CliError(ExitCode::kInternal, "upload " + name + ": a source gave " + std::to_string(piece.size()) +
                                              " bytes where " + std::to_string(want) + " were expected");
    }
    v1::UploadChunk chunk;
    if (first) {
      chunk.set_name(name);
      chunk.set_total_bytes(total);
    }
    chunk.set_data(piece.data(), piece.size());
    chunk.set_crc32(crc32_of(piece));
    chunk.set_chunk_index(index++);
    if (!writer->Write(chunk)) {
      broken = true;  // the server ended the call; Finish() says why
      break;
    }
    crc = crc32_of(piece, crc);
    sent += piece.size();
    first = false;
  }
  if (!broken && !stopped) writer->WritesDone();
  const grpc::Status status = writer->Finish();
  if (stopped) throw CliError(ExitCode::kCancelled, "interrupted while uploading " + name);
  if (!status.ok()) throw rpc_error("uploading " + name, status);
  if (broken) throw CliError(ExitCode::kIntegrity, "uploading " + name + ": the server closed the stream early");
  if (response.upload_id().empty()) {
    throw CliError(ExitCode::kIntegrity, "uploading " + name + ": the server answered without an upload id");
  }
  if (response.bytes() != total || response.crc32() != crc) {
    throw CliError(ExitCode::kIntegrity, "uploading " + name + ": sent " + std::to_string(total) +
                                             " bytes with CRC-32 " + hex32(crc) + " but the server stored " +
                                             std::to_string(response.bytes()) + " bytes with CRC-32 " +
                                             hex32(response.crc32()));
  }
  return UploadResult{response.upload_id(), response.bytes(), response.crc32()};
}

}  // namespace

UploadResult upload_bytes(v1::Surfacer::Stub& stub, const std::string& name, std::string_view bytes,
                          const UploadSettings& settings) {
  std::size_t pos = 0;
  return send_upload(
      stub, name, bytes.size(),
      [&](std::size_t max) {
        const std::string_view piece = bytes.substr(pos, max);
        pos += piece.size();
        return piece;
      },
      settings);
}

UploadResult upload_file(v1::Surfacer::Stub& stub, const std::string& name, const std::filesystem::path& path,
                         const UploadSettings& settings) {
  std::ifstream in(path, std::ios::binary);
  std::error_code ec;
  const std::uintmax_t size = std::filesystem::file_size(path, ec);
  if (!in || ec) {
    throw CliError(ExitCode::kUsage, "cannot read " + path.string() + ": " +
                                         (ec ? ec.message() : std::generic_category().message(errno)));
  }
  std::string buffer;
  std::uint64_t offset = 0;
  return send_upload(
      stub, name, size,
      [&](std::size_t max) {
        buffer.resize(max);
        in.read(buffer.data(), static_cast<std::streamsize>(max));
        if (static_cast<std::size_t>(in.gcount()) != max) {
          throw CliError(ExitCode::kUsage, path.string() + ": byte " + std::to_string(offset + in.gcount()) +
                                               ": the file ended early (it was " + std::to_string(size) +
                                               " bytes when the upload started; was it changed meanwhile?)");
        }
        offset += max;
        return std::string_view(buffer);
      },
      settings);
}

std::chrono::system_clock::time_point upload_deadline(const Connection& connection, std::uint64_t bytes) {
  return connection.unary_deadline() + std::chrono::seconds(1 + bytes / (std::uint64_t{1} << 20));
}

InputLimits input_limits(Connection& connection) {
  InputLimits limits;
  if (const auto& info = connection.server_info()) {
    if (info->limits().max_particles() > 0) limits.max_particles = info->limits().max_particles();
    if (info->limits().max_upload_bytes() > 0) limits.max_upload_bytes = info->limits().max_upload_bytes();
  }
  return limits;
}

namespace {

// Reads and uploads one pending input within `limits`, filling the spec's upload id; one progress line ("uploaded
// N/TOTAL: ...").
void upload_one(Connection& connection, v1::JobSpec& spec, const PendingUpload& pending, const InputLimits& limits,
                ProgressDisplay& progress, const std::atomic<bool>* stop, int total, UploadSummary& summary) {
  // Read one input, upload it, drop it: only one input is in memory at a time.
  UploadData data = pending.read(spec, limits);
  const std::uint64_t size = data.file ? data.file_bytes : data.bytes.size();
  UploadSettings settings;
  settings.deadline = upload_deadline(connection, size);
  settings.stop = stop;
  const UploadResult result = data.file ? upload_file(connection.stub(), data.name, *data.file, settings)
                                        : upload_bytes(connection.stub(), data.name, data.bytes, settings);
  pending.set_id(spec, result.upload_id);
  ++summary.uploads;
  summary.bytes += result.bytes;
  if (data.particles && pending.frame >= 0) summary.particles[pending.frame] = *data.particles;
  progress.line("uploaded " + std::to_string(summary.uploads) + "/" + std::to_string(total) + ": " +
                pending.description + ": " + (data.detail.empty() ? "" : data.detail + ", ") + size_text(result.bytes) +
                " -> " + result.upload_id);
}

}  // namespace

UploadSummary upload_inputs(Connection& connection, v1::JobSpec& spec, const std::vector<PendingUpload>& uploads,
                            ProgressDisplay& progress, const std::atomic<bool>* stop, std::size_t count) {
  UploadSummary summary;
  const InputLimits limits = uploads.empty() ? InputLimits{} : input_limits(connection);
  const int total = static_cast<int>(uploads.size());
  for (std::size_t i = 0; i < std::min(count, uploads.size()); ++i) {
    if (stop != nullptr && stop->load()) {
      throw CliError(ExitCode::kCancelled, "interrupted before the job was submitted (while uploading inputs)");
    }
    upload_one(connection, spec, uploads[i], limits, progress, stop, total, summary);
  }
  return summary;
}

bool streams_as_open_sequence(Connection& connection, const v1::JobSpec& spec,
                              const std::vector<PendingUpload>& uploads) {
  if (!spec.has_particles() || uploads.size() < 2 || spec.particles().frames_size() != static_cast<int>(uploads.size()))
    return false;
  for (std::size_t i = 0; i < uploads.size(); ++i) {
    if (uploads[i].frame != static_cast<int>(i)) return false;
  }
  return takes_open_sequences(connection);
}

bool takes_open_sequences(Connection& connection) {
  const auto& info = connection.server_info();
  return info && info->open_sequences();
}

v1::JobSpec open_sequence_spec(const v1::JobSpec& spec) {
  v1::JobSpec first = spec;
  v1::ParticlesJob& job = *first.mutable_particles();
  while (job.frames_size() > 1) job.mutable_frames()->RemoveLast();
  job.set_open(true);
  return first;
}

v1::Job append_frames(Connection& connection, const std::string& job_id, const std::vector<v1::ParticleFrame>& frames,
                      bool end, const std::string& abort_reason) {
  v1::AppendFramesRequest request;
  request.set_job_id(job_id);
  for (const v1::ParticleFrame& frame : frames) *request.add_frames() = frame;
  request.set_end(end);
  request.set_abort_reason(abort_reason);
  grpc::ClientContext context;
  context.set_deadline(connection.unary_deadline());
  v1::Job job;
  const grpc::Status status = connection.stub().AppendFrames(&context, request, &job);
  if (!status.ok()) throw rpc_error("adding frames to job " + job_id, status);
  return job;
}

SequenceFeeder::SequenceFeeder(Connection& connection, std::string job_id, v1::JobSpec spec,
                               std::vector<PendingUpload> uploads, UploadSummary summary, ProgressDisplay& progress,
                               const std::atomic<bool>* stop)
    : connection_(connection),
      job_id_(std::move(job_id)),
      spec_(std::move(spec)),
      uploads_(std::move(uploads)),
      summary_(std::move(summary)),
      progress_(progress),
      stop_(stop),
      thread_([this] { run(); }) {}

SequenceFeeder::~SequenceFeeder() {
  quit_ = true;
  if (thread_.joinable()) thread_.join();
}

void SequenceFeeder::run() {
  const InputLimits limits = input_limits(connection_);
  const int total = static_cast<int>(uploads_.size());
  const auto stopped = [this] {
    if (stop_ != nullptr && stop_->load()) quit_ = true;
    return quit_.load();
  };
  for (int k = 1; k < total && !stopped(); ++k) {
    try {
      upload_one(connection_, spec_, uploads_[k], limits, progress_, &quit_, total, summary_);
      append_frames(connection_, job_id_, {spec_.particles().frames(uploads_[k].frame)}, k + 1 == total);
      if (k + 1 == total) ended_ = true;
    } catch (const CliError& e) {
      // A job that has finished (cancelled by Ctrl-C, failed on a frame) takes no more frames: nothing to report.
      if (stopped() || e.status_code() == static_cast<int>(grpc::StatusCode::FAILED_PRECONDITION)) return;
      const std::string reason = uploads_[k].description + ": " + e.what();
      error_ = std::make_exception_ptr(CliError(e.code(), reason, e.status_code()));
      try {
        append_frames(connection_, job_id_, {}, false, reason);
      } catch (const CliError&) {
        // The server is gone or the job is over: the watcher reports that.
      }
      return;
    }
  }
}

void SequenceFeeder::stop() { quit_ = true; }

UploadSummary SequenceFeeder::finish() {
  if (thread_.joinable()) thread_.join();
  if (error_) std::rethrow_exception(error_);
  return summary_;
}

}  // namespace surfacer::client
