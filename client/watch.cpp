#include "client/watch.h"

#include <grpcpp/client_context.h>

#include <algorithm>
#include <thread>

#include "client/frame_assembler.h"

namespace surfacer::client {

bool is_terminal(v1::JobState state) {
  return state == v1::JOB_STATE_SUCCEEDED || state == v1::JOB_STATE_FAILED || state == v1::JOB_STATE_CANCELLED;
}

JobWatcher::JobWatcher(Connection& connection, std::string job_id, int from_frame, FrameWriter& writer,
                       ProgressDisplay& progress, ReconnectPolicy policy)
    : connection_(connection),
      job_id_(std::move(job_id)),
      from_frame_(from_frame),
      writer_(&writer),
      on_frame_([&writer](const ReceivedFrame& frame) { writer.write(frame); }),
      progress_(progress),
      policy_(policy) {}

JobWatcher::JobWatcher(Connection& connection, std::string job_id, int from_frame, FrameHandler on_frame,
                       ProgressDisplay& progress, ReconnectPolicy policy, bool quiet)
    : connection_(connection),
      job_id_(std::move(job_id)),
      from_frame_(from_frame),
      on_frame_(std::move(on_frame)),
      progress_(progress),
      quiet_(quiet),
      policy_(policy) {}

void JobWatcher::stop() {
  std::lock_guard lock(mutex_);
  stopped_ = true;
  if (context_ != nullptr) context_->TryCancel();
}

int JobWatcher::next_missing() const {
  int next = from_frame_;
  while (received_.count(next) != 0) ++next;
  return next;
}

void JobWatcher::handle_frame(const ReceivedFrame& frame, int requested_from, int frames_total, WatchResult& result) {
  if (frame.index < requested_from) {
    throw CliError(ExitCode::kIntegrity, "frame " + std::to_string(frame.index) +
                                             ": the server sent it although from_frame was " +
                                             std::to_string(requested_from));
  }
  if (frames_total > 0 && frame.index >= frames_total) {
    throw CliError(ExitCode::kIntegrity, "frame " + std::to_string(frame.index) + ": beyond the job's " +
                                             std::to_string(frames_total) + " frames");
  }
  if (received_.count(frame.index) != 0) return;  // resent after a reconnect: already written
  on_frame_(frame);
  received_.insert(frame.index);
  ++result.frames_written;
  result.triangles += frame.stats.triangles();
  if (!quiet_) progress_.on_frame(frame);
}

WatchResult JobWatcher::run() {
  WatchResult result;
  FrameAssembler assembler;
  int frames_total = 0;
  int attempt = 0;
  auto last_success = std::chrono::steady_clock::now();

  while (true) {
    v1::WatchJobRequest request;
    request.set_job_id(job_id_);
    const int requested_from = next_missing();
    request.set_from_frame(requested_from);

    grpc::ClientContext context;
    {
      std::lock_guard lock(mutex_);
      if (stopped_) throw CliError(ExitCode::kCancelled, "stopped watching job " + job_id_);
      context_ = &context;
    }
    auto reader = connection_.stub().WatchJob(&context, request);
    std::optional<v1::Job> terminal;
    v1::JobEvent event;
    while (reader->Read(&event)) {
      last_success = std::chrono::steady_clock::now();
      attempt = 0;
      switch (event.event_case()) {
        case v1::JobEvent::kState: {
          const v1::Job& job = event.state();
          if (job.frames_total() > 0) frames_total = job.frames_total();
          if (!job.kind().empty() && writer_ != nullptr) writer_->set_job_kind(job.kind());
          if (!quiet_) progress_.on_state(job);
          if (is_terminal(job.state())) terminal = job;
          break;
        }
        case v1::JobEvent::kProgress:
          if (event.progress().frames_total() > 0) frames_total = event.progress().frames_total();
          if (!quiet_) progress_.on_progress(event.progress());
          if (on_progress_) on_progress_(event.progress());
          break;
        case v1::JobEvent::kFrame:
          if (auto frame = assembler.on_header(event.frame())) {
            handle_frame(*frame, requested_from, frames_total, result);
          }
          break;
        case v1::JobEvent::kChunk:
          if (auto frame = assembler.on_chunk(event.chunk())) {
            handle_frame(*frame, requested_from, frames_total, result);
          }
          break;
        default:
          break;  // an event a newer server added: not ours to interpret
      }
    }
    const grpc::Status status = reader->Finish();
    bool stopped = false;
    {
      std::lock_guard lock(mutex_);
      context_ = nullptr;
      stopped = stopped_;
    }
    if (stopped) throw CliError(ExitCode::kCancelled, "stopped watching job " + job_id_);
    if (terminal && status.ok()) {
      if (!assembler.idle()) {
        throw CliError(ExitCode::kIntegrity, "the stream of job " + job_id_ + " ended inside a frame");
      }
      result.job = *terminal;
      break;
    }
    // A stream that ends without the terminal state, or with UNAVAILABLE, is reopened; anything else is final.
    if (!status.ok() && status.error_code() != grpc::StatusCode::UNAVAILABLE) {
      throw rpc_error("watching job " + job_id_, status);
    }
    assembler.reset();
    const auto deadline = last_success + policy_.budget;
    // With a FrameHandler the caller decides what happens to the job (scale-out hands its frames to another server).
    const std::string resume = writer_ == nullptr ? std::string()
                                                  : "; resume with: surfacer watch " + job_id_ + " --from-frame " +
                                                        std::to_string(next_missing()) + " -o " + writer_->target();
    if (std::chrono::steady_clock::now() >= deadline) {
      throw CliError(ExitCode::kUnreachable,
                     "lost the connection to " + connection_.describe() + " while watching job " + job_id_ +
                         (status.ok() ? std::string(" (stream ended early)")
                                      : ": " + status_code_name(status.error_code()) + ": " + status.error_message()) +
                         resume);
    }
    const auto delay = std::min(policy_.max_delay, policy_.first_delay * (1 << std::min(attempt, 10)));
    ++attempt;
    progress_.line((quiet_ ? "job " + job_id_ + " on " + connection_.describe() + ": " : std::string()) +
                   "connection lost (" +
                   (status.ok() ? std::string("stream ended early") : status_code_name(status.error_code())) +
                   "); reconnecting from frame " + std::to_string(next_missing()) + " ...");
    std::this_thread::sleep_for(delay);
    const auto remaining = deadline - std::chrono::steady_clock::now();
    if (!connection_.wait_connected(std::chrono::system_clock::now() +
                                    std::chrono::duration_cast<std::chrono::milliseconds>(remaining))) {
      throw CliError(ExitCode::kUnreachable,
                     "lost the connection to " + connection_.describe() + " while watching job " + job_id_ + resume);
    }
  }

  if (result.job.state() == v1::JOB_STATE_SUCCEEDED) {
    // The terminal state's count is authoritative: open-ended jobs (optimize snapshots, active frames) announce an
    // upper bound while running and end with the frames they emitted.
    const int total = result.job.frames_total();
    std::string missing;
    int count = 0;
    for (int i = from_frame_; i < total; ++i) {
      if (received_.count(i) == 0) {
        if (count++ < 10) missing += (missing.empty() ? "" : ", ") + std::to_string(i);
      }
    }
    if (count > 0) {
      throw CliError(ExitCode::kIntegrity, "job " + job_id_ + " succeeded but " + std::to_string(count) +
                                               " frame(s) never arrived: " + missing + (count > 10 ? ", ..." : ""));
    }
  }
  return result;
}

}  // namespace surfacer::client
