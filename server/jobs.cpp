#include "server/jobs.h"

#include <google/protobuf/util/time_util.h>
#include <grpcpp/support/status.h>

#include <algorithm>

#include "core/errors.h"
#include "server/log.h"
#include "server/status_map.h"
#include "server/uploads.h"
#include "server/worker_pool.h"

namespace surfacer::server {
namespace {

using google::protobuf::util::TimeUtil;

constexpr auto kProgressInterval = std::chrono::milliseconds(100);
constexpr int kGrpcCancelled = 1;

bool is_terminal(v1::JobState s) {
  return s == v1::JOB_STATE_SUCCEEDED || s == v1::JOB_STATE_FAILED || s == v1::JOB_STATE_CANCELLED;
}

}  // namespace

Job::Job(std::string id, std::string name, std::unique_ptr<JobRunner> runner)
    : id_(std::move(id)),
      name_(std::move(name)),
      runner_(std::move(runner)),
      tasks_total_(runner_->task_count()),
      frames_total_(runner_->frame_count()) {
  created_ = TimeUtil::GetCurrentTime();
  progress_.set_frames_total(frames_total_);
}

void Job::snapshot_locked(v1::Job& job) const {
  job.set_id(id_);
  job.set_name(name_);
  job.set_kind(runner_->kind());
  job.set_state(state_);
  job.set_frames_total(frames_total_);
  job.set_frames_done(frames_done_);
  *job.mutable_progress() = progress_;
  if (error_.code() != 0) *job.mutable_error() = error_;
  *job.mutable_created() = created_;
  if (started_.seconds() != 0 || started_.nanos() != 0) *job.mutable_started() = started_;
  if (finished_.seconds() != 0 || finished_.nanos() != 0) *job.mutable_finished() = finished_;
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
    const std::string& bytes = cursor.current->bytes;
    const std::size_t offset = static_cast<std::size_t>(cursor.next_chunk) * kChunkBytes;
    const std::size_t size = std::min(kChunkBytes, bytes.size() - offset);
    auto* chunk = event.mutable_chunk();
    chunk->set_frame_index(cursor.current->header.frame_index());
    chunk->set_chunk_index(cursor.next_chunk);
    chunk->set_data(bytes.data() + offset, size);
    chunk->set_crc32(crc32_of(bytes.data() + offset, size));
    ++cursor.next_chunk;
    const bool last = cursor.next_chunk >= cursor.current->header.num_chunks();
    chunk->set_last(last);
    if (last) cursor.current.reset();
    return true;
  }
  std::lock_guard lock(mutex_);
  const bool term = is_terminal(state_);
  // 2. A changed state (the terminal one waits until every frame has gone out).
  if (cursor.state_version_sent != state_version_ && !term) {
    cursor.state_version_sent = state_version_;
    snapshot_locked(*event.mutable_state());
    return true;
  }
  // 3. The next finished frame.
  while (cursor.next_frame < frames_.size()) {
    auto record = frames_[cursor.next_frame++];
    if (cursor.skip_frames || record->header.frame_index() < cursor.from_frame) continue;
    *event.mutable_frame() = record->header;
    if (record->header.num_chunks() > 0) {
      cursor.current = std::move(record);
      cursor.next_chunk = 0;
    }
    return true;
  }
  // 4. New progress.
  if (!term && cursor.progress_version_sent != progress_version_) {
    cursor.progress_version_sent = progress_version_;
    *event.mutable_progress() = progress_;
    return true;
  }
  // 5. The terminal state, last.
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
  finished_ = TimeUtil::GetCurrentTime();
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
    if (is_terminal(state_) || cancel_requested_) return false;
    ++running_;
    if (state_ != v1::JOB_STATE_QUEUED) return true;
    state_ = v1::JOB_STATE_RUNNING;
    started_ = TimeUtil::GetCurrentTime();
    bump_state_locked();
  }
  log_event(LogLevel::kInfo, "job_started", {{"job", id_}, {"kind", runner_->kind()}});
  notify();
  return true;
}

void Job::emit(int frame_index, FrameOutput output) {
  auto record = std::make_shared<FrameRecord>();
  record->bytes = std::move(output.bytes);
  auto& h = record->header;
  h.set_frame_index(frame_index);
  h.set_encoding(output.encoding);
  h.set_total_bytes(record->bytes.size());
  h.set_num_chunks(static_cast<int>((record->bytes.size() + kChunkBytes - 1) / kChunkBytes));
  h.set_crc32(crc32_of(record->bytes.data(), record->bytes.size()));
  *h.mutable_stats() = std::move(output.stats);
  {
    std::lock_guard lock(mutex_);
    ++frames_done_;
    frames_total_ = std::max(frames_total_, frames_done_);
    frames_.push_back(std::move(record));
    progress_.set_frames_done(frames_done_);
    progress_.set_frames_total(frames_total_);
    ++progress_version_;
    bump_state_locked();
  }
  notify();
}

void Job::task_succeeded() {
  bool finished = false;
  {
    std::lock_guard lock(mutex_);
    --running_;
    ++tasks_done_;
    ++tasks_settled_;
    progress_.set_fraction(static_cast<double>(tasks_done_) / std::max(1, tasks_total_));
    ++progress_version_;
    finished = settle_locked();
  }
  if (finished) log_event(LogLevel::kInfo, "job_finished", {{"job", id_}, {"state", v1::JobState_Name(state())}});
  notify();
}

void Job::task_failed(int task, int grpc_code, const std::string& message) {
  bool finished = false;
  {
    std::lock_guard lock(mutex_);
    --running_;
    ++tasks_settled_;
    if (grpc_code == kGrpcCancelled && cancel_requested_) {
      finished = settle_locked();
    } else if (!is_terminal(state_)) {
      error_.set_code(grpc_code);
      error_.set_message(tasks_total_ > 1 ? "frame " + std::to_string(task) + ": " + message : message);
      finish_locked(v1::JOB_STATE_FAILED);
      finished = true;
    }
  }
  // A failed task fails the job: stop its other tasks.
  cancel_.cancel();
  if (finished) {
    log_event(LogLevel::kWarn, "job_finished",
              {{"job", id_}, {"state", v1::JobState_Name(state())}, {"task", std::to_string(task)},
               {"error", message}});
  }
  notify();
}

void Job::task_skipped() {
  bool finished = false;
  {
    std::lock_guard lock(mutex_);
    ++tasks_settled_;
    finished = settle_locked();
  }
  if (finished) notify();
}

bool Job::settle_locked() {
  if (is_terminal(state_)) return false;
  if (cancel_requested_) {
    if (running_ > 0) return false;  // the running tasks see the token and settle soon
    finish_locked(v1::JOB_STATE_CANCELLED);
    return true;
  }
  if (tasks_settled_ < tasks_total_) return false;
  if (tasks_done_ == tasks_total_) frames_total_ = frames_done_;  // open-ended jobs end with what they emitted
  progress_.set_frames_total(frames_total_);
  finish_locked(tasks_done_ == tasks_total_ ? v1::JOB_STATE_SUCCEEDED : v1::JOB_STATE_FAILED);
  return true;
}

void Job::set_progress(int frame_index, std::string_view stage, double fraction) {
  const auto now = std::chrono::steady_clock::now();
  {
    std::lock_guard lock(mutex_);
    if (now - last_progress_notify_ < kProgressInterval) return;
    last_progress_notify_ = now;
    progress_.set_stage(std::string(stage));
    progress_.set_frame_index(frame_index);
    const double per_task = 1.0 / std::max(1, tasks_total_);
    progress_.set_fraction(std::min(1.0, tasks_done_ * per_task + std::clamp(fraction, 0.0, 1.0) * per_task));
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
  notify();
  return finished;
}

// ---------------------------------------------------------------------------------------------------------------

Scheduler::Scheduler(WorkerPool& pool, int max_queued_jobs) : pool_(pool), max_queued_jobs_(max_queued_jobs) {}

void Scheduler::submit(std::shared_ptr<Job> job) {
  const int tasks = job->runner().task_count();
  {
    std::lock_guard lock(mutex_);
    int queued = 0;
    for (const auto& p : pending_) {
      if (p.job->state() == v1::JOB_STATE_QUEUED) ++queued;
    }
    if (queued >= max_queued_jobs_) {
      throw ResourceLimit("max_queued_jobs", "the job queue is full (" + std::to_string(queued) +
                                                 " jobs waiting); retry later, or start the server with a larger "
                                                 "--max-queued-jobs");
    }
    jobs_.emplace(job->id(), job);
    order_.push_back(job->id());
    pending_.push_back({job, 0});
  }
  log_event(LogLevel::kInfo, "job_submitted",
            {{"job", job->id()},
             {"kind", job->runner().kind()},
             {"tasks", std::to_string(tasks)},
             {"frames", std::to_string(job->runner().frame_count())}});
  for (int i = 0; i < tasks; ++i) pool_.post([this] { run_next_task(); });
}

void Scheduler::run_next_task() {
  std::shared_ptr<Job> job;
  int task = -1;
  {
    std::lock_guard lock(mutex_);
    // Round-robin: take one task of the job at the front, then move the job to the back.
    while (!pending_.empty()) {
      Pending p = std::move(pending_.front());
      pending_.pop_front();
      const int tasks = p.job->runner().task_count();
      if (p.job->terminal() || p.next_task >= tasks) continue;
      job = p.job;
      task = p.next_task++;
      if (p.next_task < tasks) pending_.push_back(std::move(p));
      break;
    }
  }
  if (!job) return;
  if (!job->task_started()) {
    job->task_skipped();
    return;
  }
  RunControl control;
  control.cancel = &job->cancel_token();
  control.progress = [job = job.get(), task](std::string_view stage, double fraction) {
    job->set_progress(task, stage, fraction);
  };
  try {
    job->runner().run_task(task, *job, control);
    job->task_succeeded();
  } catch (...) {
    const grpc::Status status = status_from_exception(std::current_exception());
    job->task_failed(task, status.error_code(), status.error_message());
  }
}

std::shared_ptr<Job> Scheduler::find(const std::string& id) const {
  std::lock_guard lock(mutex_);
  auto it = jobs_.find(id);
  return it == jobs_.end() ? nullptr : it->second;
}

std::vector<std::shared_ptr<Job>> Scheduler::list() const {
  std::lock_guard lock(mutex_);
  std::vector<std::shared_ptr<Job>> out;
  out.reserve(order_.size());
  for (const auto& id : order_) {
    auto it = jobs_.find(id);
    if (it != jobs_.end()) out.push_back(it->second);
  }
  return out;
}

int Scheduler::queued_jobs() const {
  int n = 0;
  for (const auto& job : list()) {
    if (job->state() == v1::JOB_STATE_QUEUED) ++n;
  }
  return n;
}

int Scheduler::active_jobs() const {
  int n = 0;
  for (const auto& job : list()) {
    if (!job->terminal()) ++n;
  }
  return n;
}

void Scheduler::cancel_all(const std::string& reason) {
  for (const auto& job : list()) job->cancel(reason);
}

void Scheduler::forget_finished(std::chrono::seconds age) {
  const auto cutoff = std::chrono::steady_clock::now() - age;
  std::lock_guard lock(mutex_);
  std::erase_if(order_, [&](const std::string& id) {
    auto it = jobs_.find(id);
    if (it == jobs_.end()) return true;
    if (it->second->terminal() && it->second->finished_at() < cutoff) {
      jobs_.erase(it);
      return true;
    }
    return false;
  });
}

}  // namespace surfacer::server
