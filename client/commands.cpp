#include "client/commands.h"

#include <grpcpp/client_context.h>

#include <algorithm>
#include <atomic>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <iomanip>
#include <map>
#include <mutex>
#include <optional>
#include <ostream>
#include <sstream>

#include "client/connection.h"
#include "client/frame_writer.h"
#include "client/health.h"
#include "client/interrupt.h"
#include "client/job_spec.h"
#include "client/json_output.h"
#include "client/output_files.h"
#include "client/preview.h"
#include "client/progress.h"
#include "client/run_report.h"
#include "client/scale_out.h"
#include "client/security.h"
#include "client/server_list.h"
#include "client/summary.h"
#include "client/upload.h"
#include "client/watch.h"
#include "core/util/format.h"

namespace surfacer::client {
namespace {

// An RPC error answered by the server (not a transport failure).
template <typename Request, typename Response>
Response call(Connection& connection, const std::string& what,
              grpc::Status (v1::Surfacer::Stub::*method)(grpc::ClientContext*, const Request&, Response*),
              const Request& request) {
  grpc::ClientContext context;
  context.set_deadline(connection.unary_deadline());
  Response response;
  const grpc::Status status = (connection.stub().*method)(&context, request, &response);
  if (!status.ok()) throw rpc_error(what, status);
  return response;
}

void warn_local(const Connection& connection, std::ostream& err) {
  if (connection.local()) {
    err << "surfacer: warning: using an in-process server (no --server and $SURFACER_SERVER unset); its jobs "
           "disappear when this command exits\n";
  }
}

std::string dir_text(const std::filesystem::path& dir) {
  std::string text = dir.string();
  if (!text.empty() && text.back() != '/') text += '/';
  return text;
}

std::string summary(const WatchResult& result, const FrameWriter& writer, std::chrono::steady_clock::time_point start) {
  return "wrote " + std::to_string(result.frames_written) + " frame" + (result.frames_written == 1 ? "" : "s") +
         " to " + dir_text(writer.dir()) + " (" + std::to_string(result.triangles) + " triangles, " +
         elapsed_text(start) + ")";
}

// The job kind a spec submits ("isosurface", ...), as the server names it in Job.kind.
std::string kind_of(const v1::JobSpec& spec) {
  switch (spec.kind_case()) {
    case v1::JobSpec::kIsosurface:
      return "isosurface";
    case v1::JobSpec::kParticles:
      return "particles";
    case v1::JobSpec::kOptimize:
      return "optimize";
    case v1::JobSpec::kActive:
      return "active";
    default:
      return "";
  }
}

// The exit code of a watched job's terminal state; prints the summary (and, for particles jobs, the table of
// frames; `uploaded` holds the particle counts this client uploaded, by frame).
ExitCode finish_watch(const WatchResult& result, const FrameWriter& writer, ProgressDisplay& progress,
                      std::chrono::steady_clock::time_point start, bool cancelled_here, const ReportSink& sink,
                      const std::map<int, std::int64_t>& uploaded = {}) {
  progress.clear();
  progress.line(summary(result, writer, start));
  if (writer.wrote_iterations()) {
    progress.line("per-iteration figures in " + (writer.dir() / "iterations.csv").string());
  }
  const v1::Job& job = result.job;
  if (job.kind() == "particles" && writer.frames_written() > 0) {
    const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    std::string table = particles_summary_table(writer.stats(), uploaded, wall);
    if (!table.empty() && table.back() == '\n') table.pop_back();
    progress.line(table);
  }
  report_run(job, writer, sink, progress, start);
  switch (job.state()) {
    case v1::JOB_STATE_SUCCEEDED:
      return ExitCode::kSuccess;
    case v1::JOB_STATE_CANCELLED: {
      std::string reason = job_error_text(job);
      throw CliError(ExitCode::kCancelled, "job " + job.id() + " was cancelled" +
                                               (cancelled_here ? std::string(" (interrupted)") : std::string()) +
                                               (reason.empty() ? "" : ": " + reason));
    }
    default: {
      std::string reason = job_error_text(job);
      throw CliError(ExitCode::kJobFailed,
                     "job " + job.id() + " failed" + (reason.empty() ? std::string() : ": " + reason));
    }
  }
}

// A job queued by queue_job(): its id and the job as queued, and whether it is an open sequence (then `uploaded` is
// what uploading its first frame gave, and the feeder uploads the others).
struct QueuedJob {
  std::string id;
  v1::Job job;
  bool open = false;
  UploadSummary uploaded;
};

// Uploads what goes before SubmitJob and submits: every input, or for a sequence that goes as an open one
// (streams_as_open_sequence) its first frame only, after every frame was read once (pin_particles_from_inputs: a bad
// file fails here, before any job is queued, and the quantization box is the whole sequence's).
// CliError(kCancelled) when `stop` fires before the job is submitted.
QueuedJob queue_job(Connection& connection, PreparedJob& prepared, ProgressDisplay& progress,
                    const std::atomic<bool>* stop) {
  QueuedJob queued;
  queued.open = streams_as_open_sequence(connection, prepared.spec, prepared.uploads);
  if (queued.open) pin_particles_from_inputs(prepared, input_limits(connection));
  queued.uploaded =
      upload_inputs(connection, prepared.spec, prepared.uploads, progress, stop, queued.open ? 1 : SIZE_MAX);
  if (stop != nullptr && stop->load()) {
    throw CliError(ExitCode::kCancelled, "interrupted before the job was submitted");
  }
  queued.id = submit_job(connection, queued.open ? open_sequence_spec(prepared.spec) : prepared.spec, &queued.job);
  return queued;
}

// `run` against one server (or the in-process one).
ExitCode run_single(const ConnectOptions& connect, PreparedJob prepared, const FrameOutputOptions& output,
                    const ReportSink& sink, ReconnectPolicy policy = {}) {
  const auto start = std::chrono::steady_clock::now();
  v1::JobSpec& spec = prepared.spec;
  FrameWriter writer(output);
  writer.set_job_kind(kind_of(spec));
  auto connection = Connection::open(connect);
  ProgressDisplay progress(sink.err, sink.progress);

  std::mutex mutex;
  std::string job_id;
  JobWatcher* watcher = nullptr;
  std::atomic<bool> interrupted{false};
  InterruptHandler interrupts([&](int count) {
    std::lock_guard lock(mutex);
    interrupted = true;
    if (count == 1 && !job_id.empty()) {
      progress.line("interrupted: cancelling job " + job_id + " (Ctrl-C again to stop waiting)");
      if (cancel_job(*connection, job_id)) return;
      progress.line("could not reach the server to cancel job " + job_id);
    }
    if (watcher != nullptr) watcher->stop();
  });

  // Inputs are read and uploaded one at a time; a bad file stops here, before any job is queued. A particle sequence
  // goes as an open one where the server takes it: submitted with its first frame, the others uploaded while the
  // server surfaces the earlier ones (SequenceFeeder; docs/ALGORITHMS.md §5, "Open sequences").
  const QueuedJob queued = queue_job(*connection, prepared, progress, &interrupted);
  const bool open_sequence = queued.open;
  UploadSummary uploaded = queued.uploaded;
  const v1::Job& job = queued.job;
  const std::string& id = queued.id;
  {
    std::lock_guard lock(mutex);
    job_id = id;
  }
  if (interrupted) {  // Ctrl-C while submitting
    cancel_job(*connection, id);
    throw CliError(ExitCode::kCancelled, "interrupted: job " + id + " cancelled");
  }
  std::optional<SequenceFeeder> feeder;
  std::string frames;
  if (open_sequence) {
    feeder.emplace(*connection, id, spec, prepared.uploads, uploaded, progress, &interrupted);
    frames = " (" + std::to_string(prepared.uploads.size()) + " frames, the rest uploaded while it runs)";
  } else if (job.frames_total() > 0) {
    frames = " (" + std::to_string(job.frames_total()) + " frame" + (job.frames_total() == 1 ? "" : "s") + ")";
  }
  progress.line("submitted job " + id + frames + " to " + connection->describe());

  JobWatcher job_watcher(*connection, id, 0, writer, progress, policy);
  {
    std::lock_guard lock(mutex);
    watcher = &job_watcher;
  }
  WatchResult result;
  try {
    result = job_watcher.run();
  } catch (const CliError& e) {
    {
      std::lock_guard lock(mutex);
      watcher = nullptr;
    }
    // We started the job and are abandoning it: do not leave it running.
    if (e.code() != ExitCode::kUnreachable && !interrupted) cancel_job(*connection, id);
    if (interrupted) throw CliError(ExitCode::kCancelled, "interrupted: stopped watching job " + id);
    throw;
  }
  {
    std::lock_guard lock(mutex);
    watcher = nullptr;
  }
  if (feeder) {
    // A frame that could not be read or uploaded failed the job: its error is the one to report.
    if (result.job.state() != v1::JOB_STATE_SUCCEEDED) feeder->stop();
    uploaded = feeder->finish();
  }
  return finish_watch(result, writer, progress, start, interrupted, sink, uploaded.particles);
}

// A job that is not a frame sequence, with several servers: the whole job on the first server that answers,
// resubmitted from scratch to the next one when that server becomes unreachable (connection lost for --timeout).
ExitCode run_failover(const ConnectOptions& connect, const std::vector<std::string>& servers,
                      const PreparedJob& prepared, const FrameOutputOptions& output, const ReportSink& sink) {
  const std::string dns_name = connect.server ? dns_host(*connect.server) : "";
  for (const std::string& server : servers) check_token_transport(server, connect.security);
  ReconnectPolicy policy;
  policy.budget = std::chrono::milliseconds(static_cast<long long>(std::llround(connect.timeout_seconds * 1000)));
  std::string failures;
  for (std::size_t i = 0; i < servers.size(); ++i) {
    ConnectOptions one = connect;
    one.server = servers[i];
    if (!dns_name.empty() && one.security.tls && !one.security.server_name) one.security.server_name = dns_name;
    try {
      return run_single(one, prepared, output, sink, policy);
    } catch (const CliError& e) {
      if (e.code() != ExitCode::kUnreachable) throw;
      failures += "\n  " + servers[i] + ": " + e.what();
      if (i + 1 < servers.size()) {
        ProgressDisplay(sink.err, sink.progress)
            .line("server " + servers[i] + " is unreachable, leaving it out: " + e.what() +
                  "\nresubmitting the whole job to " + servers[i + 1] + " (from scratch)");
      }
    }
  }
  throw CliError(ExitCode::kUnreachable, "every server is unreachable:" + failures);
}

ExitCode run_run(const ConnectOptions& connect, const RunCommand& run, const ReportSink& sink) {
  PreparedJob prepared = prepare_job(run.job);  // usage errors before connecting
  RunCommand command = run;
  command.output.frame_numbers = prepared.frame_numbers;  // output names keep the input files' frame numbers
  check_one_file(command.output, frames_before_run(prepared.spec));
  fit_encoding_to_files(prepared.spec, command.output.formats);
  if (connect.server && (is_server_list(*connect.server) || is_dns_name(*connect.server))) {
    const std::vector<std::string> servers =
        is_server_list(*connect.server) ? parse_server_list(*connect.server) : resolve_dns_name(*connect.server);
    if (servers.size() > 1) {
      if (sequence_frames(prepared.spec) > 0) {
        if (sink.options.json || sink.options.preview) {
          throw CliError(ExitCode::kUsage, std::string(sink.options.json ? "--json" : "--preview") +
                                               " is not available when a run is split across servers; run against "
                                               "one --server, or picture the frames afterwards with `surfacer "
                                               "preview`");
        }
        return run_scale_out(connect, servers, std::move(prepared), command.output, sink.err, sink.progress);
      }
      return run_failover(connect, servers, prepared, command.output, sink);
    }
    if (is_server_list(*connect.server)) {  // a list of one
      ConnectOptions one = connect;
      one.server = servers.front();
      return run_single(one, std::move(prepared), command.output, sink);
    }
  }
  return run_single(connect, std::move(prepared), command.output, sink);
}

ExitCode run_submit(const ConnectOptions& connect, const SubmitCommand& command, std::ostream& out, std::ostream& err,
                    bool tty) {
  PreparedJob prepared = prepare_job(command.job);
  fit_encoding_to_files(prepared.spec, {});  // what `watch` writes by default, as `run` would
  auto connection = Connection::open(connect);
  warn_local(*connection, err);
  std::atomic<bool> interrupted{false};
  InterruptHandler interrupts([&](int) { interrupted = true; });
  ProgressDisplay progress(err, tty);
  out << submit_with_inputs(*connection, prepared, progress, &interrupted) << "\n" << std::flush;
  return ExitCode::kSuccess;
}

ExitCode run_watch(const ConnectOptions& connect, const WatchCommand& command, const ReportSink& sink) {
  const auto start = std::chrono::steady_clock::now();
  FrameWriter writer(command.output);
  auto connection = Connection::open(connect);
  ProgressDisplay progress(sink.err, sink.progress);
  if (connection->local()) {
    std::ostringstream warning;
    warn_local(*connection, warning);
    progress.line(trim(warning.str()));
  }
  JobWatcher watcher(*connection, command.job_id, command.from_frame, writer, progress);
  const WatchResult result = watcher.run();
  return finish_watch(result, writer, progress, start, false, sink);
}

std::string percent_text(double fraction) {
  char buf[16];
  std::snprintf(buf, sizeof buf, "%.0f%%", std::clamp(fraction, 0.0, 1.0) * 100.0);
  return buf;
}

ExitCode run_status(const ConnectOptions& connect, const StatusCommand& command, std::ostream& out, std::ostream& err) {
  auto connection = Connection::open(connect);
  warn_local(*connection, err);
  const v1::Job job = get_job(*connection, command.job_id);
  if (command.json) {
    out << status_json(job) << "\n" << std::flush;
    return ExitCode::kSuccess;
  }
  out << "job:      " << job.id() << "\n";
  if (!job.name().empty()) out << "name:     " << job.name() << "\n";
  if (!job.kind().empty()) out << "kind:     " << job.kind() << "\n";
  out << "state:    " << state_name(job.state()) << "\n";
  out << "frames:   " << job.frames_done() << "/" << job.frames_total() << "\n";
  std::string progress = percent_text(job.progress().fraction());
  if (!job.progress().stage().empty()) {
    progress += " (" + job.progress().stage() + ", frame " + std::to_string(job.progress().frame_index()) + ")";
  }
  out << "progress: " << progress << "\n";
  const std::string error = job_error_text(job);
  if (!error.empty()) out << "error:    " << error << "\n";
  out << std::flush;
  return ExitCode::kSuccess;
}

ExitCode run_list(const ConnectOptions& connect, const ListCommand& command, std::ostream& out, std::ostream& err) {
  auto connection = Connection::open(connect);
  warn_local(*connection, err);
  const std::vector<v1::Job> jobs = list_jobs(*connection, command.states);
  if (command.json) {
    out << list_json(jobs) << "\n" << std::flush;
    return ExitCode::kSuccess;
  }
  std::size_t id_width = 6;
  for (const auto& job : jobs) id_width = std::max(id_width, job.id().size());
  out << std::left << std::setw(static_cast<int>(id_width)) << "JOB_ID"
      << "  " << std::setw(9) << "STATE"
      << "  " << std::setw(11) << "FRAMES"
      << "  " << std::setw(10) << "KIND"
      << "  NAME\n";
  for (const auto& job : jobs) {
    out << std::setw(static_cast<int>(id_width)) << job.id() << "  " << std::setw(9) << state_name(job.state()) << "  "
        << std::setw(11) << (std::to_string(job.frames_done()) + "/" + std::to_string(job.frames_total())) << "  "
        << std::setw(10) << (job.kind().empty() ? "-" : job.kind()) << "  " << job.name() << "\n";
  }
  out << std::flush;
  return ExitCode::kSuccess;
}

ExitCode run_cancel(const ConnectOptions& connect, const CancelCommand& command, std::ostream& out, std::ostream& err) {
  auto connection = Connection::open(connect);
  warn_local(*connection, err);
  const v1::Job job = request_cancel(*connection, command.job_id);
  if (is_terminal(job.state())) {
    out << "job " << job.id() << ": " << state_name(job.state()) << "\n";
  } else {
    out << "job " << job.id() << ": cancel requested (state " << state_name(job.state()) << ")\n";
  }
  out << std::flush;
  return ExitCode::kSuccess;
}

ExitCode run_health(const ConnectOptions& connect, const HealthCommand& command, std::ostream& out) {
  auto connection = Connection::open(connect);
  const HealthStatus status = check_health(connection->channel_ptr(), command.service, connection->unary_deadline());
  out << health_status_name(status) << "\n" << std::flush;
  if (status != HealthStatus::kServing) {
    throw CliError(ExitCode::kUnreachable,
                   connection->describe() + " is not serving" +
                       (command.service.empty() ? std::string() : " service \"" + command.service + "\"") +
                       " (health: " + health_status_name(status) + ")");
  }
  return ExitCode::kSuccess;
}

}  // namespace

std::string submit_job(Connection& connection, const v1::JobSpec& spec, v1::Job* job) {
  v1::SubmitJobResponse response;
  const grpc::Status status = connection.submit(spec, response);
  if (!status.ok()) {
    CliError error = rpc_error("the server rejected the job", status);
    // A rejection is the job's failure (exit 4), unless the server could not be reached at all.
    if (error.code() == ExitCode::kCancelled) throw CliError(ExitCode::kJobFailed, error.what(), error.status_code());
    throw error;
  }
  if (job != nullptr) *job = response.job();
  return response.job_id();
}

std::string submit_with_inputs(Connection& connection, PreparedJob& prepared, ProgressDisplay& progress,
                               const std::atomic<bool>* stop) {
  QueuedJob queued = queue_job(connection, prepared, progress, stop);
  const std::string id = queued.id;
  const auto interrupted = [&] {
    if (stop == nullptr || !stop->load()) return;
    cancel_job(connection, id);
    throw CliError(ExitCode::kCancelled, "interrupted: job " + id + " cancelled");
  };
  if (!queued.open) {
    interrupted();
    return id;
  }
  // The frames after the first join the job as they are uploaded; this returns once the sequence is ended.
  SequenceFeeder feeder(connection, id, prepared.spec, prepared.uploads, std::move(queued.uploaded), progress, stop);
  UploadSummary uploaded;
  try {
    uploaded = feeder.finish();
  } catch (const CliError& e) {
    throw CliError(e.code(),
                   std::string(e.what()) + "; job " + id +
                       " failed at that frame (the frames before it are kept: `surfacer watch " + id + "`)",
                   e.status_code());
  }
  interrupted();
  if (!feeder.ended()) {
    const v1::Job job = get_job(connection, id);
    const std::string reason = job_error_text(job);
    throw CliError(job.state() == v1::JOB_STATE_CANCELLED ? ExitCode::kCancelled : ExitCode::kJobFailed,
                   "job " + id + " ended (" + state_name(job.state()) + (reason.empty() ? "" : ": " + reason) +
                       ") after " + std::to_string(uploaded.uploads) + " of " +
                       std::to_string(prepared.uploads.size()) + " frames were uploaded");
  }
  return id;
}

v1::Job get_job(Connection& connection, const std::string& job_id) {
  v1::GetJobRequest request;
  request.set_job_id(job_id);
  return call(connection, "status of job " + job_id, &v1::Surfacer::Stub::GetJob, request);
}

std::vector<v1::Job> list_jobs(Connection& connection, const std::vector<std::string>& states) {
  v1::ListJobsRequest request;
  for (const std::string& name : states) {
    std::string upper = "JOB_STATE_";
    for (char c : name) upper += static_cast<char>(std::toupper(static_cast<unsigned char>(c)));
    v1::JobState state;
    if (!v1::JobState_Parse(upper, &state)) throw CliError(ExitCode::kUsage, "unknown job state " + name);
    request.add_states(state);
  }
  // Page by page (a server answers at most 1000 jobs at a time), until the last one.
  v1::ListJobsResponse response;
  do {
    request.set_page_token(response.next_page_token());
    v1::ListJobsResponse page = call(connection, "listing jobs", &v1::Surfacer::Stub::ListJobs, request);
    if (!page.next_page_token().empty() && (page.jobs_size() == 0 || page.next_page_token() == request.page_token())) {
      throw CliError(ExitCode::kInternal, "listing jobs: the server returned a page that does not advance");
    }
    response.mutable_jobs()->MergeFrom(page.jobs());
    response.set_next_page_token(page.next_page_token());
  } while (!response.next_page_token().empty());
  return {response.jobs().begin(), response.jobs().end()};
}

v1::Job request_cancel(Connection& connection, const std::string& job_id) {
  v1::CancelJobRequest request;
  request.set_job_id(job_id);
  return call(connection, "cancelling job " + job_id, &v1::Surfacer::Stub::CancelJob, request);
}

ExitCode run_invocation(const Invocation& invocation, std::ostream& out, std::ostream& err, bool tty) {
  const ConnectOptions& connect = invocation.connect;
  return std::visit(
      [&](const auto& command) -> ExitCode {
        using T = std::decay_t<decltype(command)>;
        if constexpr (std::is_same_v<T, RunCommand>) {
          return run_run(connect, command,
                         ReportSink{out, err, progress_mode(command.report.progress, tty), command.report});
        } else if constexpr (std::is_same_v<T, SubmitCommand>) {
          return run_submit(connect, command, out, err, tty);
        } else if constexpr (std::is_same_v<T, WatchCommand>) {
          return run_watch(connect, command,
                           ReportSink{out, err, progress_mode(command.report.progress, tty), command.report});
        } else if constexpr (std::is_same_v<T, StatusCommand>) {
          return run_status(connect, command, out, err);
        } else if constexpr (std::is_same_v<T, ListCommand>) {
          return run_list(connect, command, out, err);
        } else if constexpr (std::is_same_v<T, CancelCommand>) {
          return run_cancel(connect, command, out, err);
        } else if constexpr (std::is_same_v<T, PreviewCommand>) {
          return run_preview(command, out);
        } else {
          return run_health(connect, command, out);
        }
      },
      invocation.command);
}

}  // namespace surfacer::client
