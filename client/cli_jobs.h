// The job-type subcommands of `surfacer run` and `surfacer submit` (isosurface, particles, optimize,
// active coat|morph|advect): their flags, help and examples, and the checks that turn parsed flags into JobOptions.
// Internal to the CLI (cli.cpp); the value parsers are exposed for tests.
#pragma once

#include <CLI/CLI.hpp>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "client/options.h"
#include "client/run_report.h"

namespace surfacer::client {

inline constexpr const char* kGlobalNote =
    "Global options (--server HOST:PORT[,HOST:PORT...], --local, --workers N, --timeout S, -v, --token/--token-file, "
    "--tls, --tls-ca/--tls-cert/--tls-key/--tls-server-name, --allow-insecure) may also be given after the "
    "subcommand; see `surfacer --help`.\n";

// Output flags of `run` and `watch`: -o DIR, --format LIST, and how they report (--progress, --json, --preview).
struct OutputFlags {
  std::optional<std::string> dir;
  std::vector<std::string> formats;
  double vdb_voxel_size = 0.0;
  ReportFlags report;
};

// What CLI11 writes into for one `run` or `submit` command and its job-type subcommands. The job's option fields go
// straight into job.spec (client/job_fields.h), its inputs into the paths below.
struct JobFlags {
  JobOptions job;  // --spec, --name, the output fields, and every job-type field the flags set

  std::vector<std::filesystem::path> scenes;  // isosurface --scene (repeated)
  std::filesystem::path scene;                // optimize and advect --scene
  std::filesystem::path from;                 // morph
  std::filesystem::path to;
  ParticleInputOptions particle_inputs;  // particles and coat --input, --start, --end
  bool enright = false;
  std::optional<std::filesystem::path> velocity_grid;

  CLI::App* isosurface = nullptr;
  CLI::App* particles_app = nullptr;
  CLI::App* optimize_app = nullptr;
  CLI::App* active_app = nullptr;
  CLI::App* coat_app = nullptr;
  CLI::App* morph_app = nullptr;
  CLI::App* advect_app = nullptr;
};

void add_output_flags(CLI::App* app, OutputFlags& flags);
// --name, --raw, --normals, --quantization-bits.
void add_job_common_flags(CLI::App* app, JobOptions& job);

// Adds isosurface, particles, optimize and active (with coat, morph, advect) under `parent` (`run` or `submit`,
// named by `verb`). `output` is null for `submit` (no output flags).
void add_job_types(CLI::App* parent, const std::string& verb, JobFlags& flags, OutputFlags* output);

// The job to submit, after the checks CLI11 cannot express (exactly one job; inputs that need or exclude each other)
// and the server's own check of the options (wire::check_job_options). Throws CliError(kUsage) naming the flag.
JobOptions finish_job(JobFlags& flags, const std::string& verb);

}  // namespace surfacer::client
