// Jobs: state, finished frames and the watchers that stream them; the store that names them; and the scheduler
// that runs their tasks on the worker pool, round-robin across jobs.
#pragma once

#include <chrono>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include <set>

#include "core/util/run_control.h"
#include "surfacer/v1/surfacer.pb.h"

namespace surfacer::server {

class WorkerPool;
class Store;
class Usage;
struct StoredJob;
class Job;

// Observers of job life (metrics). Called outside the job's lock; must be cheap and thread-safe.
struct JobHooks {
  std::function<void(const Job&, const v1::FrameHeader&)> on_frame;
  std::function<void(const Job&, v1::JobState)> on_finished;
};

// What a job type computes for one frame.
struct FrameOutput {
  std::string bytes;
  v1::MeshEncoding encoding = v1::MESH_ENCODING_DRACO;
  v1::FrameStats stats;
};

// Receives the frames a task produces. Thread-safe.
class FrameSink {
 public:
  virtual ~FrameSink() = default;
  virtual void emit(int frame_index, FrameOutput output) = 0;
  // An evolving task's resumable state after it emitted every frame before `next_frame`: with a durable store it
  // is kept (replacing the task's previous one), and after a restart the runner gets it back through
  // JobRunner::resume_from() instead of starting over. Without a store it is dropped. Throws like emit().
  virtual void checkpoint(int /*task*/, int /*next_frame*/, std::string /*state*/) {}
};

// A validated, ready-to-run job of one type, cut into independent tasks. Tasks run on worker threads, in parallel
// for distinct indices; each emits its frames through the sink (a sequence of scenes or particle frames: task i
// emits frame i; an evolving job — optimization snapshots, active-surface frames — is one task emitting many).
// run_task throws surfacer::Error (or std::bad_alloc) on failure.
class JobRunner {
 public:
  virtual ~JobRunner() = default;
  virtual std::string kind() const = 0;
  virtual int task_count() const = 0;
  // Frames expected; for open-ended jobs an upper bound (the final count is what was emitted).
  virtual int frame_count() const = 0;
  virtual void run_task(int index, FrameSink& sink, const RunControl& control) = 0;
  // Called before run_task after a server restart with the task's last checkpoint (see FrameSink::checkpoint).
  // A runner that cannot use it ignores it and starts the task over (frames already stored are not sent again).
  virtual void resume_from(int /*task*/, int /*next_frame*/, std::string /*state*/) {}
};

// Something to wake when a job changes (a WatchJob stream). Called from worker or gRPC threads; must not block.
class JobListener {
 public:
  virtual ~JobListener() = default;
  virtual void on_job_changed() = 0;
};

struct FrameRecord {
  v1::FrameHeader header;
  // The frame's bytes when held in memory; null when they live in the durable store (read when streamed).
  std::shared_ptr<const std::string> bytes;
};

// Maximum payload of one FrameChunk event.
inline constexpr std::size_t kChunkBytes = std::size_t{1} << 20;

// Where a WatchJob stream is in a job's event sequence.
struct WatchCursor {
  int from_frame = 0;
  bool skip_frames = false;
  std::uint64_t state_version_sent = 0;  // 0: nothing sent yet
  std::uint64_t progress_version_sent = 0;
  std::size_t next_frame = 0;  // index into the completion-ordered frame list
  std::shared_ptr<const FrameRecord> current;
  std::shared_ptr<const std::string> current_bytes;
  int next_chunk = 0;
  bool done = false;  // the terminal state has been produced
};

struct JobInit {
  std::string id;
  std::string name;
  std::string owner;  // tenant ("" without authentication)
  std::unique_ptr<JobRunner> runner;  // null only for a finished job restored from the store
  std::string kind;                   // used when runner is null
  Store* store = nullptr;             // durable store, or null (memory only)
  Usage* usage = nullptr;             // stored-bytes accounting per tenant, or null
  std::int64_t max_stored_bytes = 0;  // the owner's quota (0 = unlimited)
  std::vector<std::string> upload_ids;
  const JobHooks* hooks = nullptr;
};

class Job : public FrameSink {
 public:
  explicit Job(JobInit init);
  Job(std::string id, std::string name, std::unique_ptr<JobRunner> runner);

  const std::string& id() const { return id_; }
  const std::string& owner() const { return owner_; }
  const std::string& kind() const { return kind_; }
  const std::vector<std::string>& upload_ids() const { return upload_ids_; }
  // Bytes of this job's frames (in memory or in the store).
  std::int64_t stored_bytes() const;
  JobRunner& runner() { return *runner_; }
  const CancelToken& cancel_token() const { return cancel_; }

  v1::Job snapshot() const;
  v1::JobState state() const;
  bool terminal() const;
  std::chrono::steady_clock::time_point finished_at() const;

  void add_listener(std::weak_ptr<JobListener> listener);

  // The next event for a watcher at `cursor`: chunks of the frame in flight, then a changed state, then the next
  // finished frame (index >= from_frame), then new progress; the terminal state comes last, after every frame.
  // Returns false when there is nothing to send yet.
  bool next_event(WatchCursor& cursor, v1::JobEvent& event) const;

  // Takes the persisted state of a job found in the store at start-up: its frames, finished tasks and, for a
  // finished job, its final state. Returns the tasks still to run (none for a finished job).
  std::vector<int> restore(const StoredJob& stored);
  // Fails a job that cannot be resumed (its runner could not be rebuilt after a restart).
  void fail_restore(int grpc_code, const std::string& message);
  // Writes the current snapshot to the store (no-op without one); failures are logged.
  void persist() const;

  // --- Transitions, called by the scheduler ----------------------------------------------------------------
  // A task starts; returns false when the job is already finished (cancelled or failed).
  bool task_started();
  void task_succeeded(int task);
  void task_failed(int task, int grpc_code, const std::string& message);
  void task_skipped();
  // FrameSink: a finished frame (stored, then streamed to watchers).
  void emit(int frame_index, FrameOutput output) override;
  void checkpoint(int task, int next_frame, std::string state) override;
  // fraction: of the current task.
  void set_progress(int frame_index, std::string_view stage, double fraction);
  // Requests cancellation; returns true when this call finished the job (nothing was running).
  bool cancel(const std::string& reason);
  // The server is stopping with a durable store: running tasks stop (as on cancel) but the job keeps its state, so
  // the next server on the same data directory resumes it. No transition is recorded after this.
  void suspend();

 private:
  void snapshot_locked(v1::Job& job) const;
  void bump_state_locked();
  void finish_locked(v1::JobState state);
  // Finishes the job when nothing more can happen: cancelled with no task running, or every task settled.
  // Returns true when it did.
  bool settle_locked();
  void notify();
  void finished_hooks();

  const std::string id_;
  const std::string name_;
  const std::string owner_;
  std::unique_ptr<JobRunner> runner_;
  const std::string kind_;
  Store* const store_;
  Usage* const usage_;
  const std::int64_t max_stored_bytes_;
  const std::vector<std::string> upload_ids_;
  const JobHooks* const hooks_;
  const int tasks_total_;
  int frames_total_;
  CancelToken cancel_;

  mutable std::mutex mutex_;
  v1::JobState state_ = v1::JOB_STATE_QUEUED;
  std::uint64_t state_version_ = 1;
  std::uint64_t progress_version_ = 0;
  v1::Progress progress_;
  std::chrono::steady_clock::time_point last_progress_notify_{};
  v1::JobError error_;
  int running_ = 0;
  int frames_done_ = 0;
  int tasks_done_ = 0;
  int tasks_settled_ = 0;  // succeeded, failed or skipped
  bool cancel_requested_ = false;
  bool suspended_ = false;
  std::string cancel_reason_;
  std::vector<std::shared_ptr<const FrameRecord>> frames_;  // in completion order
  std::set<int> frame_indices_;
  std::int64_t stored_bytes_ = 0;
  google::protobuf::Timestamp created_, started_, finished_;
  std::chrono::steady_clock::time_point finished_steady_{};
  std::vector<std::weak_ptr<JobListener>> listeners_;
};

// Owns the jobs and runs their tasks on the pool, round-robin across running jobs.
class Scheduler {
 public:
  Scheduler(WorkerPool& pool, int max_queued_jobs);

  // Throws surfacer::Error(kResourceLimit) when max_queued_jobs jobs are already waiting.
  void submit(std::shared_ptr<Job> job);
  // A job restored from the store: runs `tasks` (finished jobs: none; they are only kept for watching).
  void resume(std::shared_ptr<Job> job, std::vector<int> tasks);
  std::shared_ptr<Job> find(const std::string& id) const;
  std::vector<std::shared_ptr<Job>> list() const;
  int queued_jobs() const;
  // Jobs not yet finished.
  int active_jobs() const;
  void cancel_all(const std::string& reason);
  // Suspends every unfinished job (see Job::suspend).
  void suspend_all();
  // Jobs of `owner` not yet finished.
  int active_jobs(const std::string& owner) const;
  // Forgets finished jobs older than `age`; returns them.
  std::vector<std::shared_ptr<Job>> forget_finished(std::chrono::seconds age);
  // Forgets one finished job.
  void forget(const std::string& id);

 private:
  void run_next_task();

  WorkerPool& pool_;
  const int max_queued_jobs_;
  mutable std::mutex mutex_;
  std::map<std::string, std::shared_ptr<Job>> jobs_;
  std::vector<std::string> order_;  // submission order, for list()
  struct Pending {
    std::shared_ptr<Job> job;
    std::vector<int> tasks;
    std::size_t next = 0;
  };
  std::deque<Pending> pending_;  // jobs with tasks not yet started, round-robin
};

}  // namespace surfacer::server
