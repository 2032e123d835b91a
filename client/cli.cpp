#include "client/cli.h"

#include <grpc/support/log.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <iostream>
#include <sstream>
#include <string>
#include <vector>

#include "client/cli_jobs.h"
#include "client/cli_preview.h"
#include "client/commands.h"
#include "client/json_output.h"
#include "client/output_files.h"
#include "client/security.h"
#include "client/server_list.h"
#include "core/util/version.h"

namespace surfacer::client {
namespace {

void drop_grpc_log(gpr_log_func_args*) {}

void print_grpc_log(gpr_log_func_args* args) {
  std::fprintf(stderr, "surfacer: grpc: %s (%s:%d)\n", args->message, args->file, args->line);
}

// Edit distance (insertions, deletions, substitutions, adjacent transpositions) between two short words.
std::size_t edit_distance(const std::string& a, const std::string& b) {
  std::vector<std::vector<std::size_t>> d(a.size() + 1, std::vector<std::size_t>(b.size() + 1));
  for (std::size_t i = 0; i <= a.size(); ++i) d[i][0] = i;
  for (std::size_t j = 0; j <= b.size(); ++j) d[0][j] = j;
  for (std::size_t i = 1; i <= a.size(); ++i) {
    for (std::size_t j = 1; j <= b.size(); ++j) {
      d[i][j] = std::min({d[i - 1][j] + 1, d[i][j - 1] + 1, d[i - 1][j - 1] + (a[i - 1] == b[j - 1] ? 0 : 1)});
      if (i > 1 && j > 1 && a[i - 1] == b[j - 2] && a[i - 2] == b[j - 1])
        d[i][j] = std::min(d[i][j], d[i - 2][j - 2] + 1);
    }
  }
  return d[a.size()][b.size()];
}

// "; did you mean --cells?" for the words of `message` (CLI11's "The following arguments were not expected: ...")
// that are close to a flag or a subcommand of the deepest command parsed so far; empty when none is.
std::string suggestion(const CLI::App& app, const std::string& message) {
  const CLI::App* deepest = &app;
  for (bool deeper = true; deeper;) {
    deeper = false;
    for (const CLI::App* sub : deepest->get_subcommands([](const CLI::App*) { return true; })) {
      if (sub->parsed()) {
        deepest = sub;
        deeper = true;
        break;
      }
    }
  }
  std::vector<std::string> known;
  for (const CLI::Option* option : deepest->get_options()) {
    for (const std::string& name : option->get_lnames()) known.push_back("--" + name);
  }
  for (const CLI::App* sub : deepest->get_subcommands([](const CLI::App*) { return true; })) {
    known.push_back(sub->get_name());
  }
  const std::string marker = "not expected: ";
  const std::size_t at = message.find(marker);
  if (at == std::string::npos) return "";
  std::string out;
  std::istringstream words(message.substr(at + marker.size()));
  for (std::string word; words >> word;) {
    const std::string stem = word.substr(0, word.find('='));
    const std::string* best = nullptr;
    std::size_t best_distance = std::max<std::size_t>(2, stem.size() / 4) + 1;
    for (const std::string& name : known) {
      if (stem.starts_with("-") != name.starts_with("-")) continue;  // flags for flags, subcommands for words
      const std::size_t distance = edit_distance(stem, name);
      if (distance < best_distance) {
        best_distance = distance;
        best = &name;
      }
    }
    if (best != nullptr && *best != stem) out += (out.empty() ? "; did you mean " : ", or ") + *best + " for " + stem;
  }
  return out.empty() ? "" : out + "?";
}

FrameOutputOptions finish_output(const OutputFlags& flags, const std::string& command) {
  FrameOutputOptions options = frame_output_options(flags.dir.value_or(""), flags.formats, command);
  options.vdb_voxel_size = flags.vdb_voxel_size;
  return options;
}

}  // namespace

std::variant<Invocation, ExitCode> parse_command_line(int argc, const char* const* argv, std::ostream& out,
                                                      std::ostream& err, const char* env_server,
                                                      const char* env_token) {
  CLI::App app(
      "surfacer: turn implicit scenes and particle simulations into meshes on a Surfacer server, frame by frame",
      "surfacer");
  app.fallthrough();  // global options may follow the subcommand
  app.require_subcommand(1);
  app.footer(std::string("Examples:\n"
                         "  surfacer run isosurface --scene examples/scenes/sphere.json --cells 64 -o out/\n"
                         "  surfacer --server localhost:50051 run --spec job.json -o out/ --format ply,obj\n"
                         "  ID=$(surfacer --server localhost:50051 submit isosurface --scene a.json --scene b.json)\n"
                         "  surfacer --server localhost:50051 watch $ID -o out/\n"
                         "  surfacer --server a:50051,b:50051,c:50051 run isosurface --scene s1.json --scene s2.json "
                         "-o out/\n"
                         "  surfacer --server surfacer.example.com:443 --tls --token-file ~/.surfacer-token list\n"
                         "\n"
                         "Environment:\n"
                         "  SURFACER_SERVER  host:port used when neither --server nor --local is given\n"
                         "  SURFACER_TOKEN   bearer token used when neither --token nor --token-file is given\n"
                         "\n") +
             kExitCodesHelp);

  ConnectOptions connect;
  std::optional<std::string> server;
  CLI::Option* server_opt =
      app.add_option("--server", server,
                     "host:port of a Surfacer server (default: $SURFACER_SERVER, else --local); for `run`, a "
                     "comma-separated list a:1,b:2,c:3 or dns:///NAME:PORT with several addresses splits frame "
                     "sequences across the servers")
          ->type_name("HOST:PORT");
  bool local = false;
  app.add_flag("--local", local,
               "run an in-process server for this command only (the default without --server and "
               "$SURFACER_SERVER)")
      ->excludes(server_opt);
  app.add_option("--workers", connect.workers,
                 "worker threads of the in-process server (0: one per core); a remote server's are set where it "
                 "runs (surfacer-server --workers)")
      ->check(CLI::NonNegativeNumber)
      ->type_name("N");
  app.add_option("--timeout", connect.timeout_seconds,
                 "seconds to wait for the server connection (default 10); with several servers, also how long a "
                 "lost server may take to come back before its frames go to the others")
      ->check(CLI::PositiveNumber)
      ->type_name("S");
  app.set_version_flag("--version", "surfacer " + std::string(build_version()), "print the version and exit");
  app.add_flag("-v,--verbose", connect.verbose,
               "more lines: with several servers, which server produced each frame and every sub-job; gRPC's own "
               "log lines");

  SecurityFlags security;
  CLI::Option* token_opt =
      app.add_option("--token", security.token,
                     "bearer token sent with every call as \"authorization: Bearer TOKEN\" (default: "
                     "$SURFACER_TOKEN)")
          ->type_name("TOKEN");
  app.add_option("--token-file", security.token_file, "read the bearer token from FILE (one line)")
      ->excludes(token_opt)
      ->type_name("FILE");
  app.add_flag("--tls", security.tls, "connect with TLS, checking the server's certificate against the system roots");
  app.add_option("--tls-ca", security.tls_ca, "connect with TLS, trusting the CA certificate(s) in FILE (PEM)")
      ->type_name("FILE");
  app.add_option("--tls-cert", security.tls_cert, "client certificate (PEM) for servers that require mutual TLS")
      ->type_name("FILE");
  app.add_option("--tls-key", security.tls_key, "private key (PEM) of --tls-cert")->type_name("FILE");
  app.add_option("--tls-server-name", security.tls_server_name,
                 "name to check the server's certificate against instead of the host in --server (for IP "
                 "addresses and tests)")
      ->type_name("NAME");
  app.add_flag("--allow-insecure", security.allow_insecure,
               "allow sending the token without TLS to a host that is not loopback (trusted networks only)");

  // run
  JobFlags run_flags;
  OutputFlags run_output;
  CLI::App* run = app.add_subcommand("run", "Submit a job, watch it, and write its frames as they arrive");
  run->add_option("--spec", run_flags.job.spec_file, "a whole surfacer.v1.JobSpec in protobuf JSON (any job type)")
      ->type_name("FILE");
  add_job_common_flags(run, run_flags.job);
  add_output_flags(run, run_output);
  run->require_subcommand(0, 1);
  run->footer(
      std::string("Examples:\n"
                  "  surfacer run isosurface --scene examples/scenes/torus.json --cells 96 -o out/\n"
                  "  surfacer run particles --input 'sim/fluid_{:04d}.bgeo' --r-inner 0.01 -o out/\n"
                  "  surfacer run optimize --scene examples/scenes/csg_block.json --iterations 100 -o out/\n"
                  "  surfacer run active morph --from a.json --to b.json --grid-spacing 0.02 -o out/\n"
                  "  surfacer run --spec job.json -o out/ --format drc,ply\n"
                  "Inputs (meshes, velocity grids) are uploaded before the job is queued; a particle sequence's "
                  "frames\njoin the job as they are uploaded, each surfaced as soon as it lands.\n"
                  "Ctrl-C cancels the job on the server and exits with code 5.\n"
                  "With several servers (--server a:1,b:2,c:3 or dns:///NAME:PORT), a frame sequence (isosurface "
                  "scenes,\nparticle frames) is split into small batches across them; a server that dies "
                  "hands its frames to\nthe others. Other jobs run on the first server that answers and move "
                  "to the next one if it dies.\n\n") +
      kGlobalNote + "\n" + kExitCodesHelp);
  add_job_types(run, "run", run_flags, &run_output);

  // submit
  JobFlags submit_flags;
  CLI::App* submit = app.add_subcommand("submit", "Submit a job, print its id and exit (fetch frames with `watch`)");
  submit
      ->add_option("--spec", submit_flags.job.spec_file, "a whole surfacer.v1.JobSpec in protobuf JSON (any job type)")
      ->type_name("FILE");
  add_job_common_flags(submit, submit_flags.job);
  submit->require_subcommand(0, 1);
  submit->footer(std::string("Example:\n"
                             "  ID=$(surfacer --server localhost:50051 submit isosurface --scene a.json --cells 64)\n"
                             "  surfacer --server localhost:50051 watch $ID -o out/\n\n") +
                 kGlobalNote);
  add_job_types(submit, "submit", submit_flags, nullptr);

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
  status->add_flag("--json", status_cmd.json, "print {\"job\": {...}} as one JSON document (stable keys)");
  status->footer(std::string("Example:\n  surfacer --server localhost:50051 status j-3f2a\n\n") + kGlobalNote);

  // list
  ListCommand list_cmd;
  CLI::App* list = app.add_subcommand("list", "List the server's jobs (id, state, frames, kind, name)");
  list->add_option("--state", list_cmd.states, "only jobs in these states, comma-separated")
      ->delimiter(',')
      ->check(CLI::IsMember({"queued", "running", "succeeded", "failed", "cancelled"}))
      ->type_name("LIST");
  list->add_flag("--json", list_cmd.json, "print {\"jobs\": [...]} as one JSON document (stable keys)");
  list->footer(std::string("Example:\n  surfacer --server localhost:50051 list --state queued,running\n\n") +
               kGlobalNote);

  // cancel
  CancelCommand cancel_cmd;
  CLI::App* cancel = app.add_subcommand("cancel", "Cancel a job (cancelling a finished job is not an error)");
  cancel->add_option("job_id", cancel_cmd.job_id, "job id")->required()->type_name("JOB_ID");
  cancel->footer(std::string("Example:\n  surfacer --server localhost:50051 cancel j-3f2a\n\n") + kGlobalNote);

  // preview
  PreviewFlags preview_flags;
  CLI::App* preview = add_preview_command(app, preview_flags);

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
    if (connect.server && (is_server_list(*connect.server) || is_dns_name(*connect.server))) {
      if (is_server_list(*connect.server)) parse_server_list(*connect.server);  // syntax errors now
      if (is_server_list(*connect.server) && !run->parsed()) {
        throw CliError(ExitCode::kUsage,
                       "a list of servers (" + *connect.server +
                           ") is for `run`, which splits a job across them; give one --server HOST:PORT for this "
                           "command");
      }
    }
    if (connect.server) check_server_ports(*connect.server);
    check_workers(connect);
    connect.security = load_security(security, env_token, connect.server.has_value());

    Invocation invocation{connect, HealthCommand{}};
    if (run->parsed()) {
      invocation.command =
          RunCommand{finish_job(run_flags, "run"), finish_output(run_output, "run"), finish_report(run_output.report)};
    } else if (submit->parsed()) {
      invocation.command = SubmitCommand{finish_job(submit_flags, "submit")};
    } else if (watch->parsed()) {
      watch_cmd.output = finish_output(watch_output, "watch");
      watch_cmd.report = finish_report(watch_output.report);
      invocation.command = watch_cmd;
    } else if (status->parsed()) {
      invocation.command = status_cmd;
    } else if (list->parsed()) {
      invocation.command = list_cmd;
    } else if (cancel->parsed()) {
      invocation.command = cancel_cmd;
    } else if (health->parsed()) {
      invocation.command = health_cmd;
    } else if (preview->parsed()) {
      invocation.command = finish_preview(preview_flags);
    }
    return invocation;
  } catch (const CLI::CallForHelp&) {
    out << app.help();
    return ExitCode::kSuccess;
  } catch (const CLI::CallForAllHelp&) {
    out << app.help("", CLI::AppFormatMode::All);
    return ExitCode::kSuccess;
  } catch (const CLI::CallForVersion& e) {
    out << e.what() << "\n";
    return ExitCode::kSuccess;
  } catch (const CLI::ParseError& e) {
    std::string message = e.what();
    for (const JobFlags* flags : {&run_flags, &submit_flags}) {
      if (flags->active_app->parsed() && !flags->coat_app->parsed() && !flags->morph_app->parsed() &&
          !flags->advect_app->parsed()) {
        message =
            "active needs a mode: coat, morph or advect, e.g. `surfacer run active morph --from a.json --to "
            "b.json --grid-spacing 0.02 -o out/` (" +
            message + ")";
      }
    }
    message += suggestion(app, message);
    err << "surfacer: error: " << message << "\nRun `surfacer --help` or `surfacer COMMAND --help` for usage.\n";
    return ExitCode::kUsage;
  } catch (const CliError& e) {
    err << "surfacer: error: " << e.what() << "\n";
    return e.code();
  }
}

int run_cli(int argc, const char* const* argv) {
  // gRPC logs its own lines ("E1124 ... ssl_transport_security.cc:...") about failures the CLI reports itself, with
  // its exit code; they reach the user only with -v.
  gpr_set_log_function(drop_grpc_log);
  auto parsed = parse_command_line(argc, argv, std::cout, std::cerr, std::getenv("SURFACER_SERVER"),
                                   std::getenv("SURFACER_TOKEN"));
  if (const ExitCode* code = std::get_if<ExitCode>(&parsed)) return to_int(*code);
  if (std::get<Invocation>(parsed).connect.verbose) gpr_set_log_function(print_grpc_log);
  // With --progress json, stderr stays one JSON object per line: the error too.
  const bool json_errors = std::visit(
      [](const auto& command) {
        using T = std::decay_t<decltype(command)>;
        if constexpr (std::is_same_v<T, RunCommand> || std::is_same_v<T, WatchCommand>) {
          return command.report.progress == ProgressFormat::kJson;
        }
        return false;
      },
      std::get<Invocation>(parsed).command);
  const auto print_error = [&](ExitCode code, const std::string& message) {
    std::cout.flush();
    if (json_errors) {
      std::cerr << error_event_json(to_int(code), message) << "\n";
    } else {
      std::cerr << "surfacer: error: " << message << "\n";
    }
  };
  ExitCode code = ExitCode::kInternal;
  try {
    code = run_invocation(std::get<Invocation>(parsed), std::cout, std::cerr, isatty(STDERR_FILENO) != 0);
  } catch (const CliError& e) {
    code = e.code();
    print_error(code, e.what());
  } catch (const std::exception& e) {
    code = ExitCode::kInternal;
    print_error(code, std::string("internal error: ") + e.what());
  } catch (...) {
    code = ExitCode::kInternal;
    print_error(code, "internal error (unknown exception)");
  }
  std::cout.flush();
  return to_int(code);
}

}  // namespace surfacer::client
