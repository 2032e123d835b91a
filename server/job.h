// A job: its state, its finished frames and the watchers that stream them. The scheduler (server/scheduler.h) runs
// its tasks; a job runner (server/runners/runner.h) computes them.
#pragma once

#include <grpcpp/support/status.h>

#include <atomic>
#include <chrono>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include "core/util/run_control.h"
#include "server/runners/runner.h"
#include "surfacer/v1/surfacer.pb.h"

namespace surfacer::server {

class Store;
class Usage;
struct StoredJob;
class Job;

// Observers of job life (metrics). Called outside the job's lock; must be cheap and thread-safe.
struct JobHooks {
  std::function<void(const Job&, const v1::FrameHeader&)> on_frame;
  std::function<void(const Job&, v1::JobState)> on_finished;
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
  // The CRC-32 of each chunk (wire::kMaxChunkBytes) as the frame was made; empty for a frame read back from a store
  // after a restart, whose chunks' CRCs are computed as they are sent.
  std::vector<std::uint32_t> chunk_crcs;
};

// Where a WatchJob stream is in a job's event sequence.
struct WatchCursor {
  int from_frame = 0;
  bool skip_frames = false;
  std::uint64_t state_version_sent = 0;  // 0: nothing sent yet
  std::uint64_t progress_version_sent = 0;
  std::size_t next_frame = 0;  // index into the completion-ordered frame list
  std::shared_ptr<const FrameRecord> current;
  // The frame's bytes when held in memory (shared by every stream); null when they are read from the store one
  // chunk at a time, so a stream never holds more than a chunk of them.
  std::shared_ptr<const std::string> current_bytes;
  std::uint32_t crc_so_far = 0;  // CRC-32 of the chunks sent of a stored frame without recorded chunk CRCs
  int next_chunk = 0;
  bool done = false;  // the terminal state has been produced
};

struct JobInit {
  std::string id;
  std::string name;
  std::string owner;                  // tenant ("" without authentication)
  std::unique_ptr<JobRunner> runner;  // null only for a finished job restored from the store
  std::string kind;                   // used when runner is null
  Store* store = nullptr;             // durable store, or null (memory only)
  Usage* usage = nullptr;             // stored-bytes accounting per tenant, or null
  std::int64_t max_stored_bytes = 0;  // the owner's quota (0 = unlimited)
  std::vector<std::string> upload_ids;
  const JobHooks* hooks = nullptr;
  // The spec as stored; kept (and rewritten in the store as frames join) only while the job is an open sequence.
  v1::JobSpec spec;
};

class Job : public FrameSink {
 public:
  // A job that was running when its server stopped uncleanly this many times is FAILED at the next start instead of
  // resumed (v1::Job.interrupted_runs).
  static constexpr int kMaxInterruptedRuns = 3;

  explicit Job(JobInit init);
  Job(std::string id, std::string name, std::unique_ptr<JobRunner> runner);

  const std::string& id() const { return id_; }
  const std::string& owner() const { return owner_; }
  const std::string& kind() const { return kind_; }
  // The uploads the job uses (an open sequence's grow as frames join).
  std::vector<std::string> upload_ids() const;
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
  // finished frame (index >= from_frame), then new progress; the terminal state comes last, after every frame. No
  // frame goes out before an event with a frames_total above its index.
  // Returns false when there is nothing to send yet.
  bool next_event(WatchCursor& cursor, v1::JobEvent& event) const;

  // Takes the persisted state of a job found in the store at start-up: its frames, finished tasks and, for a
  // finished job, its final state. A job the store holds as RUNNING was interrupted (its server did not suspend it):
  // that is counted, durably before anything runs, and the kMaxInterruptedRuns-th time fails it. Returns the tasks
  // still to run (none for a finished job).
  std::vector<int> restore(const StoredJob& stored);
  // Fails a job that cannot be resumed (its runner could not be rebuilt after a restart).
  void fail_restore(int grpc_code, const std::string& message);
  // Writes the current snapshot to the store (no-op without one). A write the store refuses (a full disk) is logged
  // and stays pending: the snapshot, terminal state included, lives in memory until retry_persist() gets it written
  // (the server retries every second and once more before it stops), so a restart does not bring back an older one.
  void persist() const;
  bool persist_pending() const { return persist_pending_.load(); }
  // Writes the snapshot again if the last write failed; true once the store holds it.
  bool retry_persist() const;

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
  // --- Open sequences (ParticlesJob.open; docs/ALGORITHMS.md §5, "Open sequences") ---------------------------
  // Adds the request's frames as new tasks (their indices go to `tasks`, for the scheduler), ends the sequence on
  // `end`, or on `abort_reason` ends it so that the job fails once the frames it took are done. The spec with the new
  // frames is in the store before this returns. FAILED_PRECONDITION when the job is not an open sequence or has
  // finished; the runner's refusal of a frame (INVALID_ARGUMENT naming frames[i], RESOURCE_EXHAUSTED past
  // --max-frames); the store's (data_dir).
  grpc::Status append_frames(const v1::AppendFramesRequest& request, std::vector<int>& tasks);
  // Fails an open sequence that took no frame, no end and no upload of its owner since `cutoff` (last_upload: the
  // owner's latest upload chunk); `timeout` is what the message names. Returns whether it did.
  bool expire_if_idle(std::chrono::steady_clock::time_point cutoff, std::chrono::steady_clock::time_point last_upload,
                      std::chrono::milliseconds timeout);
  bool open() const;
  // Requests cancellation; returns true when this call finished the job (nothing was running).
  bool cancel(const std::string& reason);
  // The server is stopping with a durable store: running tasks stop (as on cancel) and the store holds the job as
  // QUEUED (not interrupted), so the next server on the same data directory resumes it. No transition is recorded
  // after this.
  void suspend();

 private:
  void snapshot_locked(v1::Job& job) const;
  void bump_state_locked();
  // Sets the progress fraction to `fraction` (clamped to 1) unless it is behind the one already reported.
  void advance_fraction_locked(double fraction);
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
  std::vector<std::string> upload_ids_;  // guarded by mutex_
  const JobHooks* const hooks_;
  int tasks_total_;  // grows in an open sequence (guarded by mutex_)
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
  int interrupted_runs_ = 0;
  std::string cancel_reason_;
  std::vector<std::shared_ptr<const FrameRecord>> frames_;  // in completion order
  std::set<int> frame_indices_;
  std::int64_t stored_bytes_ = 0;
  google::protobuf::Timestamp created_, started_, finished_;
  std::chrono::steady_clock::time_point finished_steady_{};
  std::vector<std::weak_ptr<JobListener>> listeners_;
  // Open sequences: the stored spec, whether frames may still join, and when one (or the request to end) last came.
  std::mutex append_mutex_;  // one append at a time, held across the store write
  v1::JobSpec spec_;
  bool open_ = false;
  std::optional<std::string> abort_message_;  // AppendFrames' abort_reason: the job fails once its frames settle
  std::chrono::steady_clock::time_point last_append_ = std::chrono::steady_clock::now();
  mutable std::atomic<bool> persist_pending_{false};
};

}  // namespace surfacer::server
