// The `surfacer` command line parsed in-process (parse_command_line), with what it printed.
#pragma once

#include <string>
#include <variant>
#include <vector>

#include "client/cli.h"

namespace surfacer::testing {

struct ParsedCli {
  std::variant<client::Invocation, client::ExitCode> result;
  std::string out;
  std::string err;
};

// Parses `surfacer ARGS...`; `env_server` and `env_token` stand for $SURFACER_SERVER and $SURFACER_TOKEN.
ParsedCli parse_cli(std::vector<std::string> args, const char* env_server = nullptr, const char* env_token = nullptr);

// The exit code parsing ended with, or kSuccess when it gave an invocation.
client::ExitCode exit_code_of(const ParsedCli& parsed);

}  // namespace surfacer::testing
