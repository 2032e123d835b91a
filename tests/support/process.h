// Child processes for end-to-end tests: the binaries of this build, a program run with its output in files, its
// exit code, and a free loopback port.
#pragma once

#include <sys/types.h>

#include <chrono>
#include <cstdint>
#include <filesystem>
#include <optional>
#include <ostream>
#include <string>
#include <vector>

namespace surfacer::testing {

std::filesystem::path cli_binary();     // <build>/client/surfacer
std::filesystem::path server_binary();  // <build>/server/surfacer-server

// args[0] (a path) run with `args`: stdin from /dev/null, stdout and stderr into the files `out` and `err`
// (truncated), the environment without SURFACER_SERVER (a developer's setting must not redirect a test's CLI).
// With `file_size_limit` (bytes) the child runs under that RLIMIT_FSIZE with SIGXFSZ ignored, so writes past it
// fail with EFBIG: a full disk, as write() sees it. Killed (SIGKILL) on destruction if still running.
class ChildProcess {
 public:
  ChildProcess(const std::vector<std::string>& args, const std::filesystem::path& out, const std::filesystem::path& err,
               std::optional<std::uint64_t> file_size_limit = std::nullopt);
  ~ChildProcess();
  ChildProcess(const ChildProcess&) = delete;
  ChildProcess& operator=(const ChildProcess&) = delete;

  // False when the program could not be run (or its output files not opened).
  bool started() const { return pid_ > 0; }
  const std::filesystem::path& out_path() const { return out_; }
  const std::filesystem::path& err_path() const { return err_; }

  // Sends `sig` unless the child has exited.
  void signal(int sig) const;
  // The exit code if the child has exited (128 + signal when a signal ended it), without waiting.
  std::optional<int> poll();
  // Exit code, 128 + signal when a signal ended it, or -1 after `timeout` (the child is then killed) or when it
  // never started.
  int wait(std::chrono::milliseconds timeout);
  // Peak resident set size in bytes: VmHWM while the child runs, its rusage once it has exited normally; nullopt
  // when it never started or was killed by wait()'s timeout.
  std::optional<std::uint64_t> peak_rss_bytes() const;
  // Resident set size now (VmRSS), in bytes; nullopt when the child is not running.
  std::optional<std::uint64_t> resident_bytes() const;

 private:
  pid_t pid_ = -1;
  bool exited_ = false;
  int code_ = -1;
  std::optional<std::uint64_t> peak_rss_;
  std::filesystem::path out_, err_;
};

struct ProcessResult {
  int code = -1;
  std::string out;
  std::string err;
  std::uint64_t peak_rss_bytes = 0;  // 0 when unknown
};

std::ostream& operator<<(std::ostream& os, const ProcessResult& r);

// Waits for `child` (see ChildProcess::wait) and reads its output files.
ProcessResult finish(ChildProcess& child, std::chrono::milliseconds timeout);

// Runs `args` to the end (killed after `timeout`) with stdout and stderr in `out` and `err`.
ProcessResult run_process(const std::vector<std::string>& args, const std::filesystem::path& out,
                          const std::filesystem::path& err, std::chrono::milliseconds timeout);

// A TCP port on 127.0.0.1 that nothing listened on a moment ago.
int free_port();

}  // namespace surfacer::testing
