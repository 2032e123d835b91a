// Building a surfacer.v1.JobSpec from the CLI's job options. Scene and spec files are protobuf JSON, parsed with
// google::protobuf::util::JsonStringToMessage (unknown fields are errors, so typos do not pass silently).
#pragma once

#include <filesystem>

#include "client/options.h"
#include "surfacer/v1/surfacer.pb.h"

namespace surfacer::client {

// Reads one scene file. Throws CliError(kUsage) naming the file when it is unreadable or not a valid Scene
// (with protobuf's parser message).
v1::Scene read_scene_file(const std::filesystem::path& path);

// Reads a whole JobSpec (any job type). Throws CliError(kUsage) naming the file.
v1::JobSpec read_job_spec_file(const std::filesystem::path& path);

// The spec to submit: `options.spec` read from its file, or built from `options.isosurface` (cells default 128),
// then the output overrides (name, raw, normals, quantization bits) applied. Range checks of values are the
// server's (it answers INVALID_ARGUMENT naming the field).
v1::JobSpec build_job_spec(const JobOptions& options);

}  // namespace surfacer::client
