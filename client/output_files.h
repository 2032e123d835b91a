// Where `run` and `watch` write each frame: -o DIR (DIR/frame_NNNN.<ext> per --format) or -o PATTERN
// (out/surface_{:04d}.ply: one file per frame named by the pattern, its extension giving the format), and the
// number in each name (the input sequence's own frame numbers when they exist, else the frame index).
#pragma once

#include <filesystem>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "client/options.h"

namespace surfacer::client {

// "drc" -> kDrc, ... "glb" -> kGlb (lower case, no dot); nullopt for anything else.
std::optional<FileFormat> file_format_from_name(std::string_view name);
const char* file_format_name(FileFormat format);  // "drc", ...
std::vector<std::string> file_format_names();      // every format's name, in --format's order

// The output of `command` ("run", "watch") from -o TARGET and --format NAMES (already checked to be format names).
// A TARGET with a placeholder ({} or {:04d}, as in input patterns) is a pattern: its extension must name a format
// and --format must not be given; the placeholder may not be in a directory name. A TARGET without one whose
// extension names a format and that is not an existing directory is one file (FrameOutputOptions::file). Throws
// CliError(kUsage) naming -o or --format and the fix.
FrameOutputOptions frame_output_options(const std::string& target, const std::vector<std::string>& formats,
                                        const std::string& command);

// With -o FILE.ext (options.file), throws CliError(kUsage) asking for a placeholder unless the job writes exactly one
// frame (`frames`: the count when known before the job runs, nullopt for "several": optimize snapshots, active
// frames). Does nothing for -o DIR and patterns.
void check_one_file(const FrameOutputOptions& options, std::optional<int> frames);

// The number frame `index` carries in its file name (options.frame_numbers, else the index).
int output_frame_number(const FrameOutputOptions& options, int index);

// The file frame `index` is written to in `format`: DIR/frame_NNNN.<ext> (at least 4 digits), or the pattern
// expanded with the frame's number.
std::filesystem::path frame_file_path(const FrameOutputOptions& options, int index, FileFormat format);

// Frame numbers for the output names of a sequence whose frames came from input files numbered `numbers` (nullopt:
// a file that is not part of a pattern): the numbers themselves when every frame has one and they increase, so
// `--input 'fluid_{:04d}.bgeo' --start 100` writes frame_0100.*; otherwise empty (frames are numbered from 0).
std::vector<int> output_numbers(const std::vector<std::optional<int>>& numbers);

}  // namespace surfacer::client
