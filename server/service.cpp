#include "server/service.h"

#include <google/protobuf/io/coded_stream.h>
#include <grpcpp/support/proto_buffer_reader.h>

#include <algorithm>
#include <charconv>
#include <condition_variable>
#include <mutex>
#include <optional>
#include <set>
#include <thread>
#include <unordered_map>

#include "core/util/errors.h"
#include "core/util/format.h"
#include "core/util/version.h"
#include "server/log.h"
#include "server/memory_budget.h"
#include "server/runners/runner.h"
#include "server/server_metrics.h"
#include "server/status_map.h"
#include "server/store.h"
#include "server/upload_assembler.h"
#include "wire/enums.h"
#include "wire/protocol.h"
#include "wire/request_limits.h"
#include "wire/status.h"
#include "wire/uploads.h"

namespace surfacer::server {

// Uploads being received, for ending those whose client went quiet (--upload-idle-timeout). Its thread starts with
// the first upload (the server's options are final by then) and looks a few times per timeout.
class OpenUploads {
 public:
  class Session {
   public:
    virtual ~Session() = default;
    // Marks the upload ended and frees its bytes if nothing arrived since `cutoff`; returns whether it did. Called
    // under the registry's lock, so it must not finish the call: finish_expired() does, after the lock is let go.
    virtual bool expire_if_idle(std::chrono::steady_clock::time_point cutoff) = 0;
    virtual void finish_expired() = 0;
  };

  explicit OpenUploads(const ServiceState& state) : state_(state) {}
  ~OpenUploads() {
    {
      std::lock_guard lock(mutex_);
      stop_ = true;
    }
    wake_.notify_all();
    if (thread_.joinable()) thread_.join();
  }

  void add(Session* session) {
    std::lock_guard lock(mutex_);
    sessions_.insert(session);
    if (!thread_.joinable()) thread_ = std::thread([this] { loop(); });
  }
  // Called from the session's OnDone: after it returns, the registry never touches the session again.
  void remove(Session* session) {
    std::lock_guard lock(mutex_);
    sessions_.erase(session);
  }

 private:
  void loop() {
    const std::chrono::milliseconds timeout = state_.options.upload_idle_timeout;
    const auto period = std::clamp<std::chrono::milliseconds>(timeout / 4, std::chrono::milliseconds(10),
                                                              std::chrono::milliseconds(1000));
    std::unique_lock lock(mutex_);
    while (!stop_) {
      wake_.wait_for(lock, period, [this] { return stop_; });
      if (stop_) break;
      const auto cutoff = std::chrono::steady_clock::now() - timeout;
      std::vector<Session*> expired;
      for (Session* session : sessions_) {
        if (session->expire_if_idle(cutoff)) expired.push_back(session);
      }
      // A session marked expired gets no OnDone before its Finish, so it stays alive until finish_expired().
      lock.unlock();
      for (Session* session : expired) session->finish_expired();
      lock.lock();
    }
  }

  const ServiceState& state_;
  std::mutex mutex_;
  std::condition_variable wake_;
  std::set<Session*> sessions_;
  bool stop_ = false;
  std::thread thread_;
};

// How many WatchJob streams each job has open (--max-watchers-per-job).
class WatchSlots {
 public:
  // Takes a slot on `job_id` unless `max` are taken.
  bool try_take(const std::string& job_id, int max) {
    std::lock_guard lock(mutex_);
    int& open = open_[job_id];
    if (open >= max) return false;
    ++open;
    return true;
  }
  void give_back(const std::string& job_id) {
    std::lock_guard lock(mutex_);
    auto it = open_.find(job_id);
    if (it != open_.end() && --it->second <= 0) open_.erase(it);
  }

 private:
  std::mutex mutex_;
  std::unordered_map<std::string, int> open_;
};

namespace {

// What one WatchJob stream holds at most: the chunk in its event and gRPC's serialized copy of it.
constexpr std::int64_t kWatchStreamBytes = 2 * static_cast<std::int64_t>(wire::kMaxChunkBytes);

// A reactor that only reports an error.
class FailedWrite final : public grpc::ServerWriteReactor<v1::JobEvent> {
 public:
  explicit FailedWrite(const grpc::Status& status) { Finish(status); }
  void OnDone() override { delete this; }
};
class FailedRead final : public grpc::ServerReadReactor<v1::UploadChunk> {
 public:
  explicit FailedRead(const grpc::Status& status) { Finish(status); }
  void OnDone() override { delete this; }
};

grpc::Status invalid_job_id(const std::string& id) {
  if (id.empty()) return {grpc::StatusCode::INVALID_ARGUMENT, "job_id is empty; give the id SubmitJob returned"};
  if (id.size() > wire::kMaxIdBytes) {
    return {grpc::StatusCode::INVALID_ARGUMENT, "job_id is " + std::to_string(id.size()) + " bytes; ids are at most " +
                                                    std::to_string(wire::kMaxIdBytes) +
                                                    " bytes (give the id SubmitJob returned)"};
  }
  return {grpc::StatusCode::NOT_FOUND,
          "job_id: no job " + quote(id) + " on this server (finished jobs are kept for a limited time; see ListJobs)"};
}

// The request of a SubmitJob call. Parsed here rather than by gRPC so that a scene nested deeper than the parser
// allows gets the same INVALID_ARGUMENT as one a level too deep (gRPC would answer a blank UNIMPLEMENTED).
v1::SubmitJobRequest parse_submit_request(const grpc::ByteBuffer& bytes) {
  v1::SubmitJobRequest request;
  grpc::ByteBuffer copy(bytes);  // the reader consumes its buffer
  grpc::ProtoBufferReader reader(&copy);
  google::protobuf::io::CodedInputStream coded(&reader);
  coded.SetRecursionLimit(wire::kRequestRecursionLimit);
  if (request.ParseFromCodedStream(&coded) && coded.ConsumedEntireMessage()) return request;
  std::vector<grpc::Slice> slices;
  std::string flat;
  if (bytes.Dump(&slices).ok()) {
    for (const grpc::Slice& slice : slices) flat.append(reinterpret_cast<const char*>(slice.begin()), slice.size());
  }
  if (wire::wire_nests_deeper_than(flat, wire::kRequestRecursionLimit - 1)) {
    throw InvalidInput("spec", "spec: " + wire::scene_too_deep());
  }
  throw InvalidInput("spec", "the request is not a valid surfacer.v1.SubmitJobRequest (malformed protobuf)");
}

// Streams one job's events. Kept alive by a self-reference until OnDone, and by the job's weak listener list
// while a notification runs, so a worker thread never touches a deleted reactor.
class WatchReactor final : public grpc::ServerWriteReactor<v1::JobEvent>,
                           public JobListener,
                           public std::enable_shared_from_this<WatchReactor> {
 public:
  // `slots`: where the stream's slot on its job was taken (given back when the stream ends); `buffers`: its share
  // of the memory budget.
  static WatchReactor* start(std::shared_ptr<Job> job, const v1::WatchJobRequest& request, ServerMetrics* metrics,
                             WatchSlots* slots, MemoryReservation buffers) {
    auto reactor = std::shared_ptr<WatchReactor>(new WatchReactor(std::move(job), request));
    reactor->metrics_ = metrics;
    reactor->slots_ = slots;
    reactor->buffers_ = std::move(buffers);
    if (metrics) metrics->watchers.inc();
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
    if (metrics_) metrics_->watchers.dec();
    if (slots_) slots_->give_back(job_->id());
    buffers_.release();
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
    bool more = false;
    try {
      more = job_->next_event(cursor_, event_);
    } catch (const std::exception& e) {
      finished_ = true;
      lock.unlock();
      Finish(grpc::Status(grpc::StatusCode::DATA_LOSS, e.what()));
      return;
    }
    if (!more) {
      if (cursor_.done) {
        finished_ = true;
        lock.unlock();
        Finish(grpc::Status::OK);
      }
      return;
    }
    writing_ = true;
    if (metrics_ && event_.has_chunk()) metrics_->bytes_out.inc(static_cast<double>(event_.chunk().data().size()));
    lock.unlock();
    StartWrite(&event_);
  }

  std::shared_ptr<Job> job_;
  std::shared_ptr<WatchReactor> self_;
  ServerMetrics* metrics_ = nullptr;
  WatchSlots* slots_ = nullptr;
  MemoryReservation buffers_;
  std::mutex mutex_;
  WatchCursor cursor_;
  v1::JobEvent event_;  // stable while a write is in flight
  bool writing_ = false;
  bool finished_ = false;
  bool broken_ = false;
};

// Reassembles a client-streamed upload (UploadAssembler), then stores it under the caller's tenant. Only a stream
// the client closed normally is stored, and only if the client can learn its id: an upload whose call ends
// cancelled (client cancel, deadline, a message gRPC refused) is forgotten again, wherever it was kept.
class UploadReactor final : public grpc::ServerReadReactor<v1::UploadChunk>, public OpenUploads::Session {
 public:
  // The smaller of --max-upload-bytes and what the tenant's stored-bytes quota has left.
  static std::int64_t limit(const ServiceState& state, const Tenant& tenant) {
    std::int64_t max = state.options.limits.max_upload_bytes;
    if (tenant.max_stored_bytes > 0 && state.usage) {
      max = std::min(max, std::max<std::int64_t>(0, tenant.max_stored_bytes - state.usage->bytes(tenant.name)));
    }
    return max;
  }

  UploadReactor(ServiceState& state, grpc::CallbackServerContext& context, const Tenant& tenant,
                v1::UploadResponse* response, OpenUploads& open_uploads)
      : state_(state),
        context_(context),
        tenant_(tenant),
        response_(response),
        open_uploads_(open_uploads),
        assembler_(limit(state, tenant), hint(state, tenant), state.memory) {
    open_uploads_.add(this);
    StartRead(&chunk_);
  }

  void OnReadDone(bool ok) override {
    std::unique_lock lock(mutex_);
    if (finished_) return;  // ended as idle meanwhile
    last_activity_ = std::chrono::steady_clock::now();
    if (!ok) {
      // The stream ended: closed by the client, or cancelled (then nothing is stored).
      finished_ = true;
      lock.unlock();
      if (context_.IsCancelled()) {
        Finish(grpc::Status(grpc::StatusCode::CANCELLED, "upload cancelled; nothing was stored"));
      } else {
        complete();
      }
      return;
    }
    state_.upload_activity.touch(tenant_.name);
    if (const grpc::Status status = assembler_.add(chunk_); !status.ok()) {
      finished_ = true;
      lock.unlock();
      Finish(status);
      return;
    }
    StartRead(&chunk_);
  }

  bool expire_if_idle(std::chrono::steady_clock::time_point cutoff) override {
    std::unique_lock lock(mutex_, std::try_to_lock);  // busy with a chunk: not idle
    if (!lock.owns_lock() || finished_ || last_activity_ > cutoff) return false;
    finished_ = true;
    const auto seconds = std::chrono::duration<double>(state_.options.upload_idle_timeout).count();
    expired_ = grpc::Status(grpc::StatusCode::DEADLINE_EXCEEDED,
                            "upload: no chunk arrived for " + format_number(seconds) +
                                " s (the server's --upload-idle-timeout), so the upload was ended and the " +
                                std::to_string(assembler_.bytes()) +
                                " bytes received were dropped; nothing was stored. Send the upload again without "
                                "pausing between chunks, or start the server with a larger --upload-idle-timeout");
    assembler_.abandon(expired_);
    return true;
  }
  void finish_expired() override {
    log_event(LogLevel::kInfo, "upload_idle", {{"tenant", tenant_.name}, {"error", expired_.error_message()}});
    Finish(expired_);
  }

  void OnDone() override {
    open_uploads_.remove(this);
    // The reply never reached the client: it cannot know the id, so the upload must not stay.
    if (!stored_id_.empty() && context_.IsCancelled()) {
      const std::int64_t bytes = state_.uploads->remove(stored_id_);
      if (state_.usage) state_.usage->release(tenant_.name, bytes);
      log_event(LogLevel::kInfo, "upload_dropped",
                {{"upload", stored_id_}, {"tenant", tenant_.name}, {"reason", "cancelled before the reply"}});
    }
    delete this;
  }

 private:
  static std::string hint(const ServiceState& state, const Tenant& tenant) {
    if (tenant.max_stored_bytes > 0 && state.usage &&
        tenant.max_stored_bytes - state.usage->bytes(tenant.name) < state.options.limits.max_upload_bytes) {
      return "tenant '" + tenant.name + "' has " + std::to_string(state.usage->bytes(tenant.name)) + " of its " +
             std::to_string(tenant.max_stored_bytes) +
             " quota bytes stored (quota.bytes); wait for older jobs to expire or raise bytes= for its token";
    }
    return "start the server with a larger --max-upload-bytes";
  }

  void complete() {
    if (const grpc::Status status = assembler_.finish(); !status.ok()) {
      Finish(status);
      return;
    }
    std::shared_ptr<UploadBlob> blob = assembler_.take();
    MemoryReservation held = assembler_.take_reservation();
    const auto size = static_cast<std::int64_t>(blob->bytes.size());
    if (state_.usage && !state_.usage->try_add(tenant_.name, size, tenant_.max_stored_bytes)) {
      Finish(grpc::Status(grpc::StatusCode::RESOURCE_EXHAUSTED, "upload: " + hint(state_, tenant_)));
      return;
    }
    try {
      response_->set_bytes(blob->bytes.size());
      response_->set_crc32(blob->crc32);
      const std::string name = blob->name;
      stored_id_ = state_.uploads->add(std::move(blob), tenant_.name, std::move(held));
      response_->set_upload_id(stored_id_);
      if (state_.metrics) state_.metrics->bytes_in.inc(static_cast<double>(size));
      log_event(LogLevel::kInfo, "upload",
                {{"upload", response_->upload_id()},
                 {"tenant", tenant_.name},
                 {"name", name},
                 {"bytes", std::to_string(size)}});
      Finish(grpc::Status::OK);
    } catch (...) {
      if (state_.usage) state_.usage->release(tenant_.name, size);
      Finish(status_from_exception(std::current_exception()));
    }
  }

  ServiceState& state_;
  grpc::CallbackServerContext& context_;
  const Tenant tenant_;
  v1::UploadResponse* response_;
  OpenUploads& open_uploads_;
  std::mutex mutex_;  // the assembler and the fields below, shared with the idle check
  UploadAssembler assembler_;
  std::chrono::steady_clock::time_point last_activity_ = std::chrono::steady_clock::now();
  bool finished_ = false;  // Finish is called (or, expired, about to be) by whoever set this
  grpc::Status expired_;
  v1::UploadChunk chunk_;
  std::string stored_id_;  // set once the upload is stored
};

// The job `id` if it exists and belongs to `tenant` (another tenant's job is reported as missing).
std::shared_ptr<Job> find_owned(const ServiceState& state, const std::string& id, const Tenant& tenant) {
  auto job = state.scheduler->find(id);
  return job && job->owner() == tenant.name ? job : nullptr;
}

}  // namespace

const Tenant* authenticate(const ServiceState& state, const grpc::CallbackServerContext& context,
                           grpc::Status& status) {
  if (!state.auth) return &state.open_tenant;
  const auto& metadata = context.client_metadata();
  auto it = metadata.find("authorization");
  const Tenant* tenant =
      it == metadata.end() ? nullptr : state.auth->authenticate(std::string_view(it->second.data(), it->second.size()));
  if (!tenant) {
    status = grpc::Status(grpc::StatusCode::UNAUTHENTICATED,
                          it == metadata.end()
                              ? "this server requires a bearer token: send metadata `authorization: Bearer TOKEN` "
                                "(surfacer --token TOKEN, or $SURFACER_TOKEN)"
                              : "the bearer token is not known to this server; check the token");
  }
  return tenant;
}

namespace {
// The caller's tenant; otherwise finishes the call with UNAUTHENTICATED and returns null.
const Tenant* tenant_or_finish(const ServiceState& state, const grpc::CallbackServerContext& context,
                               grpc::ServerUnaryReactor* reactor) {
  grpc::Status status;
  const Tenant* tenant = authenticate(state, context, status);
  if (!tenant) reactor->Finish(status);
  return tenant;
}
}  // namespace

SurfacerService::SurfacerService(ServiceState& state)
    : state_(state), open_uploads_(std::make_unique<OpenUploads>(state)), watch_slots_(std::make_unique<WatchSlots>()) {}

SurfacerService::~SurfacerService() = default;

grpc::ServerUnaryReactor* SurfacerService::SubmitJob(grpc::CallbackServerContext* context,
                                                     const grpc::ByteBuffer* request_bytes,
                                                     grpc::ByteBuffer* response_bytes) {
  auto* reactor = context->DefaultReactor();
  if (!state_.accepting.load()) {
    reactor->Finish(grpc::Status(grpc::StatusCode::UNAVAILABLE, "server is shutting down; submit to another server"));
    return reactor;
  }
  const Tenant* tenant = tenant_or_finish(state_, *context, reactor);
  if (!tenant) return reactor;
  v1::SubmitJobResponse response;
  grpc::Status status;
  try {
    submit(parse_submit_request(*request_bytes), *tenant, response);
    bool own_buffer = false;
    status = grpc::SerializationTraits<v1::SubmitJobResponse>::Serialize(response, response_bytes, &own_buffer);
  } catch (...) {
    status = status_from_exception(std::current_exception());
    if (state_.metrics)
      state_.metrics->jobs_rejected.with({std::string(wire::status_code_name(status.error_code()))}).inc();
    log_event(LogLevel::kInfo, "job_rejected",
              {{"code", std::to_string(status.error_code())}, {"error", status.error_message()}});
  }
  reactor->Finish(status);
  return reactor;
}

void SurfacerService::submit(const v1::SubmitJobRequest& request, const Tenant& tenant,
                             v1::SubmitJobResponse& response) {
  wire::check_request_limits(request.spec(), "spec");
  // Another tenant's uploads do not exist for this one.
  std::vector<std::string> uploads;
  for (const auto& [path, id] : Store::referenced_upload_fields(request.spec(), "spec")) {
    if (!state_.uploads->owned_by(id, tenant.name)) throw wire::unknown_upload(id, path);
    uploads.push_back(id);
  }
  // The running= quota: checked now (before the spec's work), and again where the job is added, atomically with it.
  const auto check_running = [&tenant](int active) {
    if (tenant.max_running_jobs > 0 && active >= tenant.max_running_jobs) {
      throw ResourceLimit("quota.running", "tenant '" + tenant.name + "' already has " +
                                               std::to_string(tenant.max_running_jobs) +
                                               " queued or running jobs (its quota); wait for one to finish, or "
                                               "raise running= for its token in the server's --tokens-file");
    }
  };
  check_running(state_.scheduler->active_jobs(tenant.name));
  JobContext job_context{state_.options.limits, *state_.uploads, state_.worker_threads, state_.memory};
  JobInit init;
  init.id = random_id("j-");
  init.name = request.spec().name();
  init.owner = tenant.name;
  init.runner = make_job_runner(request.spec(), job_context);
  init.store = state_.store;
  init.usage = state_.usage;
  init.max_stored_bytes = tenant.max_stored_bytes;
  init.upload_ids = std::move(uploads);
  init.hooks = state_.hooks;
  v1::JobSpec stored_spec = request.spec();
  init.runner->pin(stored_spec);  // what a restart must not derive again (an open sequence's box)
  init.spec = stored_spec;
  auto job = std::make_shared<Job>(std::move(init));
  if (state_.store) state_.store->put_job(job->id(), tenant.name, stored_spec, job->snapshot());
  try {
    state_.scheduler->submit(job, check_running);
  } catch (...) {
    if (state_.store) state_.store->delete_job(job->id());
    throw;
  }
  if (state_.metrics) state_.metrics->jobs_submitted.with({job->kind()}).inc();
  response.set_job_id(job->id());
  *response.mutable_job() = job->snapshot();
}

grpc::ServerReadReactor<v1::UploadChunk>* SurfacerService::Upload(grpc::CallbackServerContext* context,
                                                                  v1::UploadResponse* response) {
  grpc::Status auth_status;
  const Tenant* tenant = authenticate(state_, *context, auth_status);
  if (!tenant) return new FailedRead(auth_status);
  return new UploadReactor(state_, *context, *tenant, response, *open_uploads_);
}

grpc::ServerUnaryReactor* SurfacerService::AppendFrames(grpc::CallbackServerContext* context,
                                                        const v1::AppendFramesRequest* request, v1::Job* response) {
  auto* reactor = context->DefaultReactor();
  const Tenant* tenant = tenant_or_finish(state_, *context, reactor);
  if (!tenant) return reactor;
  auto job = find_owned(state_, request->job_id(), *tenant);
  if (!job) {
    reactor->Finish(invalid_job_id(request->job_id()));
    return reactor;
  }
  grpc::Status status;
  try {
    wire::check_request_limits(*request, "request");
    // Another tenant's uploads do not exist for this one.
    for (const auto& [path, id] : Store::referenced_upload_fields(*request, "request")) {
      if (!state_.uploads->owned_by(id, tenant->name)) throw wire::unknown_upload(id, path);
    }
    std::vector<int> tasks;
    status = job->append_frames(*request, tasks);
    state_.scheduler->add_tasks(job, std::move(tasks));
  } catch (...) {
    status = status_from_exception(std::current_exception());
  }
  if (status.ok()) *response = job->snapshot();
  reactor->Finish(status);
  return reactor;
}

grpc::ServerWriteReactor<v1::JobEvent>* SurfacerService::WatchJob(grpc::CallbackServerContext* context,
                                                                  const v1::WatchJobRequest* request) {
  grpc::Status auth_status;
  const Tenant* tenant = authenticate(state_, *context, auth_status);
  if (!tenant) return new FailedWrite(auth_status);
  auto job = find_owned(state_, request->job_id(), *tenant);
  if (!job) return new FailedWrite(invalid_job_id(request->job_id()));
  if (request->from_frame() < 0) {
    return new FailedWrite(grpc::Status(grpc::StatusCode::INVALID_ARGUMENT,
                                        "from_frame (" + std::to_string(request->from_frame()) + ") must be >= 0"));
  }
  const int max_watchers = state_.options.max_watchers_per_job;
  if (!watch_slots_->try_take(job->id(), max_watchers)) {
    return new FailedWrite(grpc::Status(
        grpc::StatusCode::RESOURCE_EXHAUSTED,
        "job " + job->id() + " already has " + std::to_string(max_watchers) +
            " WatchJob streams open (the server's --max-watchers-per-job); close one (a client that stopped "
            "reading still holds its stream), or start the server with a larger --max-watchers-per-job"));
  }
  MemoryReservation buffers;
  if (state_.memory) {
    try {
      buffers = state_.memory->reserve(kWatchStreamBytes, "a WatchJob stream");
    } catch (...) {
      watch_slots_->give_back(job->id());
      return new FailedWrite(status_from_exception(std::current_exception()));
    }
  }
  return WatchReactor::start(std::move(job), *request, state_.metrics, watch_slots_.get(), std::move(buffers));
}

grpc::ServerUnaryReactor* SurfacerService::GetJob(grpc::CallbackServerContext* context,
                                                  const v1::GetJobRequest* request, v1::Job* response) {
  auto* reactor = context->DefaultReactor();
  const Tenant* tenant = tenant_or_finish(state_, *context, reactor);
  if (!tenant) return reactor;
  if (auto job = find_owned(state_, request->job_id(), *tenant)) {
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
  const Tenant* tenant = tenant_or_finish(state_, *context, reactor);
  if (!tenant) return reactor;
  try {
    list_jobs(*request, *tenant, *response);
    reactor->Finish(grpc::Status::OK);
  } catch (...) {
    reactor->Finish(status_from_exception(std::current_exception()));
  }
  return reactor;
}

void SurfacerService::list_jobs(const v1::ListJobsRequest& request, const Tenant& tenant,
                                v1::ListJobsResponse& response) const {
  for (int i = 0; i < request.states_size(); ++i) {
    wire::require_known_enum(v1::JobState_descriptor(), request.states(i), "states[" + std::to_string(i) + "]");
  }
  if (request.page_size() < 0) {
    throw InvalidInput("page_size", "page_size (" + std::to_string(request.page_size()) + ") must be >= 0 (0 means " +
                                        std::to_string(wire::kDefaultListPageSize) + ")");
  }
  const int page_size =
      request.page_size() == 0 ? wire::kDefaultListPageSize : std::min(request.page_size(), wire::kMaxListPageSize);
  // Pages follow (created, id), oldest first; a token is the key of the last job of its page, so jobs removed or
  // added meanwhile neither shift nor repeat the rest.
  using Key = std::pair<std::int64_t, std::string>;
  auto key_of = [](const v1::Job& job) {
    return Key{job.created().seconds() * 1'000'000'000 + job.created().nanos(), job.id()};
  };
  std::optional<Key> after;
  if (!request.page_token().empty()) {
    const std::string& token = request.page_token();
    const auto dash = token.find('-');
    std::int64_t created = 0;
    const auto [end, ec] = std::from_chars(token.data(), token.data() + std::min(dash, token.size()), created);
    if (token.size() > wire::kMaxIdBytes || dash == std::string::npos || ec != std::errc() ||
        end != token.data() + dash) {
      throw InvalidInput("page_token", "page_token " + quote(token) +
                                           " is not one ListJobs returned; pass next_page_token as it came, or none");
    }
    after = Key{created, token.substr(dash + 1)};
  }
  std::vector<std::pair<Key, v1::Job>> jobs;
  for (const auto& job : state_.scheduler->list()) {
    if (job->owner() != tenant.name) continue;
    v1::Job snapshot = job->snapshot();
    bool keep = request.states_size() == 0;
    for (int s : request.states()) keep = keep || s == snapshot.state();
    Key key = key_of(snapshot);
    if (keep && (!after || *after < key)) jobs.emplace_back(std::move(key), std::move(snapshot));
  }
  std::sort(jobs.begin(), jobs.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
  const std::size_t n = std::min(jobs.size(), static_cast<std::size_t>(page_size));
  for (std::size_t i = 0; i < n; ++i) *response.add_jobs() = std::move(jobs[i].second);
  if (n < jobs.size()) {
    response.set_next_page_token(std::to_string(jobs[n - 1].first.first) + "-" + jobs[n - 1].first.second);
  }
}

grpc::ServerUnaryReactor* SurfacerService::CancelJob(grpc::CallbackServerContext* context,
                                                     const v1::CancelJobRequest* request, v1::Job* response) {
  auto* reactor = context->DefaultReactor();
  const Tenant* tenant = tenant_or_finish(state_, *context, reactor);
  if (!tenant) return reactor;
  if (auto job = find_owned(state_, request->job_id(), *tenant)) {
    job->cancel("cancelled by client");
    *response = job->snapshot();
    reactor->Finish(grpc::Status::OK);
  } else {
    reactor->Finish(invalid_job_id(request->job_id()));
  }
  return reactor;
}

grpc::ServerUnaryReactor* SurfacerService::GetServerInfo(grpc::CallbackServerContext* context,
                                                         const v1::GetServerInfoRequest*, v1::ServerInfo* response) {
  auto* reactor = context->DefaultReactor();
  const Tenant* tenant = tenant_or_finish(state_, *context, reactor);
  if (!tenant) return reactor;
  const Limits& limits = state_.options.limits;
  response->set_version(std::string(build_version()));
  v1::ServerLimits* out = response->mutable_limits();
  out->set_max_grid_cells(limits.max_grid_cells);
  out->set_max_particles(limits.max_particles);
  out->set_max_triangles(limits.max_triangles);
  out->set_max_upload_bytes(UploadReactor::limit(state_, *tenant));
  out->set_max_frames(limits.max_frames);
  out->set_max_chunk_bytes(static_cast<std::int32_t>(wire::kMaxChunkBytes));
  out->set_max_name_bytes(static_cast<std::int32_t>(wire::kMaxNameBytes));
  out->set_max_id_bytes(static_cast<std::int32_t>(wire::kMaxIdBytes));
  out->set_max_scene_depth(wire::kMaxSceneDepth);
  out->set_max_list_page_size(wire::kMaxListPageSize);
  response->set_open_sequences(true);
  reactor->Finish(grpc::Status::OK);
  return reactor;
}

}  // namespace surfacer::server
