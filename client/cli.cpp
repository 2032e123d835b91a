#include "client/cli.h"

#include <unistd.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <charconv>
#include <cstdlib>
#include <iostream>
#include <string>

#include "client/commands.h"

namespace surfacer::client {
namespace {

constexpr const char* kGlobalNote =
    "Global options (--server HOST:PORT, --local, --workers N, --timeout S) may also be given after the subcommand; "
    "see `surfacer --help`.\n";

// Variables CLI11 writes into for one `run` or `submit` subcommand.
struct JobFlags {
  JobOptions job;
  IsosurfaceOptions iso;
  std::optional<std::string> bounds;
  CLI::App* isosurface = nullptr;
};

struct OutputFlags {
  std::optional<std::string> dir;
  std::vector<std::string> formats;
};

void add_output_flags(CLI::App* app, OutputFlags& flags) {
  app->add_option("-o,--output", flags.dir, "directory for frame_NNNN.<ext> files and stats.csv (created)")
      ->type_name("DIR");
  app->add_option("--format", flags.formats,
                  "files per frame, comma-separated: drc,ply,obj (default: the frame's encoding: .drc, or .ply with "
                  "--raw)")
      ->delimiter(',')
      ->check(CLI::IsMember({"drc", "ply", "obj"}))
      ->type_name("LIST");
}

void add_job_common_flags(CLI::App* app, JobOptions& job) {
  app->add_option("--name", job.name, "free text shown by `surfacer list` (default: the first scene's file name)");
  app->add_flag("--raw", job.raw, "lossless frames: binary PLY with double-precision positions instead of Draco");
  app->add_flag("--normals", job.normals, "per-vertex normals (from the field gradient) in every frame");
  app->add_option("--quantization-bits", job.quantization_bits,
                  "Draco position quantization, 1..30 bits (server default 14)")
      ->check(CLI::Range(1, 30))
      ->type_name("B");
}

CLI::App* add_isosurface(CLI::App* parent, JobFlags& flags, OutputFlags* output, const std::string& example) {
  CLI::App* iso = parent->add_subcommand("isosurface", "Polygonize the surface f = 0 of one or more scenes");
  iso->add_option("--scene", flags.iso.scenes,
                  "scene file (protobuf JSON of surfacer.v1.Scene); repeat for a sequence, one frame per scene")
      ->required()
      ->type_name("FILE");
  CLI::Option* cells =
      iso->add_option("--cells", flags.iso.cells, "cells along the longest axis of the bounds (default 128)")
          ->check(CLI::PositiveNumber)
          ->type_name("N");
  iso->add_option("--cell-size", flags.iso.cell_size, "edge of a cubic cell, in scene units")
      ->check(CLI::PositiveNumber)
      ->excludes(cells)
      ->type_name("H");
  iso->add_option("--bounds", flags.bounds,
                  "region to polygonize: x0,y0,z0,x1,y1,z1 (default: the scenes' own bounds, padded by two cells)")
      ->type_name("BOX");
  iso->add_option("--method", flags.iso.method, "polygonizer: cubes (Marching Cubes; the default)")
      ->check(CLI::IsMember({"cubes"}))
      ->type_name("NAME");
  add_job_common_flags(iso, flags.job);
  if (output != nullptr) add_output_flags(iso, *output);
  iso->footer(std::string("Example:\n  ") + example + "\n\n" + kGlobalNote);
  flags.isosurface = iso;
  return iso;
}

std::array<double, 6> parse_bounds(const std::string& text) {
  std::array<double, 6> values{};
  std::size_t count = 0;
  std::size_t pos = 0;
  while (true) {
    std::size_t comma = text.find(',', pos);
    std::string item = text.substr(pos, comma == std::string::npos ? std::string::npos : comma - pos);
    double value = 0;
    auto [end, ec] = std::from_chars(item.data(), item.data() + item.size(), value);
    if (item.empty() || ec != std::errc() || end != item.data() + item.size() || count == 6) {
      throw CliError(ExitCode::kUsage, "--bounds \"" + text +
                                           "\" must be six comma-separated numbers x0,y0,z0,x1,y1,z1, e.g. "
                                           "--bounds=-1,-1,-1,1,1,1");
    }
    values[count++] = value;
    if (comma == std::string::npos) break;
    pos = comma + 1;
  }
  if (count != 6) {
    throw CliError(ExitCode::kUsage, "--bounds \"" + text + "\" has " + std::to_string(count) +
                                         " numbers; it needs six: x0,y0,z0,x1,y1,z1");
  }
  const char* axes = "xyz";
  for (int i = 0; i < 3; ++i) {
    if (!(values[i] < values[i + 3])) {
      throw CliError(ExitCode::kUsage, std::string("--bounds: the minimum ") + axes[i] + " (" +
                                           std::to_string(values[i]) + ") must be below the maximum " + axes[i] + " (" +
                                           std::to_string(values[i + 3]) + ")");
    }
  }
  return values;
}

std::vector<FileFormat> parse_formats(const std::vector<std::string>& names) {
  std::vector<FileFormat> formats;
  for (const std::string& name : names) {
    FileFormat f = name == "drc" ? FileFormat::kDrc : name == "ply" ? FileFormat::kPly : FileFormat::kObj;
    if (std::find(formats.begin(), formats.end(), f) == formats.end()) formats.push_back(f);
  }
  return formats;
}

JobOptions finish_job(JobFlags& flags, const std::string& command) {
  JobOptions job = flags.job;
  const bool has_type = flags.isosurface->parsed();
  if (job.spec && has_type) {
    throw CliError(ExitCode::kUsage, command + ": give either --spec FILE or a job type (isosurface), not both");
  }
  if (!job.spec && !has_type) {
    throw CliError(ExitCode::kUsage, command + " needs a job: `surfacer " + command +
                                         " isosurface --scene FILE ...` or `surfacer " + command + " --spec job.json`");
  }
  if (job.raw && job.quantization_bits) {
    throw CliError(ExitCode::kUsage,
                   "--quantization-bits applies to Draco frames; --raw frames are lossless PLY: drop one of them");
  }
  if (has_type) {
    IsosurfaceOptions iso = flags.iso;
    if (flags.bounds) iso.bounds = parse_bounds(*flags.bounds);
    job.isosurface = iso;
  }
  return job;
}

FrameOutputOptions finish_output(const OutputFlags& flags, const std::string& command) {
  if (!flags.dir || flags.dir->empty()) {
    throw CliError(ExitCode::kUsage, command + " needs an output directory: -o DIR");
  }
  return FrameOutputOptions{*flags.dir, parse_formats(flags.formats)};
}

}  // namespace

std::variant<Invocation, ExitCode> parse_command_line(int argc, const char* const* argv, std::ostream& out,
                                                      std::ostream& err, const char* env_server) {
  CLI::App app("surfacer: polygonize implicit scenes on a Surfacer server and fetch the meshes frame by frame",
               "surfacer");
  app.fallthrough();  // global options may follow the subcommand
  app.require_subcommand(1);
  app.footer(std::string("Examples:\n"
                         "  surfacer run isosurface --scene examples/scenes/sphere.json --cells 64 -o out/\n"
                         "  surfacer --server localhost:50051 run --spec job.json -o out/ --format ply,obj\n"
                         "  ID=$(surfacer --server localhost:50051 submit isosurface --scene a.json --scene b.json)\n"
                         "  surfacer --server localhost:50051 watch $ID -o out/\n"
                         "\n"
                         "Environment:\n"
                         "  SURFACER_SERVER  host:port used when neither --server nor --local is given\n"
                         "\n") +
             kExitCodesHelp);

  ConnectOptions connect;
  std::optional<std::string> server;
  CLI::Option* server_opt =
      app.add_option("--server", server, "host:port of a Surfacer server (default: $SURFACER_SERVER, else --local)")
          ->type_name("HOST:PORT");
  bool local = false;
  app.add_flag("--local", local,
               "run an in-process server for this command only (the default without --server and "
               "$SURFACER_SERVER)")
      ->excludes(server_opt);
  app.add_option("--workers", connect.workers,
                 "worker threads of the in-process server (0: one per core; ignored with --server)")
      ->check(CLI::NonNegativeNumber)
      ->type_name("N");
  app.add_option("--timeout", connect.timeout_seconds, "seconds to wait for the server connection (default 10)")
      ->check(CLI::PositiveNumber)
      ->type_name("S");

  // run
  JobFlags run_flags;
  OutputFlags run_output;
  CLI::App* run = app.add_subcommand("run", "Submit a job, watch it, and write its frames as they arrive");
  run->add_option("--spec", run_flags.job.spec, "a whole surfacer.v1.JobSpec in protobuf JSON (any job type)")
      ->type_name("FILE");
  add_job_common_flags(run, run_flags.job);
  add_output_flags(run, run_output);
  run->require_subcommand(0, 1);
  run->footer(std::string("Examples:\n"
                          "  surfacer run isosurface --scene examples/scenes/torus.json --cells 96 -o out/\n"
                          "  surfacer run --spec job.json -o out/ --format drc,ply\n"
                          "Ctrl-C cancels the job on the server and exits with code 5.\n\n") +
              kGlobalNote + "\n" + kExitCodesHelp);
  add_isosurface(run, run_flags, &run_output,
                 "surfacer run isosurface --scene a.json --scene b.json --cells 64 --bounds=-2,-2,-2,2,2,2 -o out/ "
                 "--format drc,ply");

  // submit
  JobFlags submit_flags;
  CLI::App* submit = app.add_subcommand("submit", "Submit a job, print its id and exit (fetch frames with `watch`)");
  submit->add_option("--spec", submit_flags.job.spec, "a whole surfacer.v1.JobSpec in protobuf JSON (any job type)")
      ->type_name("FILE");
  add_job_common_flags(submit, submit_flags.job);
  submit->require_subcommand(0, 1);
  submit->footer(std::string("Example:\n"
                             "  ID=$(surfacer --server localhost:50051 submit isosurface --scene a.json --cells 64)\n"
                             "  surfacer --server localhost:50051 watch $ID -o out/\n\n") +
                 kGlobalNote);
  add_isosurface(submit, submit_flags, nullptr,
                 "surfacer --server localhost:50051 submit isosurface --scene a.json --scene b.json --cells 64");

  // watch
  WatchCommand watch_cmd;
  OutputFlags watch_output;
  CLI::App* watch = app.add_subcommand("watch", "Follow a job and write its frames (all finished ones first)");
  watch->add_option("job_id", watch_cmd.job_id, "job id printed by `submit`")->required()->type_name("JOB_ID");
  watch->add_option("--from-frame", watch_cmd.from_frame, "first frame index to fetch (default 0)")
      ->check(CLI::NonNegativeNumber)
      ->type_name("K");
  add_output_flags(watch, watch_output);
  watch->footer(std::string("Example:\n  surfacer --server localhost:50051 watch j-3f2a --from-frame 1 -o out/\n\n") +
                kGlobalNote);

  // status
  StatusCommand status_cmd;
  CLI::App* status = app.add_subcommand("status", "Print a job's state, frames done/total, progress and error");
  status->add_option("job_id", status_cmd.job_id, "job id")->required()->type_name("JOB_ID");
  status->footer(std::string("Example:\n  surfacer --server localhost:50051 status j-3f2a\n\n") + kGlobalNote);

  // list
  ListCommand list_cmd;
  CLI::App* list = app.add_subcommand("list", "List the server's jobs (id, state, frames, kind, name)");
  list->add_option("--state", list_cmd.states, "only jobs in these states, comma-separated")
      ->delimiter(',')
      ->check(CLI::IsMember({"queued", "running", "succeeded", "failed", "cancelled"}))
      ->type_name("LIST");
  list->footer(std::string("Example:\n  surfacer --server localhost:50051 list --state queued,running\n\n") +
               kGlobalNote);

  // cancel
  CancelCommand cancel_cmd;
  CLI::App* cancel = app.add_subcommand("cancel", "Cancel a job (cancelling a finished job is not an error)");
  cancel->add_option("job_id", cancel_cmd.job_id, "job id")->required()->type_name("JOB_ID");
  cancel->footer(std::string("Example:\n  surfacer --server localhost:50051 cancel j-3f2a\n\n") + kGlobalNote);

  // health
  HealthCommand health_cmd;
  CLI::App* health = app.add_subcommand("health", "Ask the server's grpc.health.v1 service; prints SERVING or not");
  health->add_option("--service", health_cmd.service, "service name to check (default \"\": the whole server)");
  health->footer(std::string("Example:\n  surfacer --server localhost:50051 health   # prints SERVING, exit 0\n"
                             "Exit 0 when SERVING, 3 when unreachable or not serving.\n\n") +
                 kGlobalNote);

  try {
    app.parse(argc, argv);

    if (local) {
      connect.server.reset();
    } else if (server) {
      if (server->empty()) throw CliError(ExitCode::kUsage, "--server needs host:port, e.g. localhost:50051");
      connect.server = server;
    } else if (env_server != nullptr && *env_server != '\0') {
      connect.server = std::string(env_server);
    }

    Invocation invocation{connect, HealthCommand{}};
    if (run->parsed()) {
      invocation.command = RunCommand{finish_job(run_flags, "run"), finish_output(run_output, "run")};
    } else if (submit->parsed()) {
      invocation.command = SubmitCommand{finish_job(submit_flags, "submit")};
    } else if (watch->parsed()) {
      watch_cmd.output = finish_output(watch_output, "watch");
      invocation.command = watch_cmd;
    } else if (status->parsed()) {
      invocation.command = status_cmd;
    } else if (list->parsed()) {
      invocation.command = list_cmd;
    } else if (cancel->parsed()) {
      invocation.command = cancel_cmd;
    } else if (health->parsed()) {
      invocation.command = health_cmd;
    }
    return invocation;
  } catch (const CLI::CallForHelp&) {
    out << app.help();
    return ExitCode::kSuccess;
  } catch (const CLI::CallForAllHelp&) {
    out << app.help("", CLI::AppFormatMode::All);
    return ExitCode::kSuccess;
  } catch (const CLI::ParseError& e) {
    err << "surfacer: error: " << e.what() << "\nRun `surfacer --help` or `surfacer COMMAND --help` for usage.\n";
    return ExitCode::kUsage;
  } catch (const CliError& e) {
    err << "surfacer: error: " << e.what() << "\n";
    return e.code();
  }
}

int run_cli(int argc, const char* const* argv) {
  auto parsed = parse_command_line(argc, argv, std::cout, std::cerr, std::getenv("SURFACER_SERVER"));
  if (const ExitCode* code = std::get_if<ExitCode>(&parsed)) return to_int(*code);
  ExitCode code = ExitCode::kInternal;
  try {
    code = run_invocation(std::get<Invocation>(parsed), std::cout, std::cerr, isatty(STDERR_FILENO) != 0);
  } catch (const CliError& e) {
    std::cout.flush();
    std::cerr << "surfacer: error: " << e.what() << "\n";
    code = e.code();
  } catch (const std::exception& e) {
    std::cout.flush();
    std::cerr << "surfacer: error: internal error: " << e.what() << "\n";
    code = ExitCode::kInternal;
  } catch (...) {
    std::cerr << "surfacer: error: internal error (unknown exception)\n";
    code = ExitCode::kInternal;
  }
  std::cout.flush();
  return to_int(code);
}

}  // namespace surfacer::client
