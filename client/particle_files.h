// Particle files named on the command line (core/particles/particle_io.h reads them): inputs and sequence patterns
// expanded to the job's frames, and each frame packed as the protocol's upload records (little-endian float32 x y z, or
// x y z r with radii).
#pragma once

#include <cstdint>
#include <filesystem>
#include <limits>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "client/options.h"
#include "core/particles/particle_io.h"

namespace surfacer::client {

// True when `input` holds a sequence placeholder ("{}" or "{:04d}"; "{{" and "}}" are literal braces).
bool is_sequence_pattern(const std::string& input);

// The frame files of `options`, in order: each input is a file or a pattern; a pattern covers frames
// [--start, --end], and a bound that is not given is taken from the files present in the pattern's directory
// (the smallest / largest frame number found). Checks that every file exists. Throws CliError(kUsage) naming the
// flag and the input: a pattern that matches no file, a missing file (a gap in a sequence), end < start,
// --start/--end without any pattern. `flag` names the option in messages ("--input").
std::vector<std::filesystem::path> expand_particle_inputs(const ParticleInputOptions& options,
                                                          const std::string& flag = "--input");

// The same files with each one's frame number (nullopt for an input that is not a pattern). A "{}" placeholder in
// the file name matches any zero padding (fluid_{}.bgeo names fluid_7.bgeo and fluid_0007.bgeo; both present is an
// error); "{:04d}" names exactly fluid_0007.bgeo.
struct ParticleInputFiles {
  std::vector<std::filesystem::path> files;
  std::vector<std::optional<int>> numbers;
};
ParticleInputFiles expand_particle_sequence(const ParticleInputOptions& options, const std::string& flag = "--input");

// What a server accepts of one particle frame (its GetServerInfo limits); the defaults accept anything.
struct InputLimits {
  std::int64_t max_particles = std::numeric_limits<std::int64_t>::max();     // --max-particles
  std::int64_t max_upload_bytes = std::numeric_limits<std::int64_t>::max();  // --max-upload-bytes (or quota left)
};

// One frame as upload records.
struct ParticleRecords {
  std::string bytes;  // float32 LE records: x y z (or x y z r when with_radius), then the attributes' values
  bool with_radius = false;
  std::int64_t count = 0;
  std::vector<std::pair<std::string, int>> attributes;  // name and components, in record order
};

// Reads a particle file (any format of core/particles/particle_io.h) and packs it. Throws CliError(kUsage) whose
// message starts with the file name and names the line or byte offset of the problem; also for an empty frame, a radius
// count that differs from the particle count, a negative radius, or a value that does not fit in float32. A file
// the server would refuse (more particles than `limits` allow, records over its upload limit) is refused as early as
// its content shows it: gzip data stops inflating at 12 bytes per accepted particle (.bin) or 256 (other formats:
// text lines or records with many columns), at most 16 GiB; the message names the limit and the server flag.
//
// `attributes` names the file's attributes to pack after x y z [r] (ParticlesJob.interpolate; {"all"}: every one);
// a name the file lacks is refused naming the file and the attributes it has, and so is a value that is not finite
// in float32.
ParticleRecords read_particle_records(const std::filesystem::path& path, const InputLimits& limits = {},
                                      const std::vector<std::string>& attributes = {});

// Packs a frame already in memory (what read_particle_records does after reading), with the same checks and
// messages, `name` standing for the file: an empty frame, radii that are not one per particle or are negative,
// values that do not fit in float32, more particles or bytes than `limits` allow. Throws CliError(kUsage).
ParticleRecords pack_particle_records(const ParticleFrame& frame, const std::string& name,
                                      const InputLimits& limits = {}, const std::vector<std::string>& attributes = {});

}  // namespace surfacer::client
