// Runs a parsed invocation against a server: run, submit, watch, status, list, cancel, health.
#pragma once

#include <iosfwd>

#include "client/exit_codes.h"
#include "client/options.h"

namespace surfacer::client {

// Connects (remote or in-process), runs the command and returns its exit code. Results go to `out` (job ids,
// status, lists), progress, warnings and the summary to `err`; `tty` selects the in-place progress bar.
// Throws CliError for every failure (its code is the exit code).
ExitCode run_invocation(const Invocation& invocation, std::ostream& out, std::ostream& err, bool tty);

}  // namespace surfacer::client
