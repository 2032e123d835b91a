// Job `isosurface`: scene(s) + bounds + resolution -> one polygonized frame per scene.
#include <cmath>

#include "core/errors.h"
#include "core/marching_cubes.h"
#include "core/scene.h"
#include "server/frames.h"
#include "server/job_types.h"
#include "server/scene_translate.h"

namespace surfacer::server {
namespace {

constexpr int kDefaultCells = 128;
constexpr double kPadCells = 2.0;  // padding of derived bounds, so closed surfaces stay inside

class IsosurfaceRunner final : public JobRunner {
 public:
  IsosurfaceRunner(std::vector<FieldPtr> fields, MarchingCubesOptions grid, FrameEncoding encoding,
                   std::int64_t max_triangles, int worker_threads)
      : fields_(std::move(fields)),
        grid_(grid),
        encoding_(encoding),
        max_triangles_(max_triangles),
        worker_threads_(worker_threads) {}

  std::string kind() const override { return "isosurface"; }
  int task_count() const override { return static_cast<int>(fields_.size()); }
  int frame_count() const override { return task_count(); }

  void run_task(int index, FrameSink& sink, const RunControl& control) override {
    MarchingCubesOptions grid = grid_;
    // A single frame gets every core; a sequence runs its frames in parallel, one thread each.
    grid.threads = fields_.size() == 1 ? worker_threads_ : 1;
    StageTimer timer;
    const Mesh mesh = timer.run("polygonize", [&] { return marching_cubes(*fields_[index], grid, control); });
    control.check();
    sink.emit(index, make_frame(mesh, encoding_, max_triangles_, timer));
  }

 private:
  std::vector<FieldPtr> fields_;
  MarchingCubesOptions grid_;
  FrameEncoding encoding_;
  std::int64_t max_triangles_;
  int worker_threads_;
};

}  // namespace

std::unique_ptr<JobRunner> make_isosurface_runner(const v1::JobSpec& spec, const JobContext& context) {
  const auto& job = spec.isosurface();
  const std::string path = "spec.isosurface";
  if (job.scenes_size() == 0) {
    throw InvalidInput(path + ".scenes", path + ".scenes is empty; give at least one scene (one frame per scene)");
  }
  if (job.scenes_size() > context.limits.max_frames) {
    throw ResourceLimit("max_frames", path + ".scenes has " + std::to_string(job.scenes_size()) +
                                          " scenes, over the server's limit of " +
                                          std::to_string(context.limits.max_frames) +
                                          " frames per job; split the job or raise --max-frames");
  }
  if (job.method() != v1::POLYGONIZER_UNSPECIFIED && job.method() != v1::POLYGONIZER_CUBES) {
    throw InvalidInput(path + ".method", path + ".method " + v1::Polygonizer_Name(job.method()) +
                                             " is not available; use POLYGONIZER_CUBES");
  }
  std::vector<FieldPtr> fields;
  fields.reserve(job.scenes_size());
  for (int i = 0; i < job.scenes_size(); ++i) {
    fields.push_back(field_from_scene(job.scenes(i), path + ".scenes[" + std::to_string(i) + "]", context.uploads));
  }

  // Bounds: given, or the union of the scenes' own bounds padded by two cells.
  const bool derived = !job.has_bounds();
  Aabb bounds;
  if (!derived) {
    bounds = to_aabb(job.bounds(), path + ".bounds");
  } else {
    for (int i = 0; i < job.scenes_size(); ++i) {
      const auto b = fields[i]->bounds();
      if (!b) {
        throw InvalidInput(path + ".bounds", path + ".scenes[" + std::to_string(i) +
                                                 "] is unbounded (a plane or gyroid not intersected with a bounded "
                                                 "solid); give " + path + ".bounds");
      }
      if (i == 0) {
        bounds = *b;
      } else {
        bounds.min = bounds.min.cwiseMin(b->min);
        bounds.max = bounds.max.cwiseMax(b->max);
      }
    }
    if (!bounds.min.allFinite() || !bounds.max.allFinite() || !bounds.valid()) {
      throw InvalidInput(path + ".bounds", path + ": the scenes' bounds are empty or not finite; give " + path +
                                               ".bounds");
    }
  }

  // Cell size.
  double h = 0.0;
  const double longest = bounds.size().maxCoeff();
  switch (job.resolution_case()) {
    case v1::IsosurfaceJob::kCellSize:
      h = job.cell_size();
      if (!(h > 0.0) || !std::isfinite(h)) {
        throw InvalidInput(path + ".cell_size", path + ".cell_size (" + std::to_string(h) +
                                                    ") must be a finite number > 0");
      }
      break;
    case v1::IsosurfaceJob::kCells:
      if (job.cells() < 1) {
        throw InvalidInput(path + ".cells", path + ".cells (" + std::to_string(job.cells()) +
                                                ") must be >= 1 (cells along the longest axis; e.g. 128)");
      }
      h = longest / job.cells();
      break;
    case v1::IsosurfaceJob::RESOLUTION_NOT_SET:
      h = longest / kDefaultCells;
      break;
  }
  if (derived) {
    bounds.min.array() -= kPadCells * h;
    bounds.max.array() += kPadCells * h;
  }
  MarchingCubesOptions grid;
  grid.bounds = bounds;
  grid.normals = spec.output().normals();
  double total = 1.0;
  for (int a = 0; a < 3; ++a) {
    const double n = std::max(1.0, std::ceil(bounds.size()[a] / h - 1e-9));
    total *= n;
    if (n > 1e9) total = 1e30;
    grid.cells[a] = static_cast<int>(std::min(n, 1e9));
  }
  if (total > static_cast<double>(context.limits.max_grid_cells)) {
    throw ResourceLimit("max_grid_cells", path + ": the grid has " + std::to_string(grid.cells[0]) + " x " +
                                              std::to_string(grid.cells[1]) + " x " + std::to_string(grid.cells[2]) +
                                              " cells, over the server's limit of " +
                                              std::to_string(context.limits.max_grid_cells) +
                                              "; use fewer cells or start the server with a larger "
                                              "--max-grid-cells");
  }
  // Stretch the bounds to a whole number of cubic cells.
  for (int a = 0; a < 3; ++a) {
    const double extra = grid.cells[a] * h - bounds.size()[a];
    grid.bounds.min[a] -= extra / 2;
    grid.bounds.max[a] += extra / 2;
  }
  const FrameEncoding encoding = resolve_output(spec.output(), grid.bounds, "spec.output");
  return std::make_unique<IsosurfaceRunner>(std::move(fields), grid, encoding, context.limits.max_triangles,
                                            context.worker_threads);
}

}  // namespace surfacer::server
