#include "server/runners/runner.h"

#include <algorithm>

#include "core/polygonize/polygonize.h"
#include "core/util/errors.h"
#include "core/util/format.h"

namespace surfacer::server {

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
