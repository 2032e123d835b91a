#include "server/service.h"

#include <mutex>

#include "core/errors.h"
#include "server/job_types.h"
#include "server/log.h"
#include "server/status_map.h"

namespace surfacer::server {
namespace {

grpc::Status not_found(const std::string& id) {
  return {grpc::StatusCode::NOT_FOUND,
          "job_id: no job '" + id + "' on this server (finished jobs are kept for a limited time; see ListJobs)"};
}

grpc::Status invalid_job_id(const std::string& id) {
  return id.empty() ? grpc::Status(grpc::StatusCode::INVALID_ARGUMENT, "job_id is empty; give the id SubmitJob returned")
                    : not_found(id);
}

// Streams one job's events. Kept alive by a self-reference until OnDone, and by the job's weak listener list
// while a notification runs, so a worker thread never touches a deleted reactor.
class WatchReactor final : public grpc::ServerWriteReactor<v1::JobEvent>,
                           public JobListener,
                           public std::enable_shared_from_this<WatchReactor> {
 public:
  static WatchReactor* start(std::shared_ptr<Job> job, const v1::WatchJobRequest& request) {
    auto reactor = std::shared_ptr<WatchReactor>(new WatchReactor(std::move(job), request));
    reactor->self_ = reactor;
    reactor->job_->add_listener(reactor);
    reactor->pump();
    return reactor.get();
  }

  void on_job_changed() override { pump(); }
  void OnWriteDone(bool ok) override {
    {
      std::lock_guard lock(mutex_);
      writing_ = false;
      if (!ok) broken_ = true;
    }
    pump();
  }
  void OnCancel() override {
    {
      std::lock_guard lock(mutex_);
      broken_ = true;
    }
    pump();
  }
  void OnDone() override {
    auto keep = std::move(self_);  // may destroy this when the last notification has returned
  }

 private:
  WatchReactor(std::shared_ptr<Job> job, const v1::WatchJobRequest& request) : job_(std::move(job)) {
    cursor_.from_frame = request.from_frame();
    cursor_.skip_frames = request.skip_frames();
  }

  // Writes the next event if none is in flight; finishes the RPC after the terminal state or on cancel.
  void pump() {
    std::unique_lock lock(mutex_);
    if (writing_ || finished_) return;
    if (broken_) {
      finished_ = true;
      lock.unlock();
      Finish(grpc::Status(grpc::StatusCode::CANCELLED, "watch cancelled"));
      return;
    }
    if (!job_->next_event(cursor_, event_)) {
      if (cursor_.done) {
        finished_ = true;
        lock.unlock();
        Finish(grpc::Status::OK);
      }
      return;
    }
    writing_ = true;
    lock.unlock();
    StartWrite(&event_);
  }

  std::shared_ptr<Job> job_;
  std::shared_ptr<WatchReactor> self_;
  std::mutex mutex_;
  WatchCursor cursor_;
  v1::JobEvent event_;  // stable while a write is in flight
  bool writing_ = false;
  bool finished_ = false;
  bool broken_ = false;
};

// Reassembles a client-streamed upload, checking sizes and checksums as chunks arrive.
class UploadReactor final : public grpc::ServerReadReactor<v1::UploadChunk> {
 public:
  UploadReactor(ServiceState& state, v1::UploadResponse* response)
      : state_(state), response_(response), blob_(std::make_shared<UploadBlob>()) {
    StartRead(&chunk_);
  }

  void OnReadDone(bool ok) override {
    if (!ok) {
      complete();
      return;
    }
    if (chunks_ == 0) {
      blob_->name = chunk_.name();
      expected_ = chunk_.total_bytes();
      if (expected_ > static_cast<std::uint64_t>(state_.options.limits.max_upload_bytes)) {
        fail_limit(expected_);
        return;
      }
      if (expected_ > 0) blob_->bytes.reserve(expected_);
    }
    const std::string& data = chunk_.data();
    if (chunk_.has_crc32() && crc32_of(data.data(), data.size()) != chunk_.crc32()) {
      Finish(grpc::Status(grpc::StatusCode::DATA_LOSS, "chunk " + std::to_string(chunks_) +
                                                            ": crc32 does not match its data; resend the upload"));
      return;
    }
    if (blob_->bytes.size() + data.size() > static_cast<std::uint64_t>(state_.options.limits.max_upload_bytes)) {
      fail_limit(blob_->bytes.size() + data.size());
      return;
    }
    crc_ = crc32_of(data.data(), data.size(), crc_);
    blob_->bytes += data;
    ++chunks_;
    StartRead(&chunk_);
  }

  void OnDone() override { delete this; }

 private:
  void fail_limit(std::uint64_t bytes) {
    Finish(grpc::Status(grpc::StatusCode::RESOURCE_EXHAUSTED,
                        "upload of " + std::to_string(bytes) + " bytes exceeds the server's limit of " +
                            std::to_string(state_.options.limits.max_upload_bytes) +
                            " bytes; start the server with a larger --max-upload-bytes"));
  }

  void complete() {
    if (expected_ != 0 && expected_ != blob_->bytes.size()) {
      Finish(grpc::Status(grpc::StatusCode::DATA_LOSS, "total_bytes: the first chunk announced " +
                                                           std::to_string(expected_) + " bytes but " +
                                                           std::to_string(blob_->bytes.size()) + " arrived"));
      return;
    }
    blob_->crc32 = crc_;
    response_->set_bytes(blob_->bytes.size());
    response_->set_crc32(crc_);
    const std::string name = blob_->name;
    const auto size = blob_->bytes.size();
    response_->set_upload_id(state_.uploads->add(std::move(blob_)));
    log_event(LogLevel::kInfo, "upload",
              {{"upload", response_->upload_id()}, {"name", name}, {"bytes", std::to_string(size)}});
    Finish(grpc::Status::OK);
  }

  ServiceState& state_;
  v1::UploadResponse* response_;
  std::shared_ptr<UploadBlob> blob_;
  v1::UploadChunk chunk_;
  std::uint64_t expected_ = 0;
  std::uint32_t crc_ = 0;
  int chunks_ = 0;
};

}  // namespace

grpc::ServerUnaryReactor* SurfacerService::SubmitJob(grpc::CallbackServerContext* context,
                                                     const v1::SubmitJobRequest* request,
                                                     v1::SubmitJobResponse* response) {
  auto* reactor = context->DefaultReactor();
  if (!state_.accepting.load()) {
    reactor->Finish(grpc::Status(grpc::StatusCode::UNAVAILABLE, "server is shutting down; submit to another server"));
    return reactor;
  }
  try {
    state_.scheduler->forget_finished(state_.options.keep_finished);
    JobContext job_context{state_.options.limits, *state_.uploads, state_.worker_threads};
    auto runner = make_job_runner(request->spec(), job_context);
    auto job = std::make_shared<Job>(random_id("j-"), request->spec().name(), std::move(runner));
    state_.scheduler->submit(job);
    response->set_job_id(job->id());
    *response->mutable_job() = job->snapshot();
    reactor->Finish(grpc::Status::OK);
  } catch (...) {
    const grpc::Status status = status_from_exception(std::current_exception());
    log_event(LogLevel::kInfo, "job_rejected",
              {{"code", std::to_string(status.error_code())}, {"error", status.error_message()}});
    reactor->Finish(status);
  }
  return reactor;
}

grpc::ServerReadReactor<v1::UploadChunk>* SurfacerService::Upload(grpc::CallbackServerContext*,
                                                                  v1::UploadResponse* response) {
  return new UploadReactor(state_, response);
}

grpc::ServerWriteReactor<v1::JobEvent>* SurfacerService::WatchJob(grpc::CallbackServerContext*,
                                                                  const v1::WatchJobRequest* request) {
  auto job = state_.scheduler->find(request->job_id());
  if (!job || request->from_frame() < 0) {
    // A reactor that only reports the error.
    class Failed final : public grpc::ServerWriteReactor<v1::JobEvent> {
     public:
      explicit Failed(const grpc::Status& status) { Finish(status); }
      void OnDone() override { delete this; }
    };
    if (job) {
      return new Failed(grpc::Status(grpc::StatusCode::INVALID_ARGUMENT,
                                     "from_frame (" + std::to_string(request->from_frame()) + ") must be >= 0"));
    }
    return new Failed(invalid_job_id(request->job_id()));
  }
  return WatchReactor::start(std::move(job), *request);
}

grpc::ServerUnaryReactor* SurfacerService::GetJob(grpc::CallbackServerContext* context,
                                                  const v1::GetJobRequest* request, v1::Job* response) {
  auto* reactor = context->DefaultReactor();
  if (auto job = state_.scheduler->find(request->job_id())) {
    *response = job->snapshot();
    reactor->Finish(grpc::Status::OK);
  } else {
    reactor->Finish(invalid_job_id(request->job_id()));
  }
  return reactor;
}

grpc::ServerUnaryReactor* SurfacerService::ListJobs(grpc::CallbackServerContext* context,
                                                    const v1::ListJobsRequest* request,
                                                    v1::ListJobsResponse* response) {
  auto* reactor = context->DefaultReactor();
  for (const auto& job : state_.scheduler->list()) {
    v1::Job snapshot = job->snapshot();
    bool keep = request->states_size() == 0;
    for (int s : request->states()) keep = keep || s == snapshot.state();
    if (keep) *response->add_jobs() = std::move(snapshot);
  }
  reactor->Finish(grpc::Status::OK);
  return reactor;
}

grpc::ServerUnaryReactor* SurfacerService::CancelJob(grpc::CallbackServerContext* context,
                                                     const v1::CancelJobRequest* request, v1::Job* response) {
  auto* reactor = context->DefaultReactor();
  if (auto job = state_.scheduler->find(request->job_id())) {
    job->cancel("cancelled by client");
    *response = job->snapshot();
    reactor->Finish(grpc::Status::OK);
  } else {
    reactor->Finish(invalid_job_id(request->job_id()));
  }
  return reactor;
}

}  // namespace surfacer::server
