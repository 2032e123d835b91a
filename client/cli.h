// Command-line parsing of the `surfacer` CLI and the whole program (main() only calls run_cli()).
#pragma once

#include <iosfwd>
#include <variant>

#include "client/exit_codes.h"
#include "client/options.h"

namespace surfacer::client {

// Parses argv (argv[0] is the program name). `env_server` is $SURFACER_SERVER (may be null): used when neither
// --server nor --local is given; `env_token` is $SURFACER_TOKEN (may be null): used with a remote server when
// neither --token nor --token-file is given. Files named by --token-file and --tls-* are read here. Returns the
// invocation, or the exit code when parsing ends the program: --help printed to `out` (kSuccess) or a usage error
// printed to `err` as "surfacer: error: ..." (kUsage).
std::variant<Invocation, ExitCode> parse_command_line(int argc, const char* const* argv, std::ostream& out,
                                                      std::ostream& err, const char* env_server,
                                                      const char* env_token = nullptr);

// The whole program: parse, run, print errors as "surfacer: error: ...". Returns the process exit code.
int run_cli(int argc, const char* const* argv);

}  // namespace surfacer::client
