// Job `isosurface`: scene(s) + bounds + resolution -> one polygonized frame per scene.
#include <cmath>

#include "core/util/errors.h"
#include "core/scene/scene.h"
#include "server/frames.h"
#include "server/job_types.h"
#include "server/polygonize.h"
#include "server/scene_translate.h"

namespace surfacer::server {
namespace {

constexpr int kDefaultCells = 128;

class IsosurfaceRunner final : public JobRunner {
 public:
  IsosurfaceRunner(std::vector<FieldPtr> fields, PolygonizeSettings settings, FrameEncoding encoding,
                   std::int64_t max_triangles, int worker_threads)
      : fields_(std::move(fields)),
        settings_(settings),
        encoding_(encoding),
        max_triangles_(max_triangles),
        worker_threads_(worker_threads) {}

  std::string kind() const override { return "isosurface"; }
  int task_count() const override { return static_cast<int>(fields_.size()); }
  int frame_count() const override { return task_count(); }

  void run_task(int index, FrameSink& sink, const RunControl& control) override {
    // A single frame gets every core; a sequence runs its frames in parallel, one thread each.
    const int threads = fields_.size() == 1 ? worker_threads_ : 1;
    StageTimer timer;
    const Mesh mesh = timer.run("polygonize", [&] { return polygonize(*fields_[index], settings_, threads, control); });
    control.check();
    sink.emit(index, make_frame(mesh, encoding_, max_triangles_, timer));
  }

 private:
  std::vector<FieldPtr> fields_;
  PolygonizeSettings settings_;
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
  check_frame_count(job.scenes_size(), path + ".scenes", context.limits);
  std::vector<FieldPtr> fields;
  fields.reserve(job.scenes_size());
  for (int i = 0; i < job.scenes_size(); ++i) {
    fields.push_back(field_from_scene(job.scenes(i), path + ".scenes[" + std::to_string(i) + "]", context.uploads));
  }
  Resolution resolution;
  if (job.resolution_case() == v1::IsosurfaceJob::kCells) resolution.cells = job.cells();
  if (job.resolution_case() == v1::IsosurfaceJob::kCellSize) resolution.cell_size = job.cell_size();
  const PolygonizeSettings settings =
      resolve_polygonize(fields, job.has_bounds() ? &job.bounds() : nullptr, resolution, kDefaultCells, job.method(),
                         spec.output().normals(), context.limits, path);
  const FrameEncoding encoding = resolve_output(spec.output(), settings.bounds, "spec.output");
  return std::make_unique<IsosurfaceRunner>(std::move(fields), settings, encoding, context.limits.max_triangles,
                                            context.worker_threads);
}

}  // namespace surfacer::server
