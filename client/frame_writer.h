// Writes received frames to the output directory: frame_NNNN.{drc,ply,obj} (each file atomically: temporary file
// in the same directory, then rename) and stats.csv (one row per frame, rewritten atomically after every frame).
#pragma once

#include <filesystem>
#include <map>
#include <string>
#include <string_view>
#include <vector>

#include "client/frame_assembler.h"
#include "client/options.h"
#include "surfacer/v1/surfacer.pb.h"

namespace surfacer::client {

// Writes `bytes` to `path` through a temporary sibling and rename(2); readers never see a partial file.
// Throws CliError(kUsage) naming the path and the OS error.
void write_file_atomically(const std::filesystem::path& path, std::string_view bytes);

// "frame_0003.drc"
std::string frame_file_name(int index, FileFormat format);

// stats.csv text: header, then one row per frame in index order: frame, vertices, triangles, closed, manifold
// (edge && vertex manifold), euler, components, min_valence, min_angle (degrees), area, volume, one `<stage>_s`
// column per stage seen (seconds; empty when a frame lacks it), total_s.
std::string stats_csv(const std::map<int, v1::FrameStats>& stats);

class FrameWriter {
 public:
  // Creates the directory; CliError(kUsage) when that fails.
  explicit FrameWriter(FrameOutputOptions options);

  // Writes one file per requested format (default: the frame's own encoding, bytes as received), converting
  // when needed: Draco -> PLY/OBJ by decoding; lossless PLY -> OBJ by parsing, -> Draco by encoding (14 bits).
  // Throws CliError(kIntegrity) when the frame's bytes do not decode, CliError(kUsage) when a file cannot be
  // written. Returns the files written.
  std::vector<std::filesystem::path> write(const ReceivedFrame& frame);

  const std::filesystem::path& dir() const { return options_.dir; }
  int frames_written() const { return static_cast<int>(stats_.size()); }

 private:
  FrameOutputOptions options_;
  std::map<int, v1::FrameStats> stats_;
};

}  // namespace surfacer::client
