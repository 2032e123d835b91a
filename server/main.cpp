// surfacer-server: the Surfacer gRPC service on a port.
#include <CLI/CLI.hpp>
#include <chrono>
#include <csignal>
#include <cstdlib>
#include <fstream>
#include <iostream>
#include <thread>

#include "core/util/version.h"
#include "server/log.h"
#include "server/memory_budget.h"
#include "server/server.h"

using surfacer::server::LogLevel;
using surfacer::server::ServerOptions;
using surfacer::server::ShutdownMode;
using surfacer::server::SurfacerServer;

namespace {
// After a second SIGTERM/SIGINT the shutdown has this long to end before the process exits regardless, with
// kForcedExitCode.
constexpr std::chrono::milliseconds kSecondSignalGrace{2000};
constexpr int kForcedExitCode = 2;
// The smallest --memory-budget: room for a few uploads being received and watch streams at once.
constexpr std::int64_t kMinMemoryBudget = std::int64_t{64} << 20;
}  // namespace

int main(int argc, char** argv) {
  ServerOptions options;
  options.limits.memory_budget_bytes = surfacer::server::default_memory_budget();
  std::string port_file;
  double drain_seconds = 30.0;
  bool verbose = false;

  CLI::App app{
      "surfacer-server: turns implicit scenes and particle simulations into triangle meshes and streams them "
      "back frame by frame, Draco-compressed (gRPC service surfacer.v1.Surfacer, plus grpc.health.v1 and "
      "server reflection).\n\nExample:\n  surfacer-server --listen 0.0.0.0:50051 --workers 2\n"};
  app.add_option("--listen", options.listen, "host:port to listen on (port 0 picks a free port)")
      ->capture_default_str();
  app.add_option("--port-file", port_file, "write the bound port to this file once listening");
  app.add_option("--workers", options.workers,
                 "job tasks run at once (0 = hardware threads), on one pool of max(N, hardware) threads that also "
                 "runs their loops")
      ->capture_default_str();
  app.add_option("--max-queued-jobs", options.max_queued_jobs,
                 "jobs waiting for a worker beyond this are refused with RESOURCE_EXHAUSTED")
      ->capture_default_str();
  app.add_option("--max-grid-cells", options.limits.max_grid_cells, "largest grid (cells) a frame may use")
      ->capture_default_str();
  app.add_option("--max-particles", options.limits.max_particles, "most particles in one frame")->capture_default_str();
  app.add_option("--max-triangles", options.limits.max_triangles, "most triangles in one output frame")
      ->capture_default_str();
  app.add_option("--max-upload-bytes", options.limits.max_upload_bytes, "largest single upload, in bytes")
      ->capture_default_str();
  app.add_option("--max-frames", options.limits.max_frames, "most frames in one job")->capture_default_str();
  std::string memory_budget = std::to_string(options.limits.memory_budget_bytes);
  app.add_option("--memory-budget", memory_budget,
                 "memory, whole server, that uploads being received (and, without --data-dir, uploads kept) and "
                 "WatchJob streams' buffers may hold: bytes, or with K/M/G/T (6G, 512M); beyond it they are refused "
                 "with RESOURCE_EXHAUSTED (default: half the machine's RAM)")
      ->capture_default_str()
      ->check([](const std::string& text) -> std::string {
        std::int64_t bytes = 0;
        if (!surfacer::server::parse_byte_size(text, bytes)) {
          return "'" + text + "' is not a size: give bytes, or a number with K, M, G or T (6G, 512M)";
        }
        if (bytes < kMinMemoryBudget) {
          return text + " (" + std::to_string(bytes) + " bytes) is below the minimum of " +
                 std::to_string(kMinMemoryBudget) + " bytes (64M); the default is half the machine's RAM";
        }
        return {};
      });
  app.add_option("--max-watchers-per-job", options.max_watchers_per_job,
                 "WatchJob streams open at once on one job beyond this are refused with RESOURCE_EXHAUSTED")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  double upload_idle_seconds = std::chrono::duration<double>(options.upload_idle_timeout).count();
  app.add_option("--upload-idle-timeout", upload_idle_seconds,
                 "seconds an upload may wait for its next chunk; then it is ended (DEADLINE_EXCEEDED) and its "
                 "bytes are freed")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  bool memory_only = false;
  double retain_hours = 24.0 * 7;
  app.add_option("--data-dir", options.data_dir,
                 "durable store: SQLite database + frame/upload files in this directory; unfinished jobs resume "
                 "after a restart (default: none, memory only)");
  app.add_flag("--memory-only", memory_only, "keep jobs in memory only (lost on restart)")->excludes("--data-dir");
  app.add_option("--retain-hours", retain_hours, "keep finished jobs (and unused uploads) this long, then delete them")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  app.add_option("--retain-bytes", options.retain_bytes,
                 "when frames + uploads exceed this many bytes, delete the oldest finished jobs, then the oldest "
                 "unused uploads (0 = no limit)")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  app.add_option("--tls-cert", options.tls_cert_file, "server certificate chain (PEM); enables TLS with --tls-key")
      ->check(CLI::ExistingFile);
  app.add_option("--tls-key", options.tls_key_file, "server private key (PEM)")->check(CLI::ExistingFile);
  app.add_option("--tls-client-ca", options.tls_client_ca_file,
                 "CA bundle (PEM) for client certificates: mutual TLS, clients without a valid certificate are "
                 "refused")
      ->check(CLI::ExistingFile);
  app.add_flag("--allow-insecure", options.allow_insecure,
               "allow plain text on a non-loopback --listen address (e.g. behind a TLS-terminating mesh)");
  app.add_option("--tokens-file", options.tokens_file,
                 "bearer tokens, one per line: `TOKEN TENANT [running=N] [bytes=N]`; every RPC then needs "
                 "`authorization: Bearer TOKEN`, and each tenant sees only its own jobs")
      ->check(CLI::ExistingFile);
  app.add_option("--metrics-listen", options.metrics_listen,
                 "serve Prometheus text metrics at http://HOST:PORT/metrics (default: off)");
  app.add_option("--health-listen", options.health_listen,
                 "also serve grpc.health.v1 alone, in plain text, on HOST:PORT (for Kubernetes gRPC probes, which "
                 "cannot use TLS; it carries no job data)");
  app.add_option("--drain-seconds", drain_seconds,
                 "on SIGTERM/SIGINT, let running jobs finish this long before cancelling them (a second signal "
                 "cancels them at once, and exits within 2 s even if one does not stop)")
      ->capture_default_str();
  app.add_flag("-v,--verbose", verbose, "debug logs");
  app.set_version_flag("--version", "surfacer-server " + std::string(surfacer::build_version()),
                       "print the version and exit");
  CLI11_PARSE(app, argc, argv);
  if (verbose) surfacer::server::set_log_level(LogLevel::kDebug);
  options.keep_finished = std::chrono::seconds(static_cast<long long>(retain_hours * 3600.0));
  surfacer::server::parse_byte_size(memory_budget, options.limits.memory_budget_bytes);  // checked above
  options.upload_idle_timeout = std::chrono::milliseconds(static_cast<long long>(upload_idle_seconds * 1000.0));
  if (const std::int64_t ram = surfacer::server::physical_memory_bytes();
      ram > 0 && options.limits.memory_budget_bytes > ram) {
    surfacer::server::log_event(LogLevel::kWarn, "memory_budget",
                                {{"bytes", std::to_string(options.limits.memory_budget_bytes)},
                                 {"note", "above the machine's RAM (" + std::to_string(ram) +
                                              " bytes); the budget cannot keep the server within memory"}});
  }
  if (options.data_dir.empty() && !memory_only) {
    surfacer::server::log_event(LogLevel::kWarn, "memory_only",
                                {{"note", "jobs are lost on restart; give --data-dir for a durable store"}});
  }

  // Signals are taken by one thread with sigwait; every other thread blocks them.
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGINT);
  sigaddset(&signals, SIGTERM);
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);

  std::unique_ptr<SurfacerServer> server;
  try {
    server = SurfacerServer::start(options);
  } catch (const std::exception& e) {
    surfacer::server::log_event(LogLevel::kError, "start_failed", {{"error", e.what()}});
    return 1;
  }
  if (!port_file.empty()) {
    const std::string tmp = port_file + ".tmp";
    std::ofstream(tmp) << server->port() << "\n";
    std::rename(tmp.c_str(), port_file.c_str());
  }

  std::thread signal_thread([&] {
    int sig = 0;
    sigwait(&signals, &sig);
    surfacer::server::log_event(LogLevel::kInfo, "signal", {{"signal", sig == SIGTERM ? "SIGTERM" : "SIGINT"}});
    // The second signal cancels every job; the shutdown then normally ends within a fraction of a second. A job
    // that does not stop (or anything else that holds the shutdown) must not keep the process alive: after
    // kSecondSignalGrace it exits at once. Nothing is lost that a crash would keep: the store is crash-safe.
    std::thread second([&] {
      int again = 0;
      sigwait(&signals, &again);
      surfacer::server::log_event(
          LogLevel::kWarn, "signal_again",
          {{"action", "cancel running jobs; exit within " + std::to_string(kSecondSignalGrace.count()) + " ms"}});
      server->cancel_jobs("server shutting down (second signal)");
      std::this_thread::sleep_for(kSecondSignalGrace);
      surfacer::server::log_event(LogLevel::kError, "exit_forced",
                                  {{"reason", "the shutdown did not end after the second signal"}});
      std::_Exit(kForcedExitCode);
    });
    second.detach();
    server->shutdown(ShutdownMode::kDrain, std::chrono::milliseconds(static_cast<long long>(drain_seconds * 1000.0)));
  });
  server->wait();
  signal_thread.join();
  return 0;
}
