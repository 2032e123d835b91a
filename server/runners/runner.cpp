#include "server/runners/runner.h"

#include <algorithm>

#include "core/polygonize/polygonize.h"
#include "core/util/errors.h"
#include "core/util/format.h"

namespace surfacer::server {

TaskMemory::TaskMemory(const Limits& limits, MemoryBudget* budget, std::string what, std::int64_t bytes_per_triangle)
    : budget_(budget), what_(std::move(what)), bytes_per_triangle_(bytes_per_triangle) {
  limit_.max_triangles = limits.max_triangles;
  limit_.name = "--max-triangles";
  if (budget_ != nullptr) limit_.reserve = [this](std::int64_t triangles) { reserve_triangles(triangles); };
}

void TaskMemory::reserve_fixed(std::int64_t bytes) {
  std::lock_guard lock(mutex_);
  fixed_bytes_ += std::max<std::int64_t>(bytes, 0);
  grow_locked();
}

void TaskMemory::reserve_triangles(std::int64_t triangles) {
  std::lock_guard lock(mutex_);
  triangles_ = std::max(triangles_, triangles);
  grow_locked();
}

void TaskMemory::grow_locked() {
  if (budget_ == nullptr) return;
  const std::int64_t bytes = fixed_bytes_ + triangles_ * bytes_per_triangle_;
  const std::string what = what_ + " (" +
                           (fixed_bytes_ > 0 ? std::to_string(fixed_bytes_) + " bytes of working memory and " : "") +
                           "a mesh of up to " + std::to_string(triangles_) + " triangles)";
  if (reservation_.bytes() == 0) {
    reservation_ = budget_->reserve(bytes, what);
  } else {
    reservation_.grow_to(bytes, what);
  }
}

RunControl TaskMemory::control(const RunControl& base) const {
  RunControl control = base;
  control.triangles = &limit_;
  return control;
}

std::int64_t TaskMemory::reserved_bytes() const {
  std::lock_guard lock(mutex_);
  return reservation_.bytes();
}

void JobRunner::check_appended(const google::protobuf::RepeatedPtrField<v1::ParticleFrame>&,
                               const std::string& path) const {
  throw InvalidInput(path, "this " + kind() + " job is not an open sequence: frames cannot join it");
}

void check_frame_count(std::int64_t count, const std::string& field_path, const Limits& limits) {
  if (count > limits.max_frames) {
    throw ResourceLimit("max_frames", field_path + " asks for " + std::to_string(count) +
                                          " frames, over the server's limit of " + std::to_string(limits.max_frames) +
                                          " per job; split the job or start the server with a larger --max-frames");
  }
}

void check_grid_cells(const PolygonizeGrid& grid, const std::string& path, const Limits& limits) {
  if (grid.cell_count > static_cast<double>(limits.max_grid_cells)) {
    // An axis of more than 1e9 cells is held at 1e9 in `cells`: then only the product says how many were asked for.
    const bool held = *std::max_element(grid.cells.begin(), grid.cells.end()) >= 1000000000;
    const std::string size = held ? format_number(grid.cell_count)
                                  : std::to_string(grid.cells[0]) + " x " + std::to_string(grid.cells[1]) + " x " +
                                        std::to_string(grid.cells[2]);
    throw ResourceLimit("max_grid_cells", path + ": the grid has " + size + " cells, over the server's limit of " +
                                              std::to_string(limits.max_grid_cells) +
                                              "; use fewer cells or start the server with a larger "
                                              "--max-grid-cells");
  }
}

std::unique_ptr<JobRunner> make_job_runner(const v1::JobSpec& spec, const JobContext& context) {
  switch (spec.kind_case()) {
    case v1::JobSpec::kIsosurface:
      return make_isosurface_runner(spec, context);
    case v1::JobSpec::kParticles:
      return make_particles_runner(spec, context);
    case v1::JobSpec::kOptimize:
      return make_optimize_runner(spec, context);
    case v1::JobSpec::kActive:
      return make_active_runner(spec, context);
    case v1::JobSpec::KIND_NOT_SET:
      break;
  }
  throw InvalidInput("spec.kind", "spec has no job kind; set one of: isosurface, particles, optimize, active");
}

}  // namespace surfacer::server
