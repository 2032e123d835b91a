#include "client/json_output.h"

#include <google/protobuf/util/time_util.h>

#include "client/job_state.h"
#include "client/rpc_error.h"
#include "client/summary.h"

namespace surfacer::client {
namespace {

void timestamp(JsonWriter& w, const google::protobuf::Timestamp& t) {
  if (t.seconds() == 0 && t.nanos() == 0) {
    w.null();
  } else {
    w.value(google::protobuf::util::TimeUtil::ToString(t));
  }
}

}  // namespace

void write_job_json(JsonWriter& w, const v1::Job& job) {
  w.begin_object();
  w.key("id").value(job.id());
  w.key("name").value(job.name());
  w.key("kind").value(job.kind());
  w.key("state").value(state_name(job.state()));
  w.key("frames_done").value(job.frames_done());
  w.key("frames_total").value(job.frames_total());
  w.key("progress").begin_object();
  w.key("stage").value(job.progress().stage());
  w.key("frame").value(job.progress().frame_index());
  w.key("fraction").value(job.progress().fraction());
  w.end_object();
  w.key("error");
  if (job.error().code() == 0 && job.error().message().empty()) {
    w.null();
  } else {
    w.begin_object();
    w.key("code").value(status_code_name(static_cast<grpc::StatusCode>(job.error().code())));
    w.key("message").value(job.error().message());
    w.end_object();
  }
  w.key("created");
  timestamp(w, job.created());
  w.key("started");
  timestamp(w, job.started());
  w.key("finished");
  timestamp(w, job.finished());
  w.end_object();
}

namespace {

void frame_fields(JsonWriter& w, int index, const v1::FrameStats& s) {
  w.key("index").value(index);
  w.key("vertices").value(static_cast<std::int64_t>(s.vertices()));
  w.key("triangles").value(static_cast<std::int64_t>(s.triangles()));
  w.key("closed").value(s.check().closed());
  w.key("manifold").value(s.check().edge_manifold() && s.check().vertex_manifold());
  w.key("components").value(s.check().components());
  w.key("iteration").value(s.iteration());
  double seconds = 0;
  for (const auto& t : s.timings()) seconds += t.seconds();
  w.key("seconds").value(seconds);
  w.key("timings").begin_object();
  for (const auto& t : s.timings()) w.key(t.stage()).value(t.seconds());
  w.end_object();
  const std::map<std::string, double> metrics(s.metrics().begin(), s.metrics().end());  // sorted keys
  w.key("metrics").begin_object();
  for (const auto& [name, value] : metrics) w.key(name).value(value);
  w.end_object();
}

}  // namespace

void write_frame_json(JsonWriter& w, int index, const v1::FrameStats& stats) {
  w.begin_object();
  frame_fields(w, index, stats);
  w.end_object();
}

std::string status_json(const v1::Job& job) {
  JsonWriter w;
  w.begin_object().key("job");
  write_job_json(w, job);
  w.end_object();
  return w.str();
}

std::string list_json(std::span<const v1::Job> jobs) {
  JsonWriter w;
  w.begin_object().key("jobs").begin_array();
  for (const auto& job : jobs) write_job_json(w, job);
  w.end_array().end_object();
  return w.str();
}

std::string run_summary_json(const RunSummary& summary) {
  JsonWriter w;
  w.begin_object().key("job");
  write_job_json(w, summary.job);
  w.key("output_dir").value(summary.output_dir.string());
  w.key("frames_written").value(static_cast<int>(summary.frames.size()));
  std::int64_t triangles = 0;
  for (const auto& [index, stats] : summary.frames) triangles += stats.triangles();
  w.key("triangles").value(triangles);
  w.key("wall_seconds").value(summary.wall_seconds);
  w.key("frames").begin_array();
  for (const auto& [index, stats] : summary.frames) {
    w.begin_object();
    frame_fields(w, index, stats);
    w.key("files").begin_array();
    if (const auto it = summary.files.find(index); it != summary.files.end()) {
      for (const auto& path : it->second) w.value(path.string());
    }
    w.end_array();
    w.end_object();
  }
  w.end_array();
  w.key("previews").begin_array();
  for (const auto& path : summary.previews) w.value(path.string());
  w.end_array();
  w.end_object();
  return w.str();
}

std::string state_event_json(const v1::Job& job, double time) {
  JsonWriter w;
  w.begin_object().key("event").value("state").key("time").value(time);
  w.key("job").value(job.id()).key("state").value(state_name(job.state()));
  w.key("frames_done").value(job.frames_done()).key("frames_total").value(job.frames_total());
  w.end_object();
  return w.str();
}

std::string progress_event_json(std::string_view job_id, const v1::Progress& progress, int frames_done,
                                int frames_total, std::optional<double> eta_seconds, double time) {
  JsonWriter w;
  w.begin_object().key("event").value("progress").key("time").value(time);
  w.key("job").value(job_id).key("stage").value(progress.stage()).key("frame").value(progress.frame_index());
  w.key("frames_done").value(frames_done).key("frames_total").value(frames_total);
  w.key("fraction").value(progress.fraction());
  w.key("eta_s");
  if (eta_seconds) {
    w.value(*eta_seconds);
  } else {
    w.null();
  }
  w.end_object();
  return w.str();
}

std::string frame_event_json(std::string_view job_id, const ReceivedFrame& frame, int frames_total, double time) {
  JsonWriter w;
  w.begin_object().key("event").value("frame").key("time").value(time);
  w.key("job").value(job_id).key("frames_total").value(frames_total).key("frame");
  write_frame_json(w, frame.index, frame.stats);
  w.end_object();
  return w.str();
}

std::string message_event_json(std::string_view text, double time) {
  JsonWriter w;
  w.begin_object().key("event").value("message").key("time").value(time).key("text").value(text).end_object();
  return w.str();
}

std::string error_event_json(int exit_code, std::string_view message) {
  JsonWriter w;
  w.begin_object().key("event").value("error").key("exit_code").value(exit_code).key("message").value(message);
  w.end_object();
  return w.str();
}

}  // namespace surfacer::client
