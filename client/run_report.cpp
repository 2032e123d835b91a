#include "client/run_report.h"

#include <ostream>

#include "client/json_output.h"
#include "client/preview.h"

namespace surfacer::client {
namespace {

namespace fs = std::filesystem;

// The file of a frame to picture: the welded PLY if written, else OBJ, else the Draco file (all exact for a
// picture; PLY and OBJ need no decode).
std::optional<fs::path> picture_source(const std::vector<fs::path>& files) {
  for (const char* ext : {".ply", ".obj", ".drc"}) {
    for (const fs::path& f : files) {
      if (f.extension() == ext) return f;
    }
  }
  return std::nullopt;
}

}  // namespace

void add_report_flags(CLI::App* app, ReportFlags& flags) {
  app->add_option("--progress", flags.progress,
                  "progress on stderr: auto (a bar on a terminal, plain lines otherwise) or json (one JSON object "
                  "per line: state, progress with frame, stage, fraction and ETA, frame, message, error)")
      ->check(CLI::IsMember({"auto", "json"}))
      ->type_name("FORMAT");
  app->add_flag("--json", flags.json,
                "print the summary as one JSON document on stdout (the job's final state, every frame's figures "
                "and files, the previews)");
  app->add_flag("--preview", flags.preview,
                "once the job succeeded, render a shaded PNG of every frame from one camera into DIR/preview/ "
                "(and, for optimize, iterations.png: e_d and e_n per iteration); see `surfacer preview`");
}

ReportOptions finish_report(const ReportFlags& flags) {
  ReportOptions options;
  options.progress = flags.progress == "json" ? ProgressFormat::kJson : ProgressFormat::kAuto;
  options.json = flags.json;
  options.preview = flags.preview;
  return options;
}

void report_run(const v1::Job& job, const FrameWriter& writer, const ReportSink& sink, ProgressDisplay& progress,
                std::chrono::steady_clock::time_point start) {
  std::vector<fs::path> previews;
  if (sink.options.preview && job.state() == v1::JOB_STATE_SUCCEEDED && writer.frames_written() > 0) {
    std::vector<fs::path> sources;
    for (const auto& [index, files] : writer.files()) {
      if (const auto source = picture_source(files)) sources.push_back(*source);
    }
    const fs::path dir = writer.dir() / "preview";
    if (!sources.empty()) previews = render_frame_previews(sources, dir, PreviewOptions{});
    if (writer.wrote_iterations()) {
      previews.push_back(render_iterations_plot(writer.dir() / "iterations.csv", dir, PreviewOptions{}));
    }
    progress.line("previews in " + dir.string() + " (" + std::to_string(previews.size()) + " PNG" +
                  (previews.size() == 1 ? "" : "s") + ")");
  }
  if (sink.options.json) {
    RunSummary summary;
    summary.job = job;
    summary.output_dir = writer.dir();
    summary.frames = writer.stats();
    summary.files = writer.files();
    summary.wall_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    summary.previews = previews;
    sink.out << run_summary_json(summary) << "\n" << std::flush;
  }
}

}  // namespace surfacer::client
