// Shared by every job type: a finished mesh becomes a frame (checks, stats, encoding).
#pragma once

#include <string>
#include <utility>
#include <vector>

#include "core/mesh.h"
#include "core/mesh_checks.h"
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

}  // namespace surfacer::server
