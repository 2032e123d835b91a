// How `run` and `watch` report beyond the frame files: where progress goes and in which form (--progress), the
// summary as JSON on stdout (--json), and pictures of the frames (--preview).
#pragma once

#include <CLI/CLI.hpp>
#include <chrono>
#include <iosfwd>
#include <string>

#include "client/frame_writer.h"
#include "client/options.h"
#include "client/progress.h"
#include "surfacer/v1/surfacer.pb.h"

namespace surfacer::client {

// The streams of a command and how it reports.
struct ReportSink {
  std::ostream& out;  // results: the --json summary
  std::ostream& err;  // progress and messages
  ProgressMode progress;
  ReportOptions options;
};

// Adds --progress, --json and --preview to `app` (`run`, each of its job types, `watch`).
struct ReportFlags {
  std::string progress = "auto";
  bool json = false;
  bool preview = false;
};
void add_report_flags(CLI::App* app, ReportFlags& flags);
ReportOptions finish_report(const ReportFlags& flags);

// Called once the watched job has ended, before its exit code is decided: with --preview (and the job SUCCEEDED),
// renders DIR/preview/<frame>.png for every frame written, from one camera, and DIR/preview/iterations.png when
// the run wrote iterations.csv; with --json, prints the summary (client/json_output.h) on `sink.out`, whatever the
// job's state. Throws CliError(kUsage) when a picture cannot be written.
void report_run(const v1::Job& job, const FrameWriter& writer, const ReportSink& sink, ProgressDisplay& progress,
                std::chrono::steady_clock::time_point start);

}  // namespace surfacer::client
