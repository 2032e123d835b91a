// Exit codes of the `surfacer` CLI (documented in `surfacer --help`) and the one error type commands throw.
#pragma once

#include <optional>
#include <stdexcept>
#include <string>

namespace surfacer::client {

enum class ExitCode : int {
  kSuccess = 0,
  kInternal = 1,     // an unexpected error inside the CLI (a bug)
  kUsage = 2,        // bad flags, unreadable or malformed scene/spec file, unwritable output directory
  kUnreachable = 3,  // no server at the address (within --timeout), connection lost for good, or not SERVING
  kJobFailed = 4,    // the job failed, or the server rejected the request (status code name and message printed)
  kCancelled = 5,    // the job was cancelled (Ctrl-C during `run`, or `surfacer cancel` from elsewhere)
  kIntegrity = 6,    // a frame failed its CRC-32 / size / chunk-count checks, or the event stream broke the protocol
};

inline int to_int(ExitCode code) { return static_cast<int>(code); }

// The text of `surfacer --help` that lists the codes above.
inline constexpr const char* kExitCodesHelp =
    "Exit codes:\n"
    "  0  success\n"
    "  1  unexpected internal error (a bug in the CLI)\n"
    "  2  usage error: bad flags, unreadable or malformed scene/spec file, unwritable output directory\n"
    "  3  server unreachable (nothing at --server within --timeout, connection lost, or health not SERVING)\n"
    "  4  job failed, or the server rejected the request (the status code and the server's message are printed)\n"
    "  5  job cancelled (Ctrl-C during `run`, or `surfacer cancel`)\n"
    "  6  frame integrity error (CRC-32, size or chunk count mismatch, or a protocol violation)\n";

// Thrown by every client function that ends the command; main() prints "surfacer: error: <what()>" and exits
// with `code()`. An error that is a server's answer also keeps its gRPC status code (a grpc::StatusCode value; the
// Python package raises it as `.code`).
class CliError : public std::runtime_error {
 public:
  CliError(ExitCode code, const std::string& message, std::optional<int> status_code = std::nullopt)
      : std::runtime_error(message), code_(code), status_code_(status_code) {}
  ExitCode code() const { return code_; }
  const std::optional<int>& status_code() const { return status_code_; }

 private:
  ExitCode code_;
  std::optional<int> status_code_;
};

}  // namespace surfacer::client
