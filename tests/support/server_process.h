// The `surfacer-server` binary of this build as a child process on a loopback port.
#pragma once

#include <chrono>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "tests/support/process.h"

namespace surfacer::testing {

// `surfacer-server --listen 127.0.0.1:0 --port-file ... --workers WORKERS FLAGS...` (FLAGS e.g. {"--data-dir", d}),
// started in the constructor, which waits up to 30 s for the port. Its stdout and stderr go to files in `dir`
// (created if needed); several servers may run, one after another or at once, in one directory. With
// `file_size_limit` (bytes), writes past it fail with EFBIG: a full disk, as write() sees it (see ChildProcess).
// Killed (SIGKILL) on destruction if still running.
class ServerProcess {
 public:
  explicit ServerProcess(const std::filesystem::path& dir, int workers = 1, const std::vector<std::string>& flags = {},
                         std::optional<std::uint64_t> file_size_limit = std::nullopt);
  ~ServerProcess();
  ServerProcess(const ServerProcess&) = delete;
  ServerProcess& operator=(const ServerProcess&) = delete;

  // 0 when the server did not start (or exited) before writing its port.
  int port() const { return port_; }
  // "127.0.0.1:PORT", or empty when the server did not start.
  const std::string& address() const { return address_; }
  // Its stderr so far.
  std::string log() const;
  // Its peak resident set size so far, in bytes (ChildProcess::peak_rss_bytes); nullopt once stopped.
  std::optional<std::uint64_t> peak_rss_bytes() const;
  // Its resident set size now, in bytes (ChildProcess::resident_bytes); nullopt once stopped.
  std::optional<std::uint64_t> resident_bytes() const;
  // SIGKILL and wait (a crash: no drain, connections reset).
  void kill_now();
  // SIGTERM and wait: the exit code (0 for a clean drain), or -1 when it did not exit within `within` (it is then
  // killed). Once stopped or killed, returns the code it ended with.
  int stop(std::chrono::seconds within = std::chrono::seconds(10));

 private:
  std::unique_ptr<ChildProcess> child_;
  std::filesystem::path log_;
  int port_ = 0;
  std::string address_;
  int code_ = -1;
};

}  // namespace surfacer::testing
