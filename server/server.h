// The Surfacer gRPC server: a callback service over a worker pool, jobs kept in memory or in the durable store
// (--data-dir). Used by the `surfacer-server` binary, by the in-process server (server/in_process.h) and by tests.
// Header kept light: gRPC types are only forward-declared.
#pragma once

#include <chrono>
#include <memory>
#include <string>

#include "server/options.h"

namespace grpc {
class Channel;
}

namespace surfacer::server {

enum class ShutdownMode {
  kDrain,   // finish running and queued jobs (up to the deadline, then cancel)
  kCancel,  // cancel running and queued jobs now
};

class SurfacerServer {
 public:
  // Builds and starts the server (health and reflection services included). Throws std::runtime_error when the
  // address cannot be bound.
  static std::unique_ptr<SurfacerServer> start(const ServerOptions& options);
  ~SurfacerServer();

  SurfacerServer(const SurfacerServer&) = delete;
  SurfacerServer& operator=(const SurfacerServer&) = delete;

  // Port actually bound (0 when in-process only).
  int port() const;
  // Port of the plain-text health listener (0 when off).
  int health_port() const;
  // Port of the metrics endpoint (0 when off).
  int metrics_port() const;
  // The metrics in Prometheus text format (what /metrics serves).
  std::string metrics_text() const;
  // Runs retention now (tests; it also runs every retention_interval).
  void run_retention();
  // A channel to this server that does not touch the network.
  std::shared_ptr<grpc::Channel> in_process_channel();
  // Stops accepting new jobs (health turns NOT_SERVING), then drains or cancels, then stops the gRPC server.
  // Safe to call more than once and from any thread except a gRPC callback.
  void shutdown(ShutdownMode mode, std::chrono::milliseconds deadline = std::chrono::seconds(30));
  // Cancels every queued and running job (the server keeps serving). A drain in progress then ends at once.
  void cancel_jobs(const std::string& reason);
  // Blocks until shutdown() has completed.
  void wait();

 private:
  struct Impl;
  explicit SurfacerServer(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace surfacer::server
