// The CLI's machine-readable output: one JSON document per `status --json`, `list --json` and `run/watch --json`
// (stdout), and one JSON object per line for `--progress json` (stderr). Keys are stable: new keys may be added,
// none renamed or removed. Written with core/util/json.h.
//
// A job:   {"id", "name", "kind", "state" ("QUEUED" ... "CANCELLED"), "frames_done", "frames_total",
//           "progress": {"stage", "frame", "fraction"}, "error": null | {"code" ("INVALID_ARGUMENT"), "message"},
//           "created", "started", "finished" (RFC 3339 UTC, or null)}
// A frame: {"index", "vertices", "triangles", "closed", "manifold", "components", "iteration", "seconds" (server time,
//           the stages summed), "timings": {stage: seconds}, "metrics": {name: value}}
// Events (--progress json), each with "event" and "time" (seconds since the command started):
//   {"event": "state", "job", "state", "frames_done", "frames_total"}
//   {"event": "progress", "job", "stage", "frame", "frames_done", "frames_total", "fraction", "eta_s" (null until
//    it can be estimated)}
//   {"event": "frame", "job", "frames_total", "frame": <a frame>}
//   {"event": "message", "text"}   (what the text display prints as a line: uploads, reconnects, the summary)
//   {"event": "error", "exit_code", "message"}  (the command's last line when it fails)
#pragma once

#include <filesystem>
#include <map>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "client/frame_assembler.h"
#include "core/util/json.h"
#include "surfacer/v1/surfacer.pb.h"

namespace surfacer::client {

void write_job_json(JsonWriter& w, const v1::Job& job);
void write_frame_json(JsonWriter& w, int index, const v1::FrameStats& stats);

// `status --json`: {"job": <a job>}.
std::string status_json(const v1::Job& job);
// `list --json`: {"jobs": [<a job>, ...]} (oldest first).
std::string list_json(std::span<const v1::Job> jobs);

// `run --json` / `watch --json`: {"job": <a job> (its final state), "output_dir", "frames_written", "triangles",
// "wall_seconds", "frames": [<a frame> + "files": [paths]], "previews": [paths of PNGs, when --preview]}.
struct RunSummary {
  v1::Job job;
  std::filesystem::path output_dir;
  std::map<int, v1::FrameStats> frames;
  std::map<int, std::vector<std::filesystem::path>> files;
  double wall_seconds = 0;
  std::vector<std::filesystem::path> previews;
};
std::string run_summary_json(const RunSummary& summary);

// --progress json lines (without the newline). `time`: seconds since the command started.
std::string state_event_json(const v1::Job& job, double time);
std::string progress_event_json(std::string_view job_id, const v1::Progress& progress, int frames_done,
                                int frames_total, std::optional<double> eta_seconds, double time);
std::string frame_event_json(std::string_view job_id, const ReceivedFrame& frame, int frames_total, double time);
std::string message_event_json(std::string_view text, double time);
std::string error_event_json(int exit_code, std::string_view message);

}  // namespace surfacer::client
