#include "tests/support/cli_parse.h"

#include <sstream>

namespace surfacer::testing {

ParsedCli parse_cli(std::vector<std::string> args, const char* env_server, const char* env_token) {
  args.insert(args.begin(), "surfacer");
  std::vector<const char*> argv;
  for (const auto& a : args) argv.push_back(a.c_str());
  std::ostringstream out, err;
  ParsedCli p{client::parse_command_line(static_cast<int>(argv.size()), argv.data(), out, err, env_server, env_token),
              "", ""};
  p.out = out.str();
  p.err = err.str();
  return p;
}

client::ExitCode exit_code_of(const ParsedCli& parsed) {
  return std::holds_alternative<client::ExitCode>(parsed.result) ? std::get<client::ExitCode>(parsed.result)
                                                                 : client::ExitCode::kSuccess;
}

}  // namespace surfacer::testing
