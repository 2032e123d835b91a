// A minimal HTTP/1.1 endpoint for Prometheus scrapes and HTTP health probes, on plain POSIX sockets and one
// background thread (poll() over the listening socket and every open connection, so a slow or idle client never
// blocks the others).
//
//   GET|HEAD /metrics  200, MetricsRegistry::render() as `text/plain; version=0.0.4; charset=utf-8`
//                      (500 with the error text if a callback throws)
//   GET|HEAD /healthz  200 "ok", or 503 "unavailable" while options.healthy() returns false
//   other paths        404;  other methods 405 (with `Allow: GET, HEAD`)
//   malformed request  400;  request head over max_request_bytes 431
//   head not complete within read_timeout: one attempt to send 408, then the connection is closed
//
// Every response closes the connection (`Connection: close`). The query string is ignored. The request head is parsed
// by server/http_request_head.h.
//
// Idle clients cannot lock scrapes out: a connection holds its slot at most read_timeout before its request head is
// complete, and a new connection is never refused: when its peer address already holds max_connections_per_peer
// connections, or the server holds max_connections, one of that peer's (or of all) is closed for it: an answered one
// still lingering, else the request being read that has gone longest without a byte (a connection that has just been
// accepted and has sent nothing yet is fresh: it is a client about to send), else the oldest being answered.
//
// Why not prometheus-cpp's pull Exposer (civetweb), which would replace this file: civetweb serves each connection on
// one of its num_threads worker threads (2 by default in Exposer) for as long as the connection stays open, up to its
// request_timeout_ms, and has no bound per peer, so a client holding a few idle connections locks every scrape out:
// the case the per-peer bound above exists for. Exposer also serves registered collectables only, so /healthz with its
// 503 while draining would need a second HTTP server. What this server sends is prometheus-cpp's text (render()).
#pragma once

#include <atomic>
#include <chrono>
#include <cstddef>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <string_view>
#include <thread>

#include "server/metrics.h"

namespace surfacer::server {

struct MetricsHttpOptions {
  // The whole request head (request line and headers) must arrive within this time of accepting the connection
  // (a scraper sends it at once).
  std::chrono::milliseconds read_timeout{2000};
  // A response not fully sent within this time is abandoned (the connection is closed).
  std::chrono::milliseconds write_timeout{10000};
  // Larger request heads answer 431.
  std::size_t max_request_bytes = 8192;
  // Open connections, in all and from one peer address (any port); a new one beyond either closes an older one (see
  // above). >= 1 each.
  int max_connections = 64;
  int max_connections_per_peer = 8;
  // /healthz answers 503 while this returns false (e.g. while draining). Empty: always healthy. Called on the
  // server thread; must be thread-safe and fast.
  std::function<bool()> healthy;
};

class MetricsHttpServer {
 public:
  // Binds `address` and starts serving `registry`, which must outlive the server. Address forms: "127.0.0.1:9090",
  // "0.0.0.0:9090", "localhost:9090", "[::1]:9090", "[::]:9090"; port 0 picks a free port (see port()). Throws
  // std::runtime_error naming the address when it is malformed, cannot be resolved or cannot be bound.
  static std::unique_ptr<MetricsHttpServer> start(const MetricsRegistry& registry, std::string_view address,
                                                  MetricsHttpOptions options = {});
  // Stops the server (see stop()).
  ~MetricsHttpServer();

  MetricsHttpServer(const MetricsHttpServer&) = delete;
  MetricsHttpServer& operator=(const MetricsHttpServer&) = delete;

  // The bound port.
  int port() const { return port_; }
  // The bound address, e.g. "127.0.0.1:40123" or "[::1]:40123".
  const std::string& address() const { return address_; }

  // Closes the listening socket and every open connection and joins the thread; returns within milliseconds even
  // while clients hold connections open. Idempotent; safe from any thread but the server's own.
  void stop();

 private:
  MetricsHttpServer(const MetricsRegistry& registry, MetricsHttpOptions options);
  void run();
  // The complete response to one request head (request line and headers, ending with the blank line).
  std::string respond(std::string_view head) const;

  const MetricsRegistry& registry_;
  const MetricsHttpOptions options_;
  int listen_fd_ = -1;
  int wake_read_fd_ = -1;  // a pipe: stop() writes a byte to interrupt poll()
  int wake_write_fd_ = -1;
  int port_ = 0;
  std::string address_;
  std::atomic<bool> stopping_{false};
  std::mutex stop_mutex_;
  std::thread thread_;
};

}  // namespace surfacer::server
