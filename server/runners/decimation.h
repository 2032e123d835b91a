// The output option `decimate` (docs/ALGORITHMS.md §5, CHOICE "Decimation"): a job's mesh decimated under the
// engine's rule for surface points before it becomes a frame.
#pragma once

#include "core/mesh/decimate.h"
#include "server/runners/frames.h"

namespace surfacer::server {

// The frame of `mesh` (FrameMaker::make), decimated first when the job's output asks for it
// (frames.encoding().decimate.tolerance > 0) under `rule` (empty: the tolerance bound alone): the stage "decimate" is
// timed in `timer` and the metric "triangles_before_decimate" records the engine's triangle count. `mesh` is taken by
// value, as FrameMaker::make snaps its positions: callers that no longer need theirs move it in. Throws what
// decimate() and FrameMaker::make throw.
// The memory a task of the job reserves per triangle of its mesh (TaskMemory): `engine_bytes` (one of TaskMemory's
// k*BytesPerTriangle), plus TaskMemory::kDecimateBytesPerTriangle when its frames are decimated.
std::int64_t task_bytes_per_triangle(const FrameMaker& frames, std::int64_t engine_bytes);

FrameOutput decimated_frame(const FrameMaker& frames, Mesh mesh, const SurfacePointRule& rule, StageTimer& timer,
                            const RunControl& control);

}  // namespace surfacer::server
