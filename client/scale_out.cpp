#include "client/scale_out.h"

#include <google/protobuf/descriptor.h>
#include <google/protobuf/reflection.h>
#include <grpcpp/client_context.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <condition_variable>
#include <cstring>
#include <deque>
#include <limits>
#include <mutex>
#include <set>
#include <sstream>
#include <thread>

#include "client/connection.h"
#include "client/frame_writer.h"
#include "client/health.h"
#include "client/interrupt.h"
#include "client/progress.h"
#include "client/security.h"
#include "client/server_list.h"
#include "client/summary.h"
#include "client/upload.h"
#include "client/watch.h"
#include "core/polygonize/polygonize.h"
#include "core/util/errors.h"
#include "wire/job_options.h"
#include "wire/particle_frames.h"
#include "wire/scene.h"
#include "wire/uploads.h"

namespace surfacer::client {
namespace {

// A job the client refuses before splitting it: the server's own validation (wire/, core/), run here.
CliError invalid_job(const Error& e) {
  return CliError(
      ExitCode::kJobFailed,
      std::string("the job is invalid (checked before splitting it across the servers): INVALID_ARGUMENT: ") +
          e.what());
}

// The grid the server would derive for the whole sequence (wire/job_options.h, core/polygonize/polygonize.h), fixed
// in the spec as bounds and cell size, so that every sub-job polygonizes on it.
void pin_isosurface(v1::JobSpec& spec) {
  v1::IsosurfaceJob& job = *spec.mutable_isosurface();
  if (job.has_bounds()) return;  // the server derives the cell size from the given bounds, alike in every sub-job
  const wire::MemoryUploads no_uploads;  // scale-out refuses jobs that refer to uploads (find_upload_reference)
  try {
    const std::vector<FieldPtr> fields = wire::isosurface_fields(job, no_uploads, "spec.isosurface");
    const PolygonizeOptions options = wire::isosurface_options(job, spec.output().normals(), "spec.isosurface");
    const PolygonizeGrid grid = with_path("spec.isosurface", [&] { return resolve_grid(fields, options); });
    wire::set_bounds(*job.mutable_bounds(), grid.bounds);
    job.set_cell_size(grid.h);
  } catch (const Error& e) {
    if (e.kind() != ErrorKind::kInvalidInput) throw;
    throw invalid_job(e);
  }
}

// The quantization box the server would derive for the whole sequence (wire/particle_frames.h).
void pin_particles(v1::JobSpec& spec, const std::vector<wire::ParticleSummary>& frames,
                   const std::vector<Vec3>& first) {
  if (spec.output().has_quantization_bounds() || frames.empty()) return;
  try {
    const Aabb box = wire::particles_job_box(spec.particles(), frames, [&] { return first; });
    wire::set_bounds(*spec.mutable_output()->mutable_quantization_bounds(), box);
  } catch (const Error& e) {
    if (e.kind() != ErrorKind::kInvalidInput) throw;
    throw invalid_job(e);
  }
}

std::optional<std::string> find_upload_in(const google::protobuf::Message& message, const std::string& path) {
  const google::protobuf::Reflection* reflection = message.GetReflection();
  std::vector<const google::protobuf::FieldDescriptor*> fields;
  reflection->ListFields(message, &fields);
  for (const auto* field : fields) {
    const std::string name = path + "." + field->name();
    if (field->cpp_type() == google::protobuf::FieldDescriptor::CPPTYPE_STRING && !field->is_repeated() &&
        (field->name() == "upload_id" || field->name() == "mesh_upload_id")) {
      const std::string id = reflection->GetString(message, field);
      if (!id.empty()) return name + " = " + id;
    } else if (field->cpp_type() == google::protobuf::FieldDescriptor::CPPTYPE_MESSAGE) {
      if (field->is_repeated()) {
        for (int i = 0; i < reflection->FieldSize(message, field); ++i) {
          auto found =
              find_upload_in(reflection->GetRepeatedMessage(message, field, i), name + "[" + std::to_string(i) + "]");
          if (found) return found;
        }
      } else if (auto found = find_upload_in(reflection->GetMessage(message, field), name)) {
        return found;
      }
    }
  }
  return std::nullopt;
}

// A job's error for a log line ("no reason given" when it has none).
std::string reason_text(const v1::Job& job) {
  std::string text = job_error_text(job);
  return text.empty() ? "no reason given" : text;
}

// A server that has stopped taking work: unreachable, or answering health with something else than SERVING.
bool server_going_away(Connection& connection) {
  try {
    return check_health(connection.channel_ptr(), "", std::chrono::system_clock::now() + std::chrono::seconds(2)) !=
           HealthStatus::kServing;
  } catch (const CliError&) {
    return true;
  }
}

struct ServerSlot {
  std::string address;
  ConnectOptions connect;
  // Guarded by ScaleOut::mutex_.
  bool dead = false;
  std::string death;
  int frames = 0;    // frames this server produced that were written
  int sub_jobs = 0;  // sub-jobs submitted
  JobWatcher* watcher = nullptr;
};

class ScaleOut {
 public:
  ScaleOut(const ConnectOptions& connect, const std::vector<std::string>& servers, PreparedJob prepared,
           const FrameOutputOptions& output, ProgressDisplay& progress)
      : prepared_(std::move(prepared)), writer_(output), progress_(progress), verbose_(connect.verbose) {
    const v1::JobSpec& spec = prepared_.spec;
    writer_.set_job_kind(spec.has_isosurface() ? "isosurface" : "particles");
    frames_total_ = sequence_frames(spec);
    const std::string dns_name = connect.server ? dns_host(*connect.server) : "";
    for (const std::string& address : servers) {
      auto slot = std::make_unique<ServerSlot>();
      slot->address = address;
      slot->connect = connect;
      slot->connect.server = address;
      // Addresses resolved from a dns:/// name: the certificate carries the name, not the address.
      if (!dns_name.empty() && slot->connect.security.tls && !slot->connect.security.server_name) {
        slot->connect.security.server_name = dns_name;
      }
      slots_.push_back(std::move(slot));
    }
    const auto batches = make_batches(frames_total_, static_cast<int>(servers.size()));
    batch_size_ = batches.empty() ? 0 : static_cast<int>(batches.front().size());
    queue_.assign(batches.begin(), batches.end());
    remaining_ = frames_total_;
  }

  ExitCode run(std::chrono::steady_clock::time_point start) {
    std::string names;
    for (const auto& slot : slots_) names += (names.empty() ? "" : ", ") + slot->address;
    progress_.line("splitting " + std::to_string(frames_total_) + " frames into " + std::to_string(queue_.size()) +
                   " batches of up to " + std::to_string(batch_size_) + " across " + std::to_string(slots_.size()) +
                   " servers: " + names);
    {
      InterruptHandler interrupts([this](int count) {
        if (count == 1)
          progress_.line(
              "interrupted: cancelling the sub-jobs on every server (Ctrl-C again to stop "
              "waiting)");
        stop(CliError(ExitCode::kCancelled, "interrupted: the sub-jobs on every server were cancelled"));
      });
      std::vector<std::thread> threads;
      for (auto& slot : slots_) threads.emplace_back([this, &slot] { worker(*slot); });
      for (auto& t : threads) t.join();
    }
    std::lock_guard lock(mutex_);
    progress_.clear();
    if (error_) throw *error_;
    if (remaining_ > 0) {
      std::string deaths;
      for (const auto& slot : slots_) deaths += "\n  " + slot->address + ": " + slot->death;
      throw CliError(ExitCode::kUnreachable, "every server is unreachable; " + std::to_string(remaining_) + " of " +
                                                 std::to_string(frames_total_) +
                                                 " frames were not produced (the others are in " +
                                                 writer_.dir().string() + "):" + deaths);
    }
    print_summary(start);
    return ExitCode::kSuccess;
  }

 private:
  // Ends the run with `error` (the first one wins): queued batches are dropped, the watchers stopped; each worker
  // then cancels its sub-job.
  void stop(const CliError& error) {
    std::lock_guard lock(mutex_);
    if (!error_) error_ = error;
    stopping_ = true;
    stop_flag_ = true;
    for (auto& slot : slots_) {
      if (slot->watcher != nullptr) slot->watcher->stop();
    }
    ready_.notify_all();
  }

  bool take(std::vector<int>& batch) {
    std::unique_lock lock(mutex_);
    ready_.wait(lock, [this] { return stopping_ || !queue_.empty() || remaining_ == 0; });
    if (stopping_ || queue_.empty()) return false;
    batch = std::move(queue_.front());
    queue_.pop_front();
    return true;
  }

  void server_died(ServerSlot& slot, const std::string& reason, const std::vector<int>& batch) {
    std::lock_guard lock(mutex_);
    slot.dead = true;
    slot.death = reason;
    std::vector<int> unwritten;
    for (int g : batch) {
      if (written_.count(g) == 0) unwritten.push_back(g);
    }
    std::string text = "server " + slot.address + " is unreachable, leaving it out: " + reason;
    if (!unwritten.empty() && !stopping_) {
      queue_.push_front(unwritten);  // first in line, so the output fills in order
      ++retried_batches_;
      retried_frames_ += static_cast<int>(unwritten.size());
      text += "; its " + frames_text(unwritten) + (unwritten.size() == 1 ? " goes" : " go") + " back to the queue";
      ready_.notify_all();
    }
    progress_.line(text);
  }

  // Writes one frame of a sub-job under its global index (once, whoever sends it).
  void write_frame(ServerSlot& slot, const std::vector<int>& batch, const std::string& job_id,
                   const ReceivedFrame& frame) {
    if (frame.index < 0 || frame.index >= static_cast<int>(batch.size())) {
      throw CliError(ExitCode::kIntegrity, "job " + job_id + " on " + slot.address + " sent frame " +
                                               std::to_string(frame.index) + " but has only " +
                                               std::to_string(batch.size()));
    }
    ReceivedFrame global = frame;
    global.index = batch[static_cast<std::size_t>(frame.index)];
    std::lock_guard lock(mutex_);
    if (written_.count(global.index) != 0) return;
    writer_.write(global);
    written_.insert(global.index);
    triangles_ += global.stats.triangles();
    ++slot.frames;
    --remaining_;
    progress_.on_frame(global, frames_total_, verbose_ ? " [" + slot.address + ", job " + job_id + "]" : "");
    if (remaining_ == 0) ready_.notify_all();
  }

  // The pending uploads of the batch's frames, in the batch's order.
  std::vector<PendingUpload> batch_uploads(const std::vector<int>& batch) const {
    std::vector<PendingUpload> uploads;
    for (int g : batch) {
      for (const PendingUpload& pending : prepared_.uploads) {
        if (pending.frame == g) uploads.push_back(pending);
      }
    }
    return uploads;
  }

  void count_particles(const UploadSummary& uploaded) {
    std::lock_guard lock(mutex_);
    for (const auto& [g, particles] : uploaded.particles) particles_[g] = particles;
  }

  std::string submit(Connection& connection, ServerSlot& slot, const v1::JobSpec& spec, const std::vector<int>& batch) {
    v1::SubmitJobResponse response;
    const grpc::Status status = connection.submit(spec, response);
    if (!status.ok()) {
      CliError error = rpc_error(slot.address + " rejected the sub-job of " + frames_text(batch), status);
      if (error.code() == ExitCode::kUnreachable) throw error;
      throw CliError(ExitCode::kJobFailed, globalize_indices(error.what(), batch));
    }
    return response.job_id();
  }

  // Runs one batch as a sub-job on `connection`. A particle batch of several frames, each uploaded, goes to a server
  // that takes open sequences as one: submitted once its first frame is uploaded, the others joining it as they are
  // uploaded (SequenceFeeder) while it surfaces the first; otherwise the batch's inputs are all uploaded first.
  void run_batch(Connection& connection, ServerSlot& slot, const std::vector<int>& batch, std::string& job_id) {
    v1::JobSpec scratch = prepared_.spec;  // uploads record their ids (and with_radius) at global indices
    const std::vector<PendingUpload> uploads = batch_uploads(batch);
    const bool open = scratch.has_particles() && batch.size() >= 2 && uploads.size() == batch.size() &&
                      takes_open_sequences(connection);
    std::ostringstream quiet;  // uploads are not reported one by one here: the frames are
    ProgressDisplay upload_progress(quiet, false);
    UploadSummary uploaded =
        upload_inputs(connection, scratch, uploads, upload_progress, &stop_flag_, open ? 1 : SIZE_MAX);
    const v1::JobSpec spec = open ? open_sequence_spec(sub_job_spec(scratch, batch)) : sub_job_spec(scratch, batch);
    job_id = submit(connection, slot, spec, batch);
    {
      std::lock_guard lock(mutex_);
      ++slot.sub_jobs;
      if (stopping_) return;  // the caller cancels it
    }
    std::optional<SequenceFeeder> feeder;
    if (open) {
      feeder.emplace(connection, job_id, scratch, uploads, uploaded, upload_progress, &stop_flag_);
    } else {
      count_particles(uploaded);
    }
    if (verbose_) progress_.line(frames_text(batch) + " -> job " + job_id + " on " + slot.address);
    ReconnectPolicy policy;
    policy.budget =
        std::chrono::milliseconds(static_cast<long long>(std::llround(slot.connect.timeout_seconds * 1000)));
    const std::string id = job_id;
    JobWatcher watcher(
        connection, job_id, 0, [&](const ReceivedFrame& frame) { write_frame(slot, batch, id, frame); }, progress_,
        policy, /*quiet=*/true);
    {
      std::lock_guard lock(mutex_);
      if (stopping_) return;
      slot.watcher = &watcher;
    }
    WatchResult result;
    try {
      result = watcher.run();
    } catch (...) {
      std::lock_guard lock(mutex_);
      slot.watcher = nullptr;
      throw;
    }
    {
      std::lock_guard lock(mutex_);
      slot.watcher = nullptr;
    }
    if (feeder) {
      // A frame that could not be read or uploaded failed the sub-job: its error is the one to report.
      if (result.job.state() != v1::JOB_STATE_SUCCEEDED) feeder->stop();
      count_particles(feeder->finish());
    }
    switch (result.job.state()) {
      case v1::JOB_STATE_SUCCEEDED:
        return;
      case v1::JOB_STATE_CANCELLED:
        if (server_going_away(connection)) {
          throw CliError(ExitCode::kUnreachable,
                         "it cancelled job " + job_id + " (" + reason_text(result.job) + ") and is shutting down");
        }
        throw CliError(ExitCode::kCancelled, "job " + job_id + " (" + frames_text(batch) + ") on " + slot.address +
                                                 " was cancelled elsewhere: " + reason_text(result.job));
      default:
        throw CliError(ExitCode::kJobFailed, "job " + job_id + " (" + frames_text(batch) + ") failed on " +
                                                 slot.address + ": " +
                                                 globalize_indices(reason_text(result.job), batch));
    }
  }

  void worker(ServerSlot& slot) {
    std::unique_ptr<Connection> connection;
    try {
      connection = Connection::open(slot.connect);
    } catch (const CliError& e) {
      if (e.code() == ExitCode::kUnreachable) {
        server_died(slot, e.what(), {});
      } else {
        stop(e);
      }
      return;
    }
    std::vector<int> batch;
    while (take(batch)) {
      std::string job_id;
      try {
        run_batch(*connection, slot, batch, job_id);
        bool stopping = false;
        {
          std::lock_guard lock(mutex_);
          stopping = stopping_;
        }
        if (stopping && !job_id.empty()) cancel_job(*connection, job_id, std::chrono::seconds(3));
      } catch (const CliError& e) {
        bool stopping = false;
        {
          std::lock_guard lock(mutex_);
          stopping = stopping_;
        }
        if (stopping) {  // another worker failed, or Ctrl-C: do not leave this sub-job running
          if (!job_id.empty()) cancel_job(*connection, job_id, std::chrono::seconds(3));
          return;
        }
        if (e.code() == ExitCode::kUnreachable) {
          if (!job_id.empty())
            cancel_job(*connection, job_id, std::chrono::seconds(3));  // in case it is only our link that broke
          server_died(slot, e.what(), batch);
          return;
        }
        if (!job_id.empty()) cancel_job(*connection, job_id, std::chrono::seconds(3));
        stop(e);
        return;
      } catch (const std::exception& e) {  // a bug: end the run cleanly rather than the process
        if (!job_id.empty()) cancel_job(*connection, job_id, std::chrono::seconds(3));
        stop(CliError(ExitCode::kInternal, std::string("internal error on ") + slot.address + ": " + e.what()));
        return;
      }
    }
  }

  void print_summary(std::chrono::steady_clock::time_point start) {
    progress_.line("wrote " + std::to_string(frames_total_) + " frames to " + writer_.dir().string() +
                   (writer_.dir().string().back() == '/' ? "" : "/") + " (" + std::to_string(triangles_) +
                   " triangles, " + elapsed_text(start) + ") from " + std::to_string(slots_.size()) + " servers:");
    for (const auto& slot : slots_) {
      std::string line = "  " + slot->address + ": " + std::to_string(slot->frames) + " frame" +
                         (slot->frames == 1 ? "" : "s") + " in " + std::to_string(slot->sub_jobs) + " sub-job" +
                         (slot->sub_jobs == 1 ? "" : "s");
      if (slot->dead) line += " (unreachable since then)";
      progress_.line(line);
    }
    progress_.line("retries: " + std::to_string(retried_batches_) + " batch" + (retried_batches_ == 1 ? "" : "es") +
                   " (" + std::to_string(retried_frames_) + " frame" + (retried_frames_ == 1 ? "" : "s") +
                   ") moved to another server");
    if (prepared_.spec.has_particles()) {
      const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
      std::string table = particles_summary_table(writer_.stats(), particles_, wall);
      if (!table.empty() && table.back() == '\n') table.pop_back();
      progress_.line(table);
    }
  }

  PreparedJob prepared_;
  FrameWriter writer_;
  ProgressDisplay& progress_;
  bool verbose_ = false;
  int frames_total_ = 0;
  int batch_size_ = 0;
  std::vector<std::unique_ptr<ServerSlot>> slots_;
  std::atomic<bool> stop_flag_{false};  // for uploads in progress

  std::mutex mutex_;
  std::condition_variable ready_;
  std::deque<std::vector<int>> queue_;
  std::set<int> written_;
  int remaining_ = 0;
  bool stopping_ = false;
  std::optional<CliError> error_;
  std::int64_t triangles_ = 0;
  int retried_batches_ = 0;
  int retried_frames_ = 0;
  std::map<int, std::int64_t> particles_;
};

}  // namespace

int sequence_frames(const v1::JobSpec& spec) {
  int frames = 0;
  if (spec.has_isosurface()) frames = spec.isosurface().scenes_size();
  if (spec.has_particles()) frames = spec.particles().frames_size();
  return frames >= 2 ? frames : 0;
}

std::vector<std::vector<int>> make_batches(int frames, int servers) {
  std::vector<std::vector<int>> batches;
  if (frames <= 0) return batches;
  const int per = std::max(1, (frames + 4 * std::max(servers, 1) - 1) / (4 * std::max(servers, 1)));
  for (int first = 0; first < frames; first += per) {
    std::vector<int> batch;
    for (int g = first; g < std::min(frames, first + per); ++g) batch.push_back(g);
    batches.push_back(std::move(batch));
  }
  return batches;
}

v1::JobSpec sub_job_spec(const v1::JobSpec& whole, const std::vector<int>& frames) {
  v1::JobSpec sub = whole;
  if (whole.has_isosurface()) {
    sub.mutable_isosurface()->clear_scenes();
    for (int g : frames) *sub.mutable_isosurface()->add_scenes() = whole.isosurface().scenes(g);
  } else if (whole.has_particles()) {
    sub.mutable_particles()->clear_frames();
    for (int g : frames) *sub.mutable_particles()->add_frames() = whole.particles().frames(g);
  }
  sub.set_name(whole.name() + (whole.name().empty() ? "" : " ") + "[" + frames_text(frames) + "]");
  return sub;
}

std::string frames_text(const std::vector<int>& frames) {
  if (frames.empty()) return "no frames";
  if (frames.size() == 1) return "frame " + std::to_string(frames.front());
  bool contiguous = true;
  for (std::size_t i = 1; i < frames.size(); ++i) contiguous = contiguous && frames[i] == frames[i - 1] + 1;
  if (contiguous) return "frames " + std::to_string(frames.front()) + "-" + std::to_string(frames.back());
  std::string text = "frames ";
  for (std::size_t i = 0; i < frames.size(); ++i) text += (i > 0 ? ", " : "") + std::to_string(frames[i]);
  return text;
}

std::string globalize_indices(const std::string& message, const std::vector<int>& frames) {
  std::string out;
  std::size_t pos = 0;
  while (pos < message.size()) {
    std::size_t best = std::string::npos;
    std::size_t key_size = 0;
    for (const char* key : {"scenes[", "frames["}) {
      const std::size_t at = message.find(key, pos);
      if (at < best) {
        best = at;
        key_size = std::strlen(key);
      }
    }
    if (best == std::string::npos) {
      out += message.substr(pos);
      break;
    }
    std::size_t digits = best + key_size;
    std::size_t end = digits;
    while (end < message.size() && std::isdigit(static_cast<unsigned char>(message[end]))) ++end;
    out += message.substr(pos, digits - pos);
    if (end > digits && end < message.size() && message[end] == ']' && end - digits < 9) {
      const int local = std::stoi(message.substr(digits, end - digits));
      out += local < static_cast<int>(frames.size()) ? std::to_string(frames[static_cast<std::size_t>(local)])
                                                     : message.substr(digits, end - digits);
    } else {
      out += message.substr(digits, end - digits);
    }
    pos = end;
  }
  return out;
}

std::optional<std::string> find_upload_reference(const v1::JobSpec& spec) { return find_upload_in(spec, "spec"); }

void pin_whole_job_geometry(v1::JobSpec& spec, const std::vector<wire::ParticleSummary>& particle_frames,
                            const std::vector<Vec3>& first_frame) {
  if (spec.has_isosurface()) pin_isosurface(spec);
  if (spec.has_particles()) pin_particles(spec, particle_frames, first_frame);
}

void pin_particles_from_inputs(PreparedJob& prepared, const InputLimits& limits) {
  v1::JobSpec scratch = prepared.spec;
  const int frames = scratch.particles().frames_size();
  std::vector<wire::ParticleSummary> boxes(static_cast<std::size_t>(frames));
  std::vector<Vec3> first;
  for (int g = 0; g < frames; ++g) {
    wire::ParticleSummary& box = boxes[static_cast<std::size_t>(g)];
    box.bounds = Aabb::empty();
    auto visit = [&](double x, double y, double z, double r) {
      const Vec3 p(x, y, z);
      box.bounds.merge(p);
      box.max_radius = std::max(box.max_radius, r);
      ++box.count;
      if (g == 0) first.push_back(p);
    };
    const PendingUpload* pending = nullptr;
    for (const PendingUpload& p : prepared.uploads) {
      if (p.frame == g) pending = &p;
    }
    if (pending != nullptr) {
      const UploadData data = pending->read(scratch, limits);
      const bool with_radius = scratch.particles().frames(g).with_radius();
      std::size_t floats = with_radius ? 4 : 3;
      for (const v1::ParticleAttribute& a : scratch.particles().frames(g).attributes()) {
        floats += static_cast<std::size_t>(a.components());
      }
      const std::size_t record = floats * sizeof(float);
      for (std::size_t at = 0; at + record <= data.bytes.size(); at += record) {
        float v[4] = {0, 0, 0, 0};
        std::memcpy(v, data.bytes.data() + at, (with_radius ? 4 : 3) * sizeof(float));
        visit(v[0], v[1], v[2], v[3]);
      }
    } else {
      const v1::ParticleFrame& frame = scratch.particles().frames(g);
      const bool with_radius = frame.radii_size() > 0;
      for (int i = 0; i + 2 < frame.positions_size(); i += 3) {
        visit(frame.positions(i), frame.positions(i + 1), frame.positions(i + 2),
              with_radius && i / 3 < frame.radii_size() ? frame.radii(i / 3) : 0.0);
      }
    }
  }
  pin_whole_job_geometry(prepared.spec, boxes, first);
}

ExitCode run_scale_out(const ConnectOptions& connect, const std::vector<std::string>& servers, PreparedJob prepared,
                       const FrameOutputOptions& output, std::ostream& err, ProgressMode mode) {
  const auto start = std::chrono::steady_clock::now();
  if (const auto reference = find_upload_reference(prepared.spec)) {
    throw CliError(ExitCode::kUsage,
                   "the job refers to an upload (" + *reference +
                       ") that exists on one server only, so it cannot be split across servers; give the input as a "
                       "file (the CLI uploads it to each server) or run against one --server");
  }
  for (const std::string& server : servers) check_token_transport(server, connect.security);
  if (prepared.spec.has_particles()) {
    pin_particles_from_inputs(prepared);  // before connecting: each server checks its own limits
  } else {
    pin_whole_job_geometry(prepared.spec, {}, {});
  }
  ProgressDisplay progress(err, mode);
  ScaleOut scale_out(connect, servers, std::move(prepared), output, progress);
  return scale_out.run(start);
}

}  // namespace surfacer::client
