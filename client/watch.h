// Following a job with WatchJob: frames are reassembled, verified and written as they arrive (in any order);
// a stream that breaks with UNAVAILABLE before the job ends is reopened from the smallest frame not yet received
// (duplicates skipped), with backoff, for up to ~10 s without a successful read.
#pragma once

#include <chrono>
#include <cstdint>
#include <functional>
#include <mutex>
#include <set>
#include <string>

#include "client/connection.h"
#include "client/frame_writer.h"
#include "client/progress.h"
#include "surfacer/v1/surfacer.pb.h"

namespace grpc {
class ClientContext;
}

namespace surfacer::client {

struct WatchResult {
  v1::Job job;  // the terminal state
  int frames_written = 0;
  std::int64_t triangles = 0;
};

struct ReconnectPolicy {
  std::chrono::milliseconds budget{10'000};    // give up after this long without a successful read
  std::chrono::milliseconds first_delay{250};  // doubled per attempt ...
  std::chrono::milliseconds max_delay{2'000};  // ... up to this
};

// Where a watcher puts each verified frame (FrameWriter::write by default).
using FrameHandler = std::function<void(const ReceivedFrame& frame)>;
// Called with every Progress event of the stream, quiet or not (Python's progress= callable).
using ProgressHandler = std::function<void(const v1::Progress& progress)>;

class JobWatcher {
 public:
  JobWatcher(Connection& connection, std::string job_id, int from_frame, FrameWriter& writer, ProgressDisplay& progress,
             ReconnectPolicy policy = {});
  // Frames go to `on_frame` (in any order, each once; it may throw CliError to end the watch). With `quiet`, the
  // job's state, progress and frame lines are not shown (the reconnect lines still are): scale-out sub-jobs.
  JobWatcher(Connection& connection, std::string job_id, int from_frame, FrameHandler on_frame,
             ProgressDisplay& progress, ReconnectPolicy policy, bool quiet);

  // Returns once the job reached a terminal state and the stream ended. Throws CliError: kIntegrity (a frame
  // failed its checks, a protocol violation, or the job SUCCEEDED with frames missing: fewer than the terminal
  // state's frames_total, which for open-ended jobs may be below the bound announced while running), kUnreachable
  // (reconnecting failed), kCancelled (stop() was called), or rpc_error() for other stream errors (e.g. NOT_FOUND).
  WatchResult run();
  // Before run(): `handler` sees every Progress event, in the order the server sent them.
  void set_progress_handler(ProgressHandler handler) { on_progress_ = std::move(handler); }
  // Thread-safe: ends the stream now; run() throws CliError(kCancelled).
  void stop();

 private:
  void handle_frame(const ReceivedFrame& frame, int requested_from, int frames_total, WatchResult& result);
  int next_missing() const;

  Connection& connection_;
  std::string job_id_;
  int from_frame_;
  FrameWriter* writer_ = nullptr;  // null with a FrameHandler
  FrameHandler on_frame_;
  ProgressHandler on_progress_;
  ProgressDisplay& progress_;
  bool quiet_ = false;
  ReconnectPolicy policy_;
  std::set<int> received_;

  std::mutex mutex_;
  grpc::ClientContext* context_ = nullptr;
  bool stopped_ = false;
};

bool is_terminal(v1::JobState state);

}  // namespace surfacer::client
