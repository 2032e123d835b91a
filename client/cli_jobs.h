// The job-type subcommands of `surfacer run` and `surfacer submit` (isosurface, particles, optimize,
// active coat|morph|advect): their flags, help and examples, and the checks that turn parsed flags into JobOptions.
// Internal to the CLI (cli.cpp); the value parsers are exposed for tests.
#pragma once

#include <CLI/CLI.hpp>
#include <array>
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
  ReportFlags report;
};

// Variables CLI11 writes into for one `run` or `submit` command and its job-type subcommands.
struct JobFlags {
  JobOptions job;  // --spec and the output overrides

  IsosurfaceOptions iso;
  std::optional<std::string> iso_bounds;

  ParticlesOptions particles;
  std::optional<std::string> sweeps;
  std::optional<std::string> container_box;

  OptimizeOptions optimize;
  std::optional<std::string> start_bounds;
  std::optional<std::string> flows;

  ActiveOptions active;  // the parameters every mode shares; `mode` is filled by finish_job()
  std::optional<std::string> active_bounds;
  ActiveCoatOptions coat;
  ActiveMorphOptions morph;
  ActiveAdvectOptions advect;
  bool enright = false;
  std::optional<std::string> velocity_grid;
  std::optional<std::string> velocity_origin;
  std::optional<std::string> velocity_spacing;
  std::optional<std::string> velocity_dims;

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

// The job to submit, after the checks CLI11 cannot express (exactly one job; flags that need or exclude each other;
// list values). Throws CliError(kUsage) naming the flag.
JobOptions finish_job(JobFlags& flags, const std::string& verb);

// "1,2,3" -> numbers; CliError(kUsage) naming `flag` unless there are exactly `count` of them.
std::vector<double> parse_numbers(const std::string& text, std::size_t count, const std::string& flag,
                                  const std::string& example);
// x0,y0,z0,x1,y1,z1 with min < max on every axis.
Box parse_box(const std::string& text, const std::string& flag);
// "5,15,5" -> Laplacian, Bilaplacian and polish sweep counts (integers >= 0).
std::array<int, 3> parse_sweeps(const std::string& text);
// "d,n" -> the flows on (the others off); at least one of d, n, t.
FlowSet parse_flows(const std::string& text);

}  // namespace surfacer::client
