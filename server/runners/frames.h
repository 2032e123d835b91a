// Shared by every job runner: a finished mesh becomes a frame (checks, stats, encoding).
#pragma once

#include <chrono>
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

// Checks and encodes `mesh` into a frame, the checks running beside the (single-threaded) encoder. The frame stats
// get every timing of `timer` plus "encode" and "check". Throws ResourceLimit when the mesh has more than
// max_triangles triangles.
FrameOutput make_frame(const Mesh& mesh, const FrameEncoding& encoding, std::int64_t max_triangles, StageTimer& timer);

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
