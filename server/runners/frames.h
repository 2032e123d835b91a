// Shared by every job runner: a finished mesh becomes a frame (checks, stats, encoding).
#pragma once

#include <chrono>
#include <future>
#include <string>
#include <utility>
#include <vector>

#include "core/mesh/mesh.h"
#include "core/mesh/mesh_checks.h"
#include "server/runners/runner.h"
#include "wire/output.h"

namespace surfacer::server {

using wire::FrameEncoding;

// Times stages of a frame: `timings.run("polygonize", [&]{...})`.
class StageTimer {
 public:
  template <class F>
  auto run(const char* stage, F&& f) {
    const auto start = now();
    struct Record {
      StageTimer* self;
      const char* stage;
      double start;
      ~Record() { self->timings_.emplace_back(stage, now() - start); }
    } record{this, stage, start};
    return f();
  }
  // Records a stage timed elsewhere (e.g. by an engine's own stats).
  void add(std::string stage, double seconds) { timings_.emplace_back(std::move(stage), seconds); }
  const std::vector<std::pair<std::string, double>>& timings() const { return timings_; }

 private:
  static double now();
  std::vector<std::pair<std::string, double>> timings_;
};

void fill_mesh_check(const MeshReport& report, v1::MeshCheck& out);

// Turns a job's meshes into frames: checks, stats and encoding (docs/ALGORITHMS.md §5 "Frames").
class FrameMaker {
 public:
  // `threads` (>= 1; less is taken as 1): the threads the checks and the pieces of a pieced codec run on, the calling
  // thread and free threads of the process-wide pool. Throws nothing; the encoding was validated by
  // wire::frame_encoding.
  FrameMaker(FrameEncoding encoding, std::int64_t max_triangles, int threads);

  // The frame of `mesh`, its stats holding every timing of `timer` plus "grid_cleanup", "encode" and "check" (wall
  // seconds of each). On a quantizing codec the mesh is first made clean on the job's grid (core/mesh/grid_cleanup.h;
  // metrics grid_degenerate_found, grid_coincident_found, grid_nudges, grid_left) and every vertex put on its grid
  // point, so the checks (area and volume included) are of the mesh a decoder reads. The checks run first, then the
  // encoding, each on every one of `threads`; a standard Draco frame is encoded while the checks run. The
  // checks and a pieced codec's pieces run as items of parallel loops and stop between items when `control` fires. A
  // standard Draco frame's encoder cannot be interrupted: above one piece's size it is posted to the process-wide
  // pool beside the checks (the caller runs it itself when no pool thread has taken it by the time the checks end),
  // and a cancel leaves a pool thread's encoding to finish in the background, so that the caller is free as soon as
  // that thread has its copy of the mesh.
  // Throws ResourceLimit when the mesh has more than max_triangles triangles, Cancelled, and what the codec throws.
  FrameOutput make(Mesh mesh, StageTimer& timer, const RunControl& control) const;

  const FrameEncoding& encoding() const { return encoding_; }

  // Frames also state, as metric slivers_left, how many triangles of the mesh a decoder reads have an angle below
  // `degrees` (> 0): the particle engine's repair threshold, counted after the grid cleanup and any decimation.
  void count_slivers_below(double degrees) { sliver_degrees_ = degrees; }

  // The margin a polygonizer keeps between its vertices and the ends of their edges for these frames
  // (PolygonizeGrid::vertex_margin): kMarginSteps steps of the quantization grid, 0 for lossless frames. Vertices
  // near a zero sample then keep distinct grid points, so the grid cleanup has little left to do.
  double vertex_margin() const;
  static constexpr double kMarginSteps = 3.0;

 private:
  FrameEncoding encoding_;
  std::int64_t max_triangles_;
  int threads_;
  double sliver_degrees_ = 0.0;  // count_slivers_below
};

// Keeps checkpoints under ~10% of the task's time: one is taken only when the work since the previous one took at
// least 10 times what that one cost (serializing plus the store's write and fsync). With snapshots or frames seconds
// apart that is every one; an optimization snapshotting every iteration of a large mesh checkpoints less often.
class CheckpointPacer {
 public:
  bool due() const { return Clock::now() - last_end_ >= kWorkPerCost * last_cost_; }
  template <class F>
  void take(F&& checkpoint) {
    const auto t0 = Clock::now();
    checkpoint();
    last_end_ = Clock::now();
    last_cost_ = last_end_ - t0;
  }

 private:
  using Clock = std::chrono::steady_clock;
  static constexpr int kWorkPerCost = 10;
  Clock::time_point last_end_ = Clock::now();
  Clock::duration last_cost_{0};
};

}  // namespace surfacer::server
