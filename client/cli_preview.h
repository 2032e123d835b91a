// The `surfacer preview` subcommand: its flags, help and the checks that turn them into a PreviewCommand.
#pragma once

#include <CLI/CLI.hpp>
#include <optional>
#include <string>
#include <vector>

#include "client/options.h"

namespace surfacer::client {

struct PreviewFlags {
  std::vector<std::string> frames;
  std::optional<std::string> dir;
  std::string size = "480x360";
  PreviewOptions options;
  std::vector<std::string> particles;
  std::optional<std::string> iterations;
};

CLI::App* add_preview_command(CLI::App& app, PreviewFlags& flags);
// Throws CliError(kUsage) naming the flag: no output directory, nothing to picture, a bad --size, particle files
// that do not exist.
PreviewCommand finish_preview(const PreviewFlags& flags);

}  // namespace surfacer::client
