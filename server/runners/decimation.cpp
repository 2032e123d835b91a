#include "server/runners/decimation.h"

namespace surfacer::server {

FrameOutput decimated_frame(const FrameMaker& frames, const Mesh& mesh, const SurfacePointRule& rule,
                            StageTimer& timer, const RunControl& control) {
  const DecimateOptions& options = frames.encoding().decimate;
  if (options.tolerance == 0.0) return frames.make(mesh, timer, control);
  const Mesh decimated = timer.run("decimate", [&] { return decimate(mesh, options, rule, control); });
  FrameOutput frame = frames.make(decimated, timer, control);
  (*frame.stats.mutable_metrics())["triangles_before_decimate"] = static_cast<double>(mesh.triangles.size());
  return frame;
}

}  // namespace surfacer::server
