// Pictures of a run: `surfacer preview FRAME... -o DIR` and `run/watch --preview`. Frames are mesh files (.drc,
// .ply, .obj) rendered headless (core/render/) from one camera framed on the union of every frame's bounds (and
// particles', when given), so a sequence does not jump; an optimize run's iterations.csv becomes a plot of e_d and
// e_n per iteration, log scale.
#pragma once

#include <filesystem>
#include <iosfwd>
#include <vector>

#include "client/exit_codes.h"
#include "client/options.h"

namespace surfacer::client {

// DIR/<frame file's stem>.png for each frame (created, each atomically); `options.particles` is empty or holds one
// particle file per frame. Returns the PNGs in frame order. Throws CliError(kUsage) naming the file that cannot be
// read or written, or a particle count that does not match.
std::vector<std::filesystem::path> render_frame_previews(const std::vector<std::filesystem::path>& frames,
                                                         const std::filesystem::path& dir,
                                                         const PreviewOptions& options);

// DIR/iterations.png from an optimize run's iterations.csv (columns iteration, e_d, e_n). Throws CliError(kUsage)
// when the file cannot be read or has neither e_d nor e_n with a positive value.
std::filesystem::path render_iterations_plot(const std::filesystem::path& csv, const std::filesystem::path& dir,
                                             const PreviewOptions& options);

// The `preview` command: the PNGs' paths on `out`, one per line.
ExitCode run_preview(const PreviewCommand& command, std::ostream& out);

}  // namespace surfacer::client
