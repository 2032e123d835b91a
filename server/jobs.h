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

#include "core/run_control.h"
#include "surfacer/v1/surfacer.pb.h"

namespace surfacer::server {

class WorkerPool;

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
};

// Something to wake when a job changes (a WatchJob stream). Called from worker or gRPC threads; must not block.
class JobListener {
 public:
  virtual ~JobListener() = default;
  virtual void on_job_changed() = 0;
};

struct FrameRecord {
  v1::FrameHeader header;
  std::string bytes;
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
  int next_chunk = 0;
  bool done = false;  // the terminal state has been produced
};

class Job : public FrameSink {
 public:
  Job(std::string id, std::string name, std::unique_ptr<JobRunner> runner);

  const std::string& id() const { return id_; }
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

  // --- Transitions, called by the scheduler ----------------------------------------------------------------
  // A task starts; returns false when the job is already finished (cancelled or failed).
  bool task_started();
  void task_succeeded();
  void task_failed(int task, int grpc_code, const std::string& message);
  void task_skipped();
  // FrameSink: a finished frame (stored, then streamed to watchers).
  void emit(int frame_index, FrameOutput output) override;
  // fraction: of the current task.
  void set_progress(int frame_index, std::string_view stage, double fraction);
  // Requests cancellation; returns true when this call finished the job (nothing was running).
  bool cancel(const std::string& reason);

 private:
  void snapshot_locked(v1::Job& job) const;
  void bump_state_locked();
  void finish_locked(v1::JobState state);
  // Finishes the job when nothing more can happen: cancelled with no task running, or every task settled.
  // Returns true when it did.
  bool settle_locked();
  void notify();

  const std::string id_;
  const std::string name_;
  std::unique_ptr<JobRunner> runner_;
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
  std::string cancel_reason_;
  std::vector<std::shared_ptr<const FrameRecord>> frames_;  // in completion order
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
  std::shared_ptr<Job> find(const std::string& id) const;
  std::vector<std::shared_ptr<Job>> list() const;
  int queued_jobs() const;
  // Jobs not yet finished.
  int active_jobs() const;
  void cancel_all(const std::string& reason);
  // Forgets finished jobs older than `age`.
  void forget_finished(std::chrono::seconds age);

 private:
  void run_next_task();

  WorkerPool& pool_;
  const int max_queued_jobs_;
  mutable std::mutex mutex_;
  std::map<std::string, std::shared_ptr<Job>> jobs_;
  std::vector<std::string> order_;  // submission order, for list()
  struct Pending {
    std::shared_ptr<Job> job;
    int next_task = 0;
  };
  std::deque<Pending> pending_;  // jobs with tasks not yet started, round-robin
};

}  // namespace surfacer::server
