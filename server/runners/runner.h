// Job runners: what computes a job's frames. Each job type turns its part of a v1::JobSpec into a JobRunner,
// validating everything at submit time so that bad input answers INVALID_ARGUMENT / RESOURCE_EXHAUSTED before any
// work is queued. The request's fields become engine options in wire/job_options.h; the runner adds what depends on
// the server (its limits, its workers) and cuts the job into tasks.
#pragma once

#include <memory>
#include <string>

#include "core/util/parallel.h"
#include "core/util/run_control.h"
#include "server/options.h"
#include "surfacer/v1/surfacer.pb.h"

namespace surfacer::wire {
class UploadLookup;
}

namespace surfacer {
struct PolygonizeGrid;
}

namespace surfacer::server {

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

struct JobContext {
  const Limits& limits;
  const wire::UploadLookup& uploads;
  int worker_threads = 1;
  // Where frames are checked and encoded (the worker pool); null: on the task's own thread.
  const Executor* executor = nullptr;
};

// Throws ResourceLimit naming --max-grid-cells when the grid of a polygonization requested at `path` is larger.
void check_grid_cells(const PolygonizeGrid& grid, const std::string& path, const Limits& limits);

// Throws ResourceLimit naming --max-frames when `count` frames (requested at `field_path`) exceed the limit.
void check_frame_count(std::int64_t count, const std::string& field_path, const Limits& limits);

// Dispatches on spec.kind. Throws surfacer::Error naming the offending field ("spec.isosurface.cells").
std::unique_ptr<JobRunner> make_job_runner(const v1::JobSpec& spec, const JobContext& context);

std::unique_ptr<JobRunner> make_isosurface_runner(const v1::JobSpec& spec, const JobContext& context);
std::unique_ptr<JobRunner> make_particles_runner(const v1::JobSpec& spec, const JobContext& context);
std::unique_ptr<JobRunner> make_optimize_runner(const v1::JobSpec& spec, const JobContext& context);
std::unique_ptr<JobRunner> make_active_runner(const v1::JobSpec& spec, const JobContext& context);

}  // namespace surfacer::server
