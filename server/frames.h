// Shared by every job type: a finished mesh becomes a frame (checks, stats, encoding).
#pragma once

#include <chrono>
#include <string>
#include <utility>
#include <vector>

#include "core/mesh/mesh.h"
#include "core/mesh/mesh_checks.h"
#include "server/jobs.h"

namespace surfacer::server {

// Output settings of a job, resolved from v1::OutputOptions with defaults and validated.
struct FrameEncoding {
  v1::MeshEncoding encoding = v1::MESH_ENCODING_DRACO;
  int quantization_bits = 14;
  Aabb quantization_bounds;  // fixed for the whole job
  int draco_speed = 8;
  bool normals = false;
};

// Resolves `options` (path: where it sits in the request, for errors); `job_bounds` is the default quantization
// box. Throws InvalidInput naming the field.
FrameEncoding resolve_output(const v1::OutputOptions& options, const Aabb& job_bounds, const std::string& path);

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
FrameOutput make_frame(const Mesh& mesh, const FrameEncoding& encoding, std::int64_t max_triangles,
                       StageTimer& timer);

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
