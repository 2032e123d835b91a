#include "server/job.h"

#include <grpcpp/support/status.h>

#include <algorithm>
#include <cstdio>
#include <string_view>

#include "core/util/crc32.h"
#include "core/util/errors.h"
#include "core/util/format.h"
#include "server/auth.h"
#include "server/clock.h"
#include "server/log.h"
#include "server/status_map.h"
#include "server/store.h"
#include "server/uploads.h"
#include "server/worker_pool.h"
#include "wire/protocol.h"

namespace surfacer::server {
namespace {

constexpr auto kProgressInterval = std::chrono::milliseconds(100);
constexpr auto kStageChangeInterval = std::chrono::milliseconds(10);
constexpr int kGrpcCancelled = 1;
constexpr int kGrpcAborted = 10;

bool is_terminal(v1::JobState s) {
  return s == v1::JOB_STATE_SUCCEEDED || s == v1::JOB_STATE_FAILED || s == v1::JOB_STATE_CANCELLED;
}

// A frame's chunks: runs of wire::kMaxChunkBytes, the last one shorter.
int chunk_count(std::size_t bytes) {
  return static_cast<int>((bytes + wire::kMaxChunkBytes - 1) / wire::kMaxChunkBytes);
}
std::string_view chunk_of(std::string_view bytes, int chunk) {
  return bytes.substr(static_cast<std::size_t>(chunk) * wire::kMaxChunkBytes, wire::kMaxChunkBytes);
}

}  // namespace

Job::Job(JobInit init)
    : id_(std::move(init.id)),
      name_(std::move(init.name)),
      owner_(std::move(init.owner)),
      runner_(std::move(init.runner)),
      kind_(runner_ ? runner_->kind() : init.kind),
      store_(init.store),
      usage_(init.usage),
      max_stored_bytes_(init.max_stored_bytes),
      upload_ids_(std::move(init.upload_ids)),
      hooks_(init.hooks),
      tasks_total_(runner_ ? runner_->task_count() : 0),
      frames_total_(runner_ ? runner_->frame_count() : 0),
      spec_(std::move(init.spec)),
      open_(runner_ && runner_->open()) {
  if (!open_) spec_.Clear();
  created_ = now_timestamp();
  progress_.set_frames_total(frames_total_);
}

namespace {
JobInit plain_init(std::string id, std::string name, std::unique_ptr<JobRunner> runner) {
  JobInit init;
  init.id = std::move(id);
  init.name = std::move(name);
  init.runner = std::move(runner);
  return init;
}
}  // namespace

Job::Job(std::string id, std::string name, std::unique_ptr<JobRunner> runner)
    : Job(plain_init(std::move(id), std::move(name), std::move(runner))) {}

std::vector<std::string> Job::upload_ids() const {
  std::lock_guard lock(mutex_);
  return upload_ids_;
}

bool Job::open() const {
  std::lock_guard lock(mutex_);
  return open_;
}

grpc::Status Job::append_frames(const v1::AppendFramesRequest& request, std::vector<int>& tasks) {
  std::lock_guard append_lock(append_mutex_);
  {
    std::lock_guard lock(mutex_);
    if (is_terminal(state_) || cancel_requested_) {
      return {grpc::StatusCode::FAILED_PRECONDITION,
              "job " + id_ + " has finished (" + v1::JobState_Name(state_) + "): no frame can join it"};
    }
    if (!open_) {
      return {grpc::StatusCode::FAILED_PRECONDITION,
              "job " + id_ +
                  (runner_ && runner_->open() ? " has already ended its sequence (end was sent)"
                                              : " is not an open sequence (submit it with "
                                                "spec.particles.open)") +
                  ": no frame can join it"};
    }
  }
  if (!request.abort_reason().empty()) {
    if (request.frames_size() > 0 || request.end()) {
      return {grpc::StatusCode::INVALID_ARGUMENT, "abort_reason is sent alone, without frames or end"};
    }
    bool finished = false;
    {
      std::lock_guard lock(mutex_);
      if (is_terminal(state_)) return grpc::Status::OK;
      // The frames it has taken are still computed (they are the client's good ones); the job then fails with this.
      abort_message_ = utf8_prefix(
          "the client ended the sequence after " + std::to_string(tasks_total_) + " frames: " + request.abort_reason(),
          wire::kMaxErrorBytes);
      open_ = false;
      last_append_ = std::chrono::steady_clock::now();
      finished = settle_locked();
    }
    if (finished) finished_hooks();
    notify();
    return grpc::Status::OK;
  }
  try {
    runner_->check_appended(request.frames(), "frames");
    v1::ParticlesJob& stored = *spec_.mutable_particles();
    stored.mutable_frames()->MergeFrom(request.frames());
    stored.set_open(!request.end());
    if (store_) store_->update_job_spec(id_, spec_);
  } catch (...) {
    // The stored spec is unchanged when the write failed; take the frames back out of the copy too.
    v1::ParticlesJob& stored = *spec_.mutable_particles();
    while (stored.frames_size() > tasks_total_) stored.mutable_frames()->RemoveLast();
    stored.set_open(true);
    return status_from_exception(std::current_exception());
  }
  runner_->append(request.frames());
  bool finished = false;
  {
    std::lock_guard lock(mutex_);
    for (const v1::ParticleFrame& frame : request.frames()) {
      if (!frame.upload_id().empty()) upload_ids_.push_back(frame.upload_id());
      tasks.push_back(tasks_total_++);
    }
    frames_total_ = std::max(frames_total_, tasks_total_);
    progress_.set_frames_total(frames_total_);
    // The fraction of an open sequence is of the frames known so far: it may drop as frames join.
    progress_.set_fraction(static_cast<double>(tasks_done_) / std::max(1, tasks_total_));
    ++progress_version_;
    open_ = !request.end();
    last_append_ = std::chrono::steady_clock::now();
    bump_state_locked();
    finished = settle_locked();
  }
  if (finished) finished_hooks();
  notify();
  return grpc::Status::OK;
}

bool Job::expire_if_idle(std::chrono::steady_clock::time_point cutoff,
                         std::chrono::steady_clock::time_point last_upload, std::chrono::milliseconds timeout) {
  {
    std::lock_guard lock(mutex_);
    if (!open_ || is_terminal(state_) || cancel_requested_ || suspended_) return false;
    if (std::max(last_append_, last_upload) >= cutoff) return false;
    error_.set_code(static_cast<int>(grpc::StatusCode::DEADLINE_EXCEEDED));
    error_.set_message(
        utf8_prefix("the open sequence got no frame, no end and no upload for " +
                        format_number(std::chrono::duration<double>(timeout).count()) + " s" +
                        " (the server's --upload-idle-timeout) after " + std::to_string(tasks_total_) +
                        " frames: its client stopped sending (disconnected?); frames already done are kept",
                    wire::kMaxErrorBytes));
    open_ = false;
    finish_locked(v1::JOB_STATE_FAILED);
  }
  cancel_.cancel();
  finished_hooks();
  notify();
  return true;
}

std::int64_t Job::stored_bytes() const {
  std::lock_guard lock(mutex_);
  return stored_bytes_;
}

std::vector<int> Job::restore(const StoredJob& stored) {
  std::set<int> done(stored.tasks_done.begin(), stored.tasks_done.end());
  std::vector<int> todo;
  bool interrupted = false;
  {
    std::lock_guard lock(mutex_);
    const v1::Job& snap = stored.snapshot;
    created_ = snap.created();
    started_ = snap.started();
    for (const auto& header : stored.frames) {
      if (!frame_indices_.insert(header.frame_index()).second) continue;
      auto record = std::make_shared<FrameRecord>();
      record->header = header;
      stored_bytes_ += static_cast<std::int64_t>(header.total_bytes());
      frames_.push_back(std::move(record));
    }
    frames_done_ = static_cast<int>(frames_.size());
    frames_total_ = std::max({frames_total_, frames_done_, snap.frames_total()});
    progress_.set_frames_done(frames_done_);
    progress_.set_frames_total(frames_total_);
    if (is_terminal(snap.state())) {
      state_ = snap.state();
      error_ = snap.error();
      finished_ = snap.finished();
      progress_ = snap.progress();
      frames_total_ = snap.frames_total();
      const auto age = std::chrono::duration_cast<std::chrono::steady_clock::duration>(
          std::chrono::duration<double>(std::max(0.0, seconds_since(finished_))));
      finished_steady_ = std::chrono::steady_clock::now() - age;
    } else {
      for (const auto& c : stored.checkpoints) {
        if (!runner_ || done.count(c.task)) continue;
        runner_->resume_from(c.task, c.next_frame, c.state);
        log_event(LogLevel::kInfo, "job_checkpoint",
                  {{"job", id_},
                   {"task", std::to_string(c.task)},
                   {"next_frame", std::to_string(c.next_frame)},
                   {"bytes", std::to_string(c.state.size())}});
      }
      for (int t = 0; t < tasks_total_; ++t) {
        if (done.count(t)) {
          ++tasks_done_;
          ++tasks_settled_;
        } else {
          todo.push_back(t);
        }
      }
      progress_.set_fraction(static_cast<double>(tasks_done_) / std::max(1, tasks_total_));
      // Every task had finished before the restart, but not the job's own record.
      if (todo.empty()) settle_locked();
    }
    interrupted_runs_ = snap.interrupted_runs();
    if (!is_terminal(state_) && snap.state() == v1::JOB_STATE_RUNNING) {
      interrupted = true;
      if (++interrupted_runs_ >= kMaxInterruptedRuns) {
        error_.set_code(kGrpcAborted);
        error_.set_message("not resumed: the server stopped " + std::to_string(interrupted_runs_) +
                           " times while this job was running (a crash, kill or power loss; the server's log has "
                           "each start's store_opened event); if that cause is gone, submit it again");
        finish_locked(v1::JOB_STATE_FAILED);
        todo.clear();
      }
    }
    bump_state_locked();
  }
  if (usage_) usage_->add(owner_, stored_bytes());
  if (interrupted) {
    log_event(
        is_terminal(state()) ? LogLevel::kWarn : LogLevel::kInfo, "job_interrupted",
        {{"job", id_}, {"interrupted_runs", std::to_string(interrupted_runs_)}, {"state", v1::JobState_Name(state())}});
  }
  // The store holds it as QUEUED from here (and its count) until a task starts: a crash before then is not counted.
  if (interrupted || (todo.empty() && !is_terminal(stored.snapshot.state()))) persist();
  return todo;
}

void Job::fail_restore(int grpc_code, const std::string& message) {
  {
    std::lock_guard lock(mutex_);
    if (is_terminal(state_)) return;
    error_.set_code(grpc_code);
    error_.set_message(utf8_prefix("cannot resume after a server restart: " + message, wire::kMaxErrorBytes));
    finish_locked(v1::JOB_STATE_FAILED);
  }
  persist();
  notify();
}

void Job::persist() const {
  if (!store_) return;
  v1::Job job;
  {
    std::lock_guard lock(mutex_);
    snapshot_locked(job);
    // A job being cancelled is CANCELLED in the store at once: its running tasks stop at their cancel token and it
    // settles so in memory a moment later, but a restart in between (kill -9 right after CancelJob answered) must not
    // resume it.
    if (cancel_requested_ && !is_terminal(state_)) {
      job.set_state(v1::JOB_STATE_CANCELLED);
      *job.mutable_finished() = now_timestamp();
    } else if (suspended_ && !is_terminal(state_)) {
      job.set_state(v1::JOB_STATE_QUEUED);  // suspended cleanly: not an interrupted run (restore())
    }
  }
  try {
    store_->update_job(job);
    persist_pending_ = false;
  } catch (const std::exception& e) {
    if (!persist_pending_.exchange(true)) {
      log_event(LogLevel::kError, "store_write_failed",
                {{"job", id_},
                 {"state", v1::JobState_Name(job.state())},
                 {"error", e.what()},
                 {"note", "the state is kept in memory and written when the store takes it"}});
    }
  }
}

bool Job::retry_persist() const {
  if (!persist_pending_) return true;
  persist();
  if (persist_pending_) return false;
  log_event(LogLevel::kInfo, "store_write_recovered", {{"job", id_}, {"state", v1::JobState_Name(state())}});
  return true;
}

void Job::finished_hooks() {
  std::string state_text, frames, frames_total, duration, error;
  {
    std::lock_guard lock(mutex_);
    state_text = v1::JobState_Name(state_);
    frames = std::to_string(frames_done_);
    frames_total = std::to_string(frames_total_);
    // Running time: from the first task's start (a job cancelled while queued ran for 0 s) to the end.
    const bool started = started_.seconds() != 0 || started_.nanos() != 0;
    const double seconds = started ? static_cast<double>(finished_.seconds() - started_.seconds()) +
                                         1e-9 * static_cast<double>(finished_.nanos() - started_.nanos())
                                   : 0.0;
    char buf[32];
    std::snprintf(buf, sizeof buf, "%.3f", std::max(0.0, seconds));
    duration = buf;
    error = error_.message();
  }
  const LogLevel level = state_text == "JOB_STATE_FAILED" ? LogLevel::kWarn : LogLevel::kInfo;
  std::vector<LogField> fields = {{"job", id_},
                                  {"kind", kind_},
                                  {"state", state_text},
                                  {"frames", frames},
                                  {"frames_total", frames_total},
                                  {"duration_s", duration}};
  if (!error.empty()) fields.emplace_back("error", error);
  log_event(level, "job_finished", fields);
  persist();
  if (hooks_ && hooks_->on_finished) hooks_->on_finished(*this, state());
}

void Job::snapshot_locked(v1::Job& job) const {
  job.set_id(id_);
  job.set_name(name_);
  job.set_kind(kind_);
  job.set_state(state_);
  job.set_frames_total(frames_total_);
  job.set_frames_done(frames_done_);
  *job.mutable_progress() = progress_;
  if (error_.code() != 0) *job.mutable_error() = error_;
  *job.mutable_created() = created_;
  if (started_.seconds() != 0 || started_.nanos() != 0) *job.mutable_started() = started_;
  if (finished_.seconds() != 0 || finished_.nanos() != 0) *job.mutable_finished() = finished_;
  job.set_interrupted_runs(interrupted_runs_);
}

v1::Job Job::snapshot() const {
  v1::Job job;
  std::lock_guard lock(mutex_);
  snapshot_locked(job);
  return job;
}

v1::JobState Job::state() const {
  std::lock_guard lock(mutex_);
  return state_;
}

bool Job::terminal() const { return is_terminal(state()); }

std::chrono::steady_clock::time_point Job::finished_at() const {
  std::lock_guard lock(mutex_);
  return finished_steady_;
}

void Job::add_listener(std::weak_ptr<JobListener> listener) {
  std::lock_guard lock(mutex_);
  std::erase_if(listeners_, [](const auto& w) { return w.expired(); });
  listeners_.push_back(std::move(listener));
}

bool Job::next_event(WatchCursor& cursor, v1::JobEvent& event) const {
  event.Clear();
  if (cursor.done) return false;
  // 1. The rest of the frame in flight, so that a frame's chunks stay contiguous. Frame records are immutable.
  if (cursor.current) {
    const v1::FrameHeader& header = cursor.current->header;
    auto* chunk = event.mutable_chunk();
    chunk->set_frame_index(header.frame_index());
    chunk->set_chunk_index(cursor.next_chunk);
    const auto& crcs = cursor.current->chunk_crcs;
    const bool last = cursor.next_chunk + 1 >= header.num_chunks();
    if (cursor.current_bytes) {
      const std::string_view data = chunk_of(*cursor.current_bytes, cursor.next_chunk);
      chunk->set_data(data.data(), data.size());
      chunk->set_crc32(crcs.empty() ? crc32_of(data) : crcs.at(cursor.next_chunk));
    } else {
      // A stored frame: this chunk alone is read, and checked before it is sent (against its recorded CRC-32, or,
      // after a restart, the chunks so far against the frame's on the last one).
      const std::uint64_t offset = static_cast<std::uint64_t>(cursor.next_chunk) * wire::kMaxChunkBytes;
      const std::size_t length = static_cast<std::size_t>(
          std::min<std::uint64_t>(wire::kMaxChunkBytes, header.total_bytes() - std::min(offset, header.total_bytes())));
      std::string data = store_->read_frame_range(id_, header, offset, length);
      const std::uint32_t crc = crc32_of(data);
      cursor.crc_so_far = crc32_concat(cursor.crc_so_far, crc, data.size());
      if ((!crcs.empty() && crcs.at(cursor.next_chunk) != crc) || (last && cursor.crc_so_far != header.crc32())) {
        throw std::runtime_error("frame " + std::to_string(header.frame_index()) + " of job " + id_ +
                                 " is damaged on disk (CRC-32 mismatch)");
      }
      chunk->set_crc32(crc);
      chunk->set_data(std::move(data));
    }
    ++cursor.next_chunk;
    chunk->set_last(last);
    if (last) {
      cursor.current.reset();
      cursor.current_bytes.reset();
    }
    return true;
  }
  std::unique_lock lock(mutex_);
  const bool term = is_terminal(state_);
  // 2. A changed state (the terminal one waits until every frame has gone out).
  if (cursor.state_version_sent != state_version_ && !term) {
    cursor.state_version_sent = state_version_;
    snapshot_locked(*event.mutable_state());
    return true;
  }
  // 3. Once the job has ended, its last progress (the final frames_total) before the frames still to send: the
  //    state event for the last frames an open sequence took is not sent once the job is terminal, and a watcher that
  //    last saw the earlier total would otherwise get those frames beyond it.
  if (term && cursor.progress_version_sent != progress_version_ && cursor.next_frame < frames_.size()) {
    cursor.progress_version_sent = progress_version_;
    *event.mutable_progress() = progress_;
    return true;
  }
  // 4. The next finished frame.
  while (cursor.next_frame < frames_.size()) {
    auto record = frames_[cursor.next_frame++];
    if (cursor.skip_frames || record->header.frame_index() < cursor.from_frame) continue;
    *event.mutable_frame() = record->header;
    if (record->header.num_chunks() > 0) {
      cursor.next_chunk = 0;
      cursor.current_bytes = record->bytes;  // null: read chunk by chunk from the store
      cursor.crc_so_far = 0;
      cursor.current = std::move(record);
    }
    return true;
  }
  // 5. New progress.
  if (!term && cursor.progress_version_sent != progress_version_) {
    cursor.progress_version_sent = progress_version_;
    *event.mutable_progress() = progress_;
    return true;
  }
  // 6. The terminal state, last.
  if (term) {
    cursor.state_version_sent = state_version_;
    cursor.done = true;
    snapshot_locked(*event.mutable_state());
    return true;
  }
  return false;
}

void Job::bump_state_locked() { ++state_version_; }

void Job::finish_locked(v1::JobState state) {
  state_ = state;
  finished_ = now_timestamp();
  finished_steady_ = std::chrono::steady_clock::now();
  if (state == v1::JOB_STATE_SUCCEEDED) progress_.set_fraction(1.0);
  bump_state_locked();
}

void Job::notify() {
  std::vector<std::shared_ptr<JobListener>> live;
  {
    std::lock_guard lock(mutex_);
    for (const auto& w : listeners_) {
      if (auto l = w.lock()) live.push_back(std::move(l));
    }
  }
  for (const auto& l : live) l->on_job_changed();
}

bool Job::task_started() {
  {
    std::lock_guard lock(mutex_);
    if (is_terminal(state_) || cancel_requested_ || suspended_) return false;
    ++running_;
    if (state_ != v1::JOB_STATE_QUEUED) return true;
    state_ = v1::JOB_STATE_RUNNING;
    started_ = now_timestamp();
    bump_state_locked();
  }
  log_event(LogLevel::kInfo, "job_started", {{"job", id_}, {"kind", kind_}});
  persist();
  notify();
  return true;
}

void Job::emit(int frame_index, FrameOutput output) {
  {
    std::lock_guard lock(mutex_);
    // A job resumed after a restart recomputes an evolving task from its start: frames already stored stay.
    if (frame_indices_.count(frame_index)) return;
  }
  auto record = std::make_shared<FrameRecord>();
  auto bytes = std::make_shared<std::string>(std::move(output.bytes));
  auto& h = record->header;
  h.set_frame_index(frame_index);
  h.set_encoding(output.encoding);
  h.set_total_bytes(bytes->size());
  h.set_num_chunks(chunk_count(bytes->size()));
  // Each byte is read once: the chunks' CRCs, which the stream sends, combine into the frame's.
  std::uint32_t crc = 0;
  for (int c = 0; c < h.num_chunks(); ++c) {
    const std::string_view data = chunk_of(*bytes, c);
    record->chunk_crcs.push_back(crc32_of(data));
    crc = crc32_concat(crc, record->chunk_crcs.back(), data.size());
  }
  h.set_crc32(crc);
  *h.mutable_stats() = std::move(output.stats);
  const auto size = static_cast<std::int64_t>(bytes->size());
  if (usage_ && !usage_->try_add(owner_, size, max_stored_bytes_)) {
    throw ResourceLimit("quota.bytes", "frame " + std::to_string(frame_index) + " (" + std::to_string(size) +
                                           " bytes) would take tenant '" + owner_ + "' past its stored-bytes quota (" +
                                           std::to_string(max_stored_bytes_) +
                                           " bytes); wait for older jobs to expire or raise bytes= for its token in "
                                           "the server's --tokens-file");
  }
  if (store_) {
    set_progress(frame_index, "store", 0.0);
    RunControl control;
    control.cancel = &cancel_;
    try {
      store_->put_frame(id_, h, *bytes, control);
    } catch (...) {
      if (usage_) usage_->release(owner_, size);
      throw;
    }
  } else {
    record->bytes = std::move(bytes);
  }
  {
    std::lock_guard lock(mutex_);
    frame_indices_.insert(frame_index);
    stored_bytes_ += size;
    ++frames_done_;
    frames_total_ = std::max(frames_total_, frames_done_);
    frames_.push_back(std::move(record));
    progress_.set_frames_done(frames_done_);
    progress_.set_frames_total(frames_total_);
    ++progress_version_;
    bump_state_locked();
  }
  if (hooks_ && hooks_->on_frame) hooks_->on_frame(*this, h);
  notify();
}

void Job::checkpoint(int task, int next_frame, std::string state) {
  if (!store_) return;
  store_->put_checkpoint(id_, task, next_frame, state);
}

void Job::suspend() {
  {
    std::lock_guard lock(mutex_);
    if (is_terminal(state_)) return;
    suspended_ = true;
  }
  persist();
  cancel_.cancel();
  log_event(LogLevel::kInfo, "job_suspended", {{"job", id_}, {"note", "resumes when a server opens this data dir"}});
}

void Job::task_succeeded(int task) {
  if (store_) {
    try {
      store_->put_task_done(id_, task);
    } catch (const std::exception& e) {
      log_event(LogLevel::kError, "store_write_failed", {{"job", id_}, {"error", e.what()}});
    }
  }
  bool finished = false;
  {
    std::lock_guard lock(mutex_);
    --running_;
    ++tasks_done_;
    ++tasks_settled_;
    advance_fraction_locked(static_cast<double>(tasks_done_) / std::max(1, tasks_total_));
    ++progress_version_;
    finished = settle_locked();
  }
  if (finished) {
    finished_hooks();
  }
  notify();
}

void Job::task_failed(int task, int grpc_code, const std::string& message) {
  bool finished = false;
  {
    std::lock_guard lock(mutex_);
    --running_;
    if (suspended_) return;  // stopped for a restart: the next server runs this task again
    ++tasks_settled_;
    if (grpc_code == kGrpcCancelled && cancel_requested_) {
      finished = settle_locked();
    } else if (!is_terminal(state_)) {
      error_.set_code(grpc_code);
      error_.set_message(utf8_prefix(tasks_total_ > 1 ? "frame " + std::to_string(task) + ": " + message : message,
                                     wire::kMaxErrorBytes));
      finish_locked(v1::JOB_STATE_FAILED);
      finished = true;
    }
  }
  // A failed task fails the job: stop its other tasks.
  cancel_.cancel();
  if (finished) {
    finished_hooks();
  }
  notify();
}

void Job::task_skipped() {
  bool finished = false;
  {
    std::lock_guard lock(mutex_);
    if (suspended_) return;
    ++tasks_settled_;
    finished = settle_locked();
  }
  if (finished) {
    finished_hooks();
    notify();
  }
}

bool Job::settle_locked() {
  if (is_terminal(state_)) return false;
  if (cancel_requested_) {
    if (running_ > 0) return false;  // the running tasks see the token and settle soon
    finish_locked(v1::JOB_STATE_CANCELLED);
    return true;
  }
  if (open_ || tasks_settled_ < tasks_total_) return false;       // an open sequence waits for frames or its end
  if (tasks_done_ == tasks_total_) frames_total_ = frames_done_;  // open-ended jobs end with what they emitted
  progress_.set_frames_total(frames_total_);
  if (abort_message_) {  // an open sequence its client ended with abort_reason
    error_.set_code(kGrpcAborted);
    error_.set_message(*abort_message_);
    finish_locked(v1::JOB_STATE_FAILED);
    return true;
  }
  finish_locked(tasks_done_ == tasks_total_ ? v1::JOB_STATE_SUCCEEDED : v1::JOB_STATE_FAILED);
  return true;
}

void Job::advance_fraction_locked(double fraction) {
  // Tasks run in parallel and each reports its own stage's fraction: the job's is the furthest reached, so a watcher
  // never sees it go back (a task starting at 0 after another reported 0.6 of its frame).
  progress_.set_fraction(std::max(progress_.fraction(), std::min(1.0, fraction)));
}

void Job::set_progress(int frame_index, std::string_view stage, double fraction) {
  const auto now = std::chrono::steady_clock::now();
  {
    std::lock_guard lock(mutex_);
    // At most every kProgressInterval; a new stage sooner, so that watchers see a short stage begin.
    const auto interval = progress_.stage() == stage ? kProgressInterval : kStageChangeInterval;
    if (now - last_progress_notify_ < interval) return;
    last_progress_notify_ = now;
    progress_.set_stage(std::string(stage));
    progress_.set_frame_index(frame_index);
    const double per_task = 1.0 / std::max(1, tasks_total_);
    advance_fraction_locked(tasks_done_ * per_task + std::clamp(fraction, 0.0, 1.0) * per_task);
    ++progress_version_;
  }
  notify();
}

bool Job::cancel(const std::string& reason) {
  bool finished = false;
  {
    std::lock_guard lock(mutex_);
    if (is_terminal(state_) || cancel_requested_) return false;
    cancel_requested_ = true;
    cancel_reason_ = reason;
    error_.set_code(kGrpcCancelled);
    error_.set_message(reason);
    finished = settle_locked();
  }
  cancel_.cancel();
  log_event(LogLevel::kInfo, "job_cancel", {{"job", id_}, {"reason", reason}});
  if (finished) {
    finished_hooks();  // persists the terminal state
  } else {
    persist();  // CANCELLED in the store before CancelJob answers (persist())
  }
  notify();
  return finished;
}

}  // namespace surfacer::server
