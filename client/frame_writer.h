// Writes received frames to the output directory: frame_NNNN.{drc,ply,obj,vtk,vtu} or the names of an output
// pattern (client/output_files.h; each file atomically: temporary file
// in the same directory, then rename), stats.csv (one row per frame, rewritten atomically after every frame) and,
// for optimize jobs, iterations.csv (one row per snapshot).
#pragma once

#include <filesystem>
#include <map>
#include <string>
#include <string_view>
#include <vector>

#include "client/frame_assembler.h"
#include "client/options.h"
#include "core/mesh/frame_codec.h"
#include "surfacer/v1/surfacer.pb.h"

namespace surfacer::client {

// Writes `bytes` to `path` through a temporary sibling and rename(2); readers never see a partial file.
// Throws CliError(kUsage) naming the path and the OS error.
void write_file_atomically(const std::filesystem::path& path, std::string_view bytes);

// "frame_0003.drc" (the name of frame 3 when the output has no pattern and no frame numbers)
std::string frame_file_name(int index, FileFormat format);

// stats.csv text: header, then one row per frame in index order: frame, vertices, triangles, closed, manifold
// (edge && vertex manifold), euler, components, min_valence, min_angle (degrees), area, volume, one `<stage>_s`
// column per stage seen (seconds; empty when a frame lacks it), total_s, then one column per FrameStats.metrics
// key seen in any frame (sorted by key; empty when a frame lacks it), named by the key, or "metric_<key>" when the
// key is also the name of a column before it (e.g. an active job's "volume").
std::string stats_csv(const std::map<int, v1::FrameStats>& stats);

// iterations.csv text (optimize jobs: one row per snapshot, in frame order): frame, iteration, triangles, then one
// column per metrics key seen in any frame (sorted: e_d, e_n, max_distance, min_angle_degrees, rms_distance, ...).
std::string iterations_csv(const std::map<int, v1::FrameStats>& stats);

// The file a frame is written as when no format is asked for: Draco pieces as they came, in a .glb (written on every
// core, nothing decoded), unless their grid has more bits than glTF holds; one Draco mesh, or pieces on such a grid,
// as a .drc; .ply for meshopt and raw frames. Throws InvalidInput("frame") for pieced bytes that are not a frame.
FileFormat default_format(FrameCodec codec, std::string_view bytes);

// A ParaView/VTK XML Collection (.pvd) of `frames` (time, file name relative to the .pvd), and the same as ParaView's
// file-series JSON (.series), which also takes legacy .vtk files.
std::string pvd_collection(const std::vector<std::pair<double, std::string>>& frames);
std::string file_series(const std::vector<std::pair<double, std::string>>& frames);

class FrameWriter {
 public:
  // Creates the directory; CliError(kUsage) when that fails.
  explicit FrameWriter(FrameOutputOptions options);

  // Writes one file per requested format (default: default_format of the frame's codec), bytes as received when
  // they are that file, converted otherwise: decoded (pieced frames on every core, welded) for PLY/OBJ; to one
  // standard Draco mesh for .drc (pieced frames on their own quantization grid, lossless PLY on its own box, 14
  // bits).
  // Throws CliError(kIntegrity) when the frame's bytes do not decode, CliError(kUsage) when a file cannot be
  // written. Returns the files written.
  std::vector<std::filesystem::path> write(const ReceivedFrame& frame);

  // The job's kind ("optimize", ...): an optimize job also gets iterations.csv (as does any job whose frames carry
  // an iteration number), rewritten after every frame.
  void set_job_kind(const std::string& kind) { kind_ = kind; }

  const std::filesystem::path& dir() const { return options_.dir; }
  // What -o named: the directory, or the file pattern.
  std::string target() const { return options_.pattern.value_or(options_.dir.string()); }
  int frames_written() const { return static_cast<int>(stats_.size()); }
  // Stats of every frame written, by index.
  const std::map<int, v1::FrameStats>& stats() const { return stats_; }
  // The files written for each frame, by index (what write() returned).
  const std::map<int, std::vector<std::filesystem::path>>& files() const { return files_; }
  bool wrote_iterations() const { return iterations_; }

 private:
  // ParaView's time series beside a .vtu or .vtk sequence, rewritten as each frame arrives: BASE.pvd (a VTK XML
  // Collection of the .vtu files) and BASE.vtk.series (ParaView's file-series JSON for the legacy files), each frame at
  // time = its number in the file names (the input's frame numbers, else the index), so ParaView shows frames 100..104
  // as times 100..104. BASE is "frames" in a directory, or the pattern's name without its placeholder. None for -o
  // FILE.
  void write_time_series() const;

  FrameOutputOptions options_;
  int decode_threads_;  // every core (resolve_threads(0))
  std::map<int, v1::FrameStats> stats_;
  std::map<int, std::vector<std::filesystem::path>> files_;
  std::string kind_;
  bool iterations_ = false;
};

}  // namespace surfacer::client
