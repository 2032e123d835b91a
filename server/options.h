// What a server is started with: its limits (also what every job runner checks a request against) and the rest of
// its options (the `surfacer-server` flags, server/main.cpp).
#pragma once

#include <chrono>
#include <cstdint>
#include <string>

namespace surfacer::server {

// Sizes beyond these answer RESOURCE_EXHAUSTED with a message naming the limit and the flag that raises it.
struct Limits {
  std::int64_t max_grid_cells = std::int64_t{1} << 30;    // --max-grid-cells (cells per frame)
  std::int64_t max_particles = 50'000'000;                // --max-particles (per frame)
  std::int64_t max_triangles = 50'000'000;                // --max-triangles (per frame)
  std::int64_t max_upload_bytes = std::int64_t{4} << 30;  // --max-upload-bytes (per upload)
  std::int64_t max_frames = 100'000;                      // --max-frames (per job)
  std::int64_t memory_budget_bytes = std::int64_t{4} << 30;  // --memory-budget (bytes, whole server)
};

struct ServerOptions {
  // host:port to listen on; port 0 picks a free port (see port()). Empty: in-process only.
  std::string listen = "127.0.0.1:50051";
  int workers = 0;           // job tasks run at once; 0 = hardware threads (server/worker_pool.h)
  int max_queued_jobs = 64;  // jobs waiting for a worker beyond this answer RESOURCE_EXHAUSTED
  Limits limits;
  // Finished jobs (and their frames) are kept this long after finishing, for WatchJob/GetJob (--retain-hours);
  // uploads no unfinished job uses are kept this long after arriving.
  std::chrono::seconds keep_finished = std::chrono::hours(24 * 7);
  // Beyond this many stored bytes (frames + uploads), the oldest finished jobs, then the oldest unused uploads,
  // are removed (--retain-bytes; 0 = no byte limit).
  std::int64_t retain_bytes = 0;
  // How often retention runs.
  std::chrono::milliseconds retention_interval = std::chrono::seconds(60);

  // WatchJob streams open at once on one job beyond this answer RESOURCE_EXHAUSTED (--max-watchers-per-job).
  int max_watchers_per_job = 32;
  // An upload whose next chunk does not arrive within this is ended (DEADLINE_EXCEEDED) and its bytes freed
  // (--upload-idle-timeout).
  std::chrono::milliseconds upload_idle_timeout = std::chrono::minutes(10);

  // Durable store (--data-dir): SQLite + files. Empty: memory only (jobs are lost on restart).
  std::string data_dir;

  // Security. TLS when both files are given; mutual TLS (client certificates required and verified) when
  // tls_client_ca_file is given too. Plain text is refused on a non-loopback address unless allow_insecure.
  std::string tls_cert_file;
  std::string tls_key_file;
  std::string tls_client_ca_file;
  bool allow_insecure = false;
  // Bearer tokens (lines `TOKEN TENANT [running=N] [bytes=N]`). Empty: no authentication (one shared tenant).
  std::string tokens_file;

  // Prometheus text metrics over HTTP at /metrics (--metrics-listen HOST:PORT). Empty: off.
  std::string metrics_listen;
  // A second, plain-text gRPC port serving only grpc.health.v1 (same status as the main port) for probes that
  // cannot speak TLS, such as Kubernetes' native gRPC probes (--health-listen HOST:PORT). Empty: off.
  std::string health_listen;
};

}  // namespace surfacer::server
