// Job runners: what computes a job's frames. Each job type turns its part of a v1::JobSpec into a JobRunner,
// validating everything at submit time so that bad input answers INVALID_ARGUMENT / RESOURCE_EXHAUSTED before any
// work is queued. The request's fields become engine options in wire/job_options.h; the runner adds what depends on
// the server (its limits, its workers) and cuts the job into tasks.
#pragma once

#include <cstdint>
#include <memory>
#include <mutex>
#include <string>

#include "core/util/run_control.h"
#include "core/util/triangle_limit.h"
#include "server/memory_budget.h"
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

  // Open sequences (ParticlesJob.open; docs/ALGORITHMS.md §5, "Open sequences"): frames join the job while it runs,
  // one task each. Whether the job was submitted open (it stays so until its end marker, which the job tracks).
  virtual bool open() const { return false; }
  // Checks `frames` (at `path`: "frames", named "frames[i]") as the job's next ones, from task_count() on, with the
  // checks submit makes; throws surfacer::Error naming the frame (InvalidInput, ResourceLimit past --max-frames).
  // A runner that is not open throws InvalidInput.
  virtual void check_appended(const google::protobuf::RepeatedPtrField<v1::ParticleFrame>& frames,
                              const std::string& path) const;
  // Adds frames check_appended() accepted as tasks task_count(), task_count() + 1, ... Thread-safe with run_task.
  virtual void append(const google::protobuf::RepeatedPtrField<v1::ParticleFrame>& /*frames*/) {}
  // Writes into `spec` what the runner derived and must keep when it is rebuilt from the stored spec after a
  // restart (an open sequence's quantization box, which later frames no longer define).
  virtual void pin(v1::JobSpec& /*spec*/) const {}
};

struct JobContext {
  const Limits& limits;
  const wire::UploadLookup& uploads;
  // Threads a task's loops run on (>= 1), its frames' checks and encoding included: the task's own thread and free
  // threads of the process-wide pool (core/util/parallel.h).
  int worker_threads = 1;
  // The server's memory budget (--memory-budget) that tasks building meshes draw from (TaskMemory); null: none.
  MemoryBudget* memory = nullptr;
};

// The memory one task that builds meshes may hold. Its meshes are held to --max-triangles as they are built
// (RunControl::triangles, core/util/triangle_limit.h), and before their triangles are made it reserves from the
// server's memory budget kBytesPerTriangle per triangle of its largest mesh (in chunks as the mesh grows) plus the
// fixed working memory a stage states before its work (reserve_fixed). A task that cannot get its reservation fails
// with RESOURCE_EXHAUSTED naming --memory-budget and leaves the other jobs alone. Everything is given back when the
// object is destroyed (at the end of the task). Not movable (control() points into it).
class TaskMemory {
 public:
  // A task's peak resident memory per triangle of its largest mesh, every stage included: the one estimate of it.
  // Measured as peak RSS growth of a surfacer-server over the output's triangles (gyroid_in_sphere at 256-400 cells,
  // torus optimized to 1.4-5.7 M triangles, drop_in_pool particles): isosurface 126 (cubes) and 142 (tiles) bytes
  // with Draco frames, 55-80 with PLY; optimize with subdivision 265; particles 240.
  // Polygonizing (isosurface, active surfaces): the polygonizer's output and merge, the mesh, the frame's checks and
  // encoding.
  static constexpr std::int64_t kPolygonizeBytesPerTriangle = 192;
  // Working on the mesh (optimize, particles): also the engine's per-vertex and per-triangle arrays, adjacency and
  // the refinement's trial copy, or the smoothing's matrices.
  static constexpr std::int64_t kMeshWorkBytesPerTriangle = 384;
  // Added to either when the job's frames are decimated (the output option decimate): the decimator's per-vertex
  // quadrics, heap and flags and one region mesh per thread beside the engine's mesh. Measured as the peak RSS
  // growth over the same run without decimation: 75 bytes per triangle of the engine's mesh for gyroid_in_sphere at
  // 256 cells (cubes, 2.1 M triangles, TOL 0.002), 38 at 200 cells (tiles, 4.2 M), 16 for a 256 k-particle block
  // (1.19 M triangles, TOL 0.0006), whose smoothing arrays are freed before.
  static constexpr std::int64_t kDecimateBytesPerTriangle = 96;
  // Particle frames reserve this per particle as well (reserve_fixed, before surfacing), since a frame's particles can
  // take more memory than its triangles (a deep block, or many coincident particles): the decoded positions (24 bytes)
  // and the surfacer's spatial hash (sorted copy 24, order 4, cell directory about 5), with room for its scratch and
  // the merging of coincident particles (groups, weights). Measured: a million copies of 515 particles (one small mesh)
  // grew a --local run's peak RSS by 101 bytes per particle, the client's own copies (36) and the upload (12) included.
  // Per-particle radii add kWeightedParticleBytes (decoded, then inner and outer in input and hash order); interpolated
  // attributes add their decoded floats.
  static constexpr std::int64_t kParticleBytes = 80;
  static constexpr std::int64_t kWeightedParticleBytes = 40;

  // `what` names the task in a refusal ("isosurface frame 3"); bytes_per_triangle: one of the two above (plus the third
  // when decimating; task_bytes_per_triangle); budget null: nothing is reserved.
  TaskMemory(const Limits& limits, MemoryBudget* budget, std::string what, std::int64_t bytes_per_triangle);
  TaskMemory(const TaskMemory&) = delete;
  TaskMemory& operator=(const TaskMemory&) = delete;

  // Adds `bytes` (>= 0) of working memory besides the triangles (e.g. polygonize_fixed_bytes), reserved now. Throws
  // ResourceLimit("memory_budget") when the budget cannot give it.
  void reserve_fixed(std::int64_t bytes);
  // `base` with this task's triangle limit and reservation hook.
  RunControl control(const RunControl& base) const;
  std::int64_t reserved_bytes() const;

 private:
  void reserve_triangles(std::int64_t triangles);
  void grow_locked();

  MemoryBudget* budget_;
  std::string what_;
  std::int64_t bytes_per_triangle_;
  TriangleLimit limit_;
  mutable std::mutex mutex_;
  MemoryReservation reservation_;
  std::int64_t fixed_bytes_ = 0;
  std::int64_t triangles_ = 0;  // the most any hook call asked for
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
