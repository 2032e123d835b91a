// Job `isosurface`: scene(s) + bounds + resolution -> one polygonized frame per scene.
#include "core/polygonize/polygonize.h"
#include "core/util/errors.h"
#include "server/runners/decimation.h"
#include "server/runners/frames.h"
#include "server/runners/runner.h"
#include "wire/job_options.h"

namespace surfacer::server {
namespace {

class IsosurfaceRunner final : public JobRunner {
 public:
  IsosurfaceRunner(std::vector<FieldPtr> fields, PolygonizeGrid grid, FrameMaker frames, const JobContext& context)
      : fields_(std::move(fields)),
        grid_(grid),
        frames_(std::move(frames)),
        worker_threads_(context.worker_threads),
        limits_(context.limits),
        memory_(context.memory) {}

  std::string kind() const override { return "isosurface"; }
  int task_count() const override { return static_cast<int>(fields_.size()); }
  int frame_count() const override { return task_count(); }

  void run_task(int index, FrameSink& sink, const RunControl& control) override {
    // A single frame gets every core; a sequence runs its frames in parallel, one thread each.
    PolygonizeGrid grid = grid_;
    grid.threads = fields_.size() == 1 ? worker_threads_ : 1;
    grid.vertex_margin = frames_.vertex_margin();
    TaskMemory memory(limits_, memory_, "isosurface frame " + std::to_string(index),
                      task_bytes_per_triangle(frames_, TaskMemory::kPolygonizeBytesPerTriangle));
    memory.reserve_fixed(polygonize_fixed_bytes(grid));
    const RunControl task = memory.control(control);
    StageTimer timer;
    Mesh mesh = timer.run("polygonize", [&] { return polygonize(*fields_[index], grid, task); });
    control.check();
    sink.emit(index,
              decimated_frame(frames_, std::move(mesh),
                              zero_set_rule(*fields_[index], frames_.encoding().decimate.tolerance), timer, task));
  }

 private:
  std::vector<FieldPtr> fields_;
  PolygonizeGrid grid_;
  FrameMaker frames_;
  int worker_threads_;
  Limits limits_;
  MemoryBudget* memory_;
};

}  // namespace

std::unique_ptr<JobRunner> make_isosurface_runner(const v1::JobSpec& spec, const JobContext& context) {
  const auto& job = spec.isosurface();
  const std::string path = "spec.isosurface";
  if (job.scenes_size() == 0) {
    throw InvalidInput(path + ".scenes", path + ".scenes is empty; give at least one scene (one frame per scene)");
  }
  check_frame_count(job.scenes_size(), path + ".scenes", context.limits);
  std::vector<FieldPtr> fields = wire::isosurface_fields(job, context.uploads, path);
  const PolygonizeOptions options = wire::isosurface_options(job, spec.output().normals(), path);
  const PolygonizeGrid grid = with_path(path, [&] { return resolve_grid(fields, options); });
  check_grid_cells(grid, path, context.limits);
  const FrameEncoding encoding = wire::frame_encoding(spec.output(), grid.bounds, "spec.output");
  return std::make_unique<IsosurfaceRunner>(
      std::move(fields), grid, FrameMaker(encoding, context.limits.max_triangles, context.worker_threads), context);
}

}  // namespace surfacer::server
