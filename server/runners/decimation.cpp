#include "server/runners/decimation.h"

namespace surfacer::server {

std::int64_t task_bytes_per_triangle(const FrameMaker& frames, std::int64_t engine_bytes) {
  return engine_bytes + (frames.encoding().decimate.tolerance > 0.0 ? TaskMemory::kDecimateBytesPerTriangle : 0);
}

FrameOutput decimated_frame(const FrameMaker& frames, Mesh mesh, const SurfacePointRule& rule, StageTimer& timer,
                            const RunControl& control) {
  DecimateOptions options = frames.encoding().decimate;
  if (options.tolerance == 0.0) return frames.make(std::move(mesh), timer, control);
  options.grid = frames.encoding().grid();  // angles as the frame's reader sees them
  const auto triangles_before = static_cast<double>(mesh.triangles.size());
  Mesh decimated = timer.run("decimate", [&] { return decimate(mesh, options, rule, control); });
  FrameOutput frame = frames.make(std::move(decimated), timer, control);
  (*frame.stats.mutable_metrics())["triangles_before_decimate"] = triangles_before;
  return frame;
}

}  // namespace surfacer::server
