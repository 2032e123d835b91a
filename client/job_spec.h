// Building a surfacer.v1.JobSpec from the CLI's job options. Scene and spec files are protobuf JSON, parsed with
// google::protobuf::util::JsonStringToMessage (unknown fields are errors, so typos do not pass silently). Inputs
// too large for the spec (particle frames, start meshes, velocity grids) become pending uploads: read and uploaded
// one at a time after connecting, their upload ids then filled into the spec (client/upload.h).
#pragma once

#include <filesystem>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "client/options.h"
#include "client/upload.h"
#include "surfacer/v1/surfacer.pb.h"

namespace surfacer::client {

// Reads one scene file. Throws CliError(kUsage) naming the file when it is unreadable or not a valid Scene
// (with protobuf's parser message).
v1::Scene read_scene_file(const std::filesystem::path& path);

// Reads a whole JobSpec (any job type). Throws CliError(kUsage) naming the file.
v1::JobSpec read_job_spec_file(const std::filesystem::path& path);

// A spec ready to submit once its uploads are done.
struct PreparedJob {
  v1::JobSpec spec;
  std::vector<PendingUpload> uploads;  // in order; empty for isosurface, morph, Enright advect and --spec
  // The number in each frame's output file name (client/output_files.h output_numbers): the input files' frame
  // numbers for particle sequences read from patterns; empty otherwise.
  std::vector<int> frame_numbers;
};

// Inputs handed over in memory rather than as files (the Python package): JobOptions name each one like a file, by
// its key here (a scene "file", or a particle input), and it is taken from here instead of being read. Every check,
// default and upload is otherwise that of a file.
struct InMemoryInputs {
  std::map<std::string, std::string> scenes;       // key -> a surfacer.v1.Scene in protobuf JSON
  std::map<std::string, ParticleFrame> particles;  // key -> one particle frame
};

// Parses a Scene from protobuf JSON with the checks of a scene file; `where` names it in errors ("scene file
// a.json"). Throws CliError(kUsage).
v1::Scene parse_scene_json(const std::string& text, const std::string& where);

// Checks the options of `options.spec` with the server's own wire::check_job_options() (every range, default and
// combination is core's, stated once). Throws CliError(kUsage) with the server's message, prefixed by the field's
// name as the user gave it ("--r-outer: spec.particles.r_outer (0.05) must exceed r_inner (0.1); ...").
void check_job(const JobOptions& options);

// The job of `options`: `options.spec_file` read (the output fields of `options.spec` override its own), or
// `options.spec` checked (check_job) with its inputs read in: scene files are parsed into it and sequence patterns
// expanded, and every other input becomes a pending upload (checked to exist, a velocity grid's size against its
// dimensions), so usage errors come before connecting. A particle frame without radii is refused as it is read when
// the job has neither r_inner nor derive_r_inner. Inputs named by a key of `in_memory` come from there (its particle
// frames are read by the uploads: keep it until they are done). Throws CliError(kUsage).
PreparedJob prepare_job(const JobOptions& options, const InMemoryInputs& in_memory = {});

// How many frames the job writes, when that is known before it runs: one per scene or particle frame, one for an
// optimize job without snapshots; nullopt otherwise (optimize snapshots, morph and advect frames).
std::optional<int> frames_before_run(const v1::JobSpec& spec);

// What a `run` that writes `formats` asks of the server (docs/ALGORITHMS.md §5 "Frames"): Draco frames come in
// pieces, encoded on every core of the server and decoded on every core here, unless a .drc file is to be written
// (a standard Draco file is one Draco mesh, which the server encodes on one core; welding pieces and encoding them
// again here would cost more); a .glb file holds the pieces as they come, and is the file written when `formats` is
// empty, unless the grid has more than 16 quantization bits (then a .drc). Other encodings are left alone. Throws
// CliError(kUsage) when .glb files are asked for with more than 16 quantization bits (glTF cannot hold them).
void fit_encoding_to_files(v1::JobSpec& spec, const std::vector<FileFormat>& formats);
// The same for a client that keeps the frames in memory (the Python package): it writes no .drc from the stream, so
// Draco frames come in pieces, and the welded mesh has the vertices of one Draco mesh on the job's grid.
void fit_encoding_to_memory(v1::JobSpec& spec);

}  // namespace surfacer::client
