// `surfacer run` against several servers (`--server a,b,c`, or a dns:/// name with several addresses).
//
// A frame sequence (isosurface with several scenes, particles with several frames) is split into small batches of
// frames kept in one shared queue. One worker thread per server takes a batch, uploads what the batch needs to that
// server, submits a sub-job with only those frames, watches it, and writes each frame under its index in the whole
// sequence; stats.csv is written in that global order. A particle batch goes to a server that takes open sequences
// as one (docs/ALGORITHMS.md §5, "Open sequences"): its sub-job is submitted once the batch's first frame is
// uploaded and the others join it as they are uploaded, so the server surfaces the first while the rest upload. Every
// sub-job gets the same grid and quantization box the whole job would have had (pin_whole_job_geometry), so the frames
// are the ones a single server would produce. A server that becomes unreachable (stream broken and not back within
// --timeout, or UNAVAILABLE) is marked dead and the frames of its batch not yet written go back to the queue for the
// others; the run succeeds while one server lives (exit 3 when none does). A sub-job that fails (bad input) fails the
// run (exit 4) and cancels the sub-jobs on the other servers, as does Ctrl-C (exit 5).
//
// Any other job (optimize, active, a single frame) runs whole on the first server that answers and is resubmitted
// from scratch to the next one when its server dies (run_run in commands.cpp).
#pragma once

#include <iosfwd>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "client/exit_codes.h"
#include "client/job_spec.h"
#include "client/options.h"
#include "client/progress.h"
#include "core/mesh/mesh.h"
#include "surfacer/v1/surfacer.pb.h"
#include "wire/particle_frames.h"

namespace surfacer::client {

// The number of frames of a job the client can split (isosurface scenes or particle frames), when there are at
// least two; 0 for every other job.
int sequence_frames(const v1::JobSpec& spec);

// Consecutive batches of global frame indices 0..frames-1 of ceil(frames / (4 * servers)) frames (at least 1).
std::vector<std::vector<int>> make_batches(int frames, int servers);

// The sub-job of `whole` (a sequence job) holding only `frames` (global indices), in that order; its name gets
// " [frames 3-5]".
v1::JobSpec sub_job_spec(const v1::JobSpec& whole, const std::vector<int>& frames);

// "frames 3-5", "frame 7", "frames 3, 5, 9".
std::string frames_text(const std::vector<int>& frames);

// A server's message about a sub-job with its local indices ("spec.isosurface.scenes[1]...") rewritten to the
// whole job's ("spec.isosurface.scenes[7]...") for `frames` = the sub-job's global indices.
std::string globalize_indices(const std::string& message, const std::vector<int>& frames);

// The first upload id a spec refers to ("spec.isosurface.scenes[2].root.grid.upload_id = u-..."): an upload lives
// on one server, so such a job cannot be split. nullopt when there is none.
std::optional<std::string> find_upload_reference(const v1::JobSpec& spec);

// Fixes in `spec` what the server would otherwise derive from the whole sequence, so each sub-job polygonizes on
// the same grid and quantizes on the same box:
// - isosurface without bounds: the grid the server would resolve for the whole sequence (bounds and cell size);
// - particles without output.quantization_bounds: the box the server would derive from `particle_frames`, with
//   frame 0's positions (`first_frame`) for a derived r_inner.
// Both use the server's own translation (wire/), so a job the server would refuse throws CliError(kJobFailed) with
// the server's INVALID_ARGUMENT message.
void pin_whole_job_geometry(v1::JobSpec& spec, const std::vector<wire::ParticleSummary>& particle_frames,
                            const std::vector<Vec3>& first_frame);

// Reads every particle frame of `prepared` once within `limits` (the uploads read them again), which refuses a bad
// file before any job is queued (CliError(kUsage) naming it), and pins the whole sequence's quantization box
// (pin_whole_job_geometry) unless the spec gives one. For jobs whose frames are uploaded while the job runs: a
// sequence split across servers, an open sequence.
void pin_particles_from_inputs(PreparedJob& prepared, const InputLimits& limits = {});

// The whole `run` of a sequence job across `servers` (already resolved "HOST:PORT" targets, at least two).
// Returns kSuccess or throws CliError (see the header comment for the codes).
ExitCode run_scale_out(const ConnectOptions& connect, const std::vector<std::string>& servers, PreparedJob prepared,
                       const FrameOutputOptions& output, std::ostream& err, ProgressMode progress);

}  // namespace surfacer::client
