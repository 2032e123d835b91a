// Load test: N concurrent clients submit, watch, re-attach to and cancel small jobs on a real
// server over TCP for a fixed time, verify every frame they receive, and print throughput and latency.
//
// Each client thread loops until --seconds have passed (its job in flight is then finished, not abandoned):
//   1. picks a job from a mix: isosurface single frame (40 %), isosurface sequence of 3-5 scenes (35 %), particles
//      (25 %: 1-2 particle balls of ~500-1400 particles, each sent with Upload) — each job takes ~10-200 ms;
//   2. submits it; RESOURCE_EXHAUSTED (the queue is full: legitimate backpressure) is counted and retried after a
//      jittered exponential backoff;
//   3. watches it with WatchJob, reassembling frames from their chunks (client/frame_assembler.h checks every
//      chunk's and every frame's CRC-32, sizes and chunk order), decodes each frame with the Draco decoder and checks
//      the mesh is non-empty, closed, edge-manifold and oriented with positive volume and the triangle count the
//      header announced;
//   4. with probability --cancel-fraction cancels the job (single-frame jobs at once, sequences at once or after
//      their first frame) and requires it to end CANCELLED, or SUCCEEDED when it finished first — never FAILED;
//   5. with probability --reattach-fraction re-attaches: drops the stream after the first frame and watches again
//      from the first frame it lacks (k; sequences, 70 %), or watches again from a random k after the job finished.
//      Either way the new stream must carry every frame >= k and none below.
// Checked protocol rules: states never go backwards, the terminal state comes last and only after whole frames, no
// frame index is repeated or out of range, a stream ends OK. A watch that outlives --job-timeout is a failure.
//
// Exit code: 0 when nothing failed; 1 with the reasons printed when any job FAILED, any frame was lost (an expected
// frame of a SUCCEEDED job never arrived) or corrupted (CRC, size, Draco decode or mesh check), or the protocol was
// broken; 2 for bad flags; 3 when --server cannot be reached.
//
// Usage: load_bench [--clients N] [--seconds S] [--cancel-fraction P] [--reattach-fraction P] [--workers W]
//                   [--max-queued-jobs Q] [--data-dir DIR] [--server HOST:PORT] [--seed N] [--job-timeout S]
//                   [--server-logs]
// --workers, --max-queued-jobs, --data-dir and --server-logs configure the embedded server: with --server they are
// refused (exit 2), as they would change nothing. --help describes every flag.
#include <google/protobuf/util/json_util.h>
#include <grpcpp/grpcpp.h>
#include <sys/resource.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <ctime>
#include <fstream>
#include <functional>
#include <mutex>
#include <random>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "bench/bench_args.h"
#include "client/exit_codes.h"
#include "client/frame_assembler.h"
#include "client/upload.h"
#include "core/mesh/mesh_checks.h"
#include "core/mesh/mesh_codec.h"
#include "server/log.h"
#include "server/server.h"
#include "surfacer/v1/surfacer.grpc.pb.h"

namespace {

using namespace surfacer;
using Clock = std::chrono::steady_clock;

double seconds_between(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double>(b - a).count();
}

// ---------------------------------------------------------------------------------------------------------------
// Settings and counters

struct Settings {
  int clients = 8;
  double seconds = 20.0;
  double cancel_fraction = 0.2;
  double reattach_fraction = 0.25;
  int workers = 0;
  int max_queued_jobs = 64;
  std::string server;    // empty: an embedded server on 127.0.0.1:0
  std::string data_dir;  // the embedded server's durable store (empty: memory only)
  unsigned seed = 1;
  double job_timeout = 120.0;
  bool server_logs = false;
};

enum class Kind { kIsoSingle = 0, kIsoSequence = 1, kParticles = 2 };
constexpr int kKinds = 3;
const char* const kKindNames[kKinds] = {"iso 1 frame", "iso 3-5 frames", "particles"};

// Per-client tallies, merged after the run (no locking on the hot path).
struct Tally {
  std::int64_t submitted = 0, succeeded = 0, cancelled = 0, failed = 0;
  std::int64_t cancel_requests = 0, finished_before_cancel = 0;
  std::int64_t rejected = 0;   // RESOURCE_EXHAUSTED answers to SubmitJob (retried)
  std::int64_t abandoned = 0;  // still rejected when the run ended: never submitted
  std::int64_t uploads = 0, upload_bytes = 0;
  std::int64_t frames = 0, frame_bytes = 0, triangles = 0;
  std::int64_t lost = 0, corrupted = 0, protocol = 0;
  std::int64_t reattach_mid = 0, reattach_done = 0, reattach_frames = 0;
  std::vector<double> first_frame[kKinds], done[kKinds];  // seconds from the accepted SubmitJob call
  std::vector<double> cancel_latency;                     // CancelJob sent -> terminal state received
  double client_cpu = 0.0;                                // CPU seconds of this client thread

  void merge(const Tally& o) {
    submitted += o.submitted, succeeded += o.succeeded, cancelled += o.cancelled, failed += o.failed;
    cancel_requests += o.cancel_requests, finished_before_cancel += o.finished_before_cancel;
    rejected += o.rejected, abandoned += o.abandoned, uploads += o.uploads, upload_bytes += o.upload_bytes;
    frames += o.frames, frame_bytes += o.frame_bytes, triangles += o.triangles;
    lost += o.lost, corrupted += o.corrupted, protocol += o.protocol;
    reattach_mid += o.reattach_mid, reattach_done += o.reattach_done, reattach_frames += o.reattach_frames;
    for (int k = 0; k < kKinds; ++k) {
      first_frame[k].insert(first_frame[k].end(), o.first_frame[k].begin(), o.first_frame[k].end());
      done[k].insert(done[k].end(), o.done[k].begin(), o.done[k].end());
    }
    cancel_latency.insert(cancel_latency.end(), o.cancel_latency.begin(), o.cancel_latency.end());
    client_cpu += o.client_cpu;
  }
};

// Live figures for the progress line, and the first failure messages (kept for the report).
struct Shared {
  std::atomic<std::int64_t> jobs_done{0}, frames{0}, problems{0};
  std::mutex mutex;
  std::vector<std::string> messages;
  std::int64_t messages_dropped = 0;

  void report(const std::string& message) {
    ++problems;
    std::lock_guard lock(mutex);
    if (messages.size() < 25) {
      messages.push_back(message);
    } else {
      ++messages_dropped;
    }
  }
};

// ---------------------------------------------------------------------------------------------------------------
// Job specs

std::string vec3(double x, double y, double z) {
  char buf[128];
  std::snprintf(buf, sizeof buf, R"({"x": %.6f, "y": %.6f, "z": %.6f})", x, y, z);
  return buf;
}

v1::Scene parse_scene(const std::string& json) {
  v1::Scene scene;
  const auto status = google::protobuf::util::JsonStringToMessage(json, &scene);
  if (!status.ok()) throw std::logic_error("load_bench built an unparsable scene: " + status.ToString() + "\n" + json);
  return scene;
}

// One closed solid of family `family` (0..4) at parameter t in [0, 1] (a sequence sweeps t); `a`, `b` in [0, 1)
// vary the shape between jobs.
v1::Scene make_scene(int family, double t, double a, double b) {
  char buf[2048];
  switch (family) {
    case 0:  // a sphere that moves and grows
      std::snprintf(buf, sizeof buf, R"({"name": "sphere", "root": {"sphere": {"center": %s, "radius": %.6f}}})",
                    vec3(0.4 * t - 0.2, 0.3 * a - 0.15, 0.0).c_str(), 0.6 + 0.3 * b + 0.2 * t);
      break;
    case 1:  // a torus that turns
      std::snprintf(buf, sizeof buf,
                    R"({"name": "torus", "root": {"torus": {"center": %s, "axis": %s, "major_radius": %.6f,
                        "minor_radius": %.6f}}})",
                    vec3(0, 0, 0).c_str(), vec3(std::sin(1.2 * t + a), 0.3 * b, std::cos(1.2 * t + a)).c_str(),
                    0.8 + 0.2 * a, 0.25 + 0.1 * b);
      break;
    case 2:  // three Wyvill blobs drifting apart
      std::snprintf(buf, sizeof buf,
                    R"({"name": "blobs", "root": {"blobs": {"kernel": "KERNEL_WYVILL", "iso": 0.5, "points": [
                        {"center": %s, "radius": 0.9, "strength": 1},
                        {"center": %s, "radius": 0.7, "strength": 1},
                        {"center": %s, "radius": 0.6, "strength": 1}]}}})",
                    vec3(0, 0, 0).c_str(), vec3(0.5 + 0.4 * t, 0.2 * a, 0).c_str(),
                    vec3(-0.3, 0.5 + 0.3 * t, 0.2 * b).c_str());
      break;
    case 3:  // a block with holes that widen
      std::snprintf(buf, sizeof buf,
                    R"({"name": "block", "root": {"difference": {"children": [
                        {"box": {"center": %s, "half_size": %s}},
                        {"cylinder": {"a": %s, "b": %s, "radius": %.6f}},
                        {"sphere": {"center": %s, "radius": %.6f}}]}}})",
                    vec3(0, 0, 0).c_str(), vec3(1.0 + 0.3 * a, 0.7, 0.4).c_str(), vec3(-0.4, 0, -1).c_str(),
                    vec3(-0.4, 0, 1).c_str(), 0.15 + 0.15 * t, vec3(1.0 + 0.3 * a, 0.7, 0.4).c_str(), 0.3 + 0.1 * b);
      break;
    default:  // a smooth blend of a slab and a rising sphere
      std::snprintf(buf, sizeof buf,
                    R"({"name": "blend", "root": {"union": {"blend": "BLEND_SMOOTH", "radius": %.6f, "children": [
                        {"box": {"center": %s, "half_size": %s}},
                        {"sphere": {"center": %s, "radius": 0.5}}]}}})",
                    0.2 + 0.1 * a, vec3(0, 0, -0.3).c_str(), vec3(0.9, 0.9 + 0.2 * b, 0.25).c_str(),
                    vec3(0, 0, 0.2 + 0.5 * t).c_str());
      break;
  }
  return parse_scene(buf);
}

// A jittered ball of particles of spacing d around c, as little-endian float32 x y z records.
std::string particle_ball(std::mt19937& rng, double cx, double cy, double cz, double radius, double d) {
  std::uniform_real_distribution<double> jitter(-0.15 * d, 0.15 * d);
  std::vector<float> xyz;
  const int n = static_cast<int>(std::ceil(radius / d));
  for (int i = -n; i <= n; ++i)
    for (int j = -n; j <= n; ++j)
      for (int k = -n; k <= n; ++k) {
        const double x = i * d, y = j * d, z = k * d;
        if (x * x + y * y + z * z > radius * radius) continue;
        xyz.push_back(static_cast<float>(cx + x + jitter(rng)));
        xyz.push_back(static_cast<float>(cy + y + jitter(rng)));
        xyz.push_back(static_cast<float>(cz + z + jitter(rng)));
      }
  static_assert(sizeof(float) == 4);
  return std::string(reinterpret_cast<const char*>(xyz.data()), xyz.size() * sizeof(float));
}

enum class CancelMode { kNone, kImmediately, kAfterFirstFrame };
enum class ReattachMode { kNone, kMidStream, kAfterDone };

struct JobPlan {
  Kind kind = Kind::kIsoSingle;
  v1::JobSpec spec;
  std::vector<std::string> particle_frames;  // to upload first (particles jobs)
  int frames = 1;                            // frames the job must produce
  CancelMode cancel = CancelMode::kNone;
  ReattachMode reattach = ReattachMode::kNone;
};

JobPlan make_plan(std::mt19937& rng, const Settings& settings, int client) {
  std::uniform_real_distribution<double> u(0.0, 1.0);
  JobPlan plan;
  const double pick = u(rng);
  plan.kind = pick < 0.40 ? Kind::kIsoSingle : pick < 0.75 ? Kind::kIsoSequence : Kind::kParticles;
  v1::JobSpec& spec = plan.spec;
  spec.set_name("load-c" + std::to_string(client));
  auto* output = spec.mutable_output();
  output->set_quantization_bits(std::uniform_int_distribution<int>(11, 16)(rng));
  if (u(rng) < 0.3) output->set_normals(true);
  if (u(rng) < 0.3) output->set_draco_speed(u(rng) < 0.5 ? 5 : 10);
  if (plan.kind == Kind::kParticles) {
    plan.frames = std::uniform_int_distribution<int>(1, 2)(rng);
    auto* job = spec.mutable_particles();
    for (int f = 0; f < plan.frames; ++f) {
      plan.particle_frames.push_back(particle_ball(rng, 0.1 * f, 0.2 * u(rng), 0.0, 0.25 + 0.1 * u(rng), 0.05));
      job->add_frames();  // upload ids are filled in after the uploads
    }
    job->set_r_inner(0.05);
    job->set_r_outer(0.1);
  } else {
    auto* job = spec.mutable_isosurface();
    const int family = std::uniform_int_distribution<int>(0, 4)(rng);
    const double a = u(rng), b = u(rng);
    if (plan.kind == Kind::kIsoSingle) {
      plan.frames = 1;
      *job->add_scenes() = make_scene(family, u(rng), a, b);
      job->set_cells(std::uniform_int_distribution<int>(40, 64)(rng));
    } else {
      plan.frames = std::uniform_int_distribution<int>(3, 5)(rng);
      for (int f = 0; f < plan.frames; ++f) *job->add_scenes() = make_scene(family, f / (plan.frames - 1.0), a, b);
      job->set_cells(std::uniform_int_distribution<int>(32, 48)(rng));
    }
    if (u(rng) < 0.2) job->set_method(v1::POLYGONIZER_CUBES);
  }
  if (u(rng) < settings.cancel_fraction) {
    plan.cancel = plan.frames > 1 && u(rng) < 0.5 ? CancelMode::kAfterFirstFrame : CancelMode::kImmediately;
  } else if (u(rng) < settings.reattach_fraction) {
    plan.reattach = plan.frames > 1 && u(rng) < 0.7 ? ReattachMode::kMidStream : ReattachMode::kAfterDone;
  }
  return plan;
}

// ---------------------------------------------------------------------------------------------------------------
// Watching

int state_rank(v1::JobState s) {
  switch (s) {
    case v1::JOB_STATE_QUEUED:
      return 1;
    case v1::JOB_STATE_RUNNING:
      return 2;
    case v1::JOB_STATE_SUCCEEDED:
    case v1::JOB_STATE_FAILED:
    case v1::JOB_STATE_CANCELLED:
      return 3;
    default:
      return 0;
  }
}

struct StreamResult {
  grpc::Status status;
  bool terminal = false;  // the terminal state arrived (and ended the stream)
  v1::Job final_job;
  std::set<int> frames;  // indices of frames received whole and verified
  bool stopped_early = false;
  bool broken = false;  // a corrupted frame or protocol error ended the stream
};

enum class Next { kContinue, kStop };

class Client {
 public:
  Client(int index, const Settings& settings, v1::Surfacer::Stub& stub, Shared& shared, Clock::time_point stop_at)
      : index_(index),
        settings_(settings),
        stub_(stub),
        shared_(shared),
        stop_at_(stop_at),
        rng_(settings.seed * 7919u + static_cast<unsigned>(index)) {}

  void run() {
    while (Clock::now() < stop_at_) run_job(make_plan(rng_, settings_, index_));
    timespec cpu{};
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &cpu);
    tally_.client_cpu = static_cast<double>(cpu.tv_sec) + cpu.tv_nsec * 1e-9;
  }

  const Tally& tally() const { return tally_; }

 private:
  void problem(const std::string& job, const std::string& what) {
    shared_.report("client " + std::to_string(index_) + (job.empty() ? "" : ", job " + job) + ": " + what);
  }

  // Decodes and checks one reassembled frame; false (and a counted corruption) when it is not a sound mesh.
  bool verify_frame(const std::string& job, const client::ReceivedFrame& frame) {
    std::string what;
    try {
      if (frame.encoding != v1::MESH_ENCODING_DRACO) {
        what = "encoding " + v1::MeshEncoding_Name(frame.encoding) + ", Draco was asked for";
      } else {
        const Mesh mesh = decode_draco(frame.bytes);
        const MeshReport report = check_mesh(mesh);
        if (mesh.triangles.empty()) {
          what = "decoded mesh is empty";
        } else if (static_cast<std::int64_t>(mesh.triangles.size()) != frame.stats.triangles()) {
          what = "decoded " + std::to_string(mesh.triangles.size()) + " triangles, the header says " +
                 std::to_string(frame.stats.triangles());
        } else if (!report.closed || !report.edge_manifold) {
          what = "decoded mesh is not closed and edge-manifold (" + std::to_string(report.boundary_edges) +
                 " boundary edges, " + std::to_string(report.non_manifold_edges) + " non-manifold edges)";
        } else if (!report.oriented || report.volume <= 0.0) {
          what = "decoded mesh is not consistently outward-oriented (volume " + std::to_string(report.volume) + ")";
        }
        tally_.triangles += static_cast<std::int64_t>(mesh.triangles.size());
      }
    } catch (const std::exception& e) {
      what = std::string("Draco decode failed: ") + e.what();
    }
    if (what.empty()) return true;
    ++tally_.corrupted;
    problem(job, "frame " + std::to_string(frame.index) + ": " + what);
    return false;
  }

  void protocol_error(const std::string& job, const std::string& what) {
    ++tally_.protocol;
    problem(job, what);
  }

  // One WatchJob stream from `from_frame`, to its end or until `on_frame` says stop.
  StreamResult watch(const std::string& job, int from_frame, int expected_frames, Clock::time_point deadline,
                     const std::function<Next(int)>& on_frame) {
    StreamResult result;
    grpc::ClientContext context;
    context.set_deadline(std::chrono::system_clock::now() +
                         std::chrono::duration_cast<std::chrono::system_clock::duration>(deadline - Clock::now()));
    v1::WatchJobRequest request;
    request.set_job_id(job);
    request.set_from_frame(from_frame);
    auto reader = stub_.WatchJob(&context, request);
    client::FrameAssembler assembler;
    v1::JobEvent event;
    int rank = 0;
    auto stop = [&](bool broken) {
      context.TryCancel();
      result.stopped_early = !broken;
      result.broken = broken;
    };
    while (reader->Read(&event)) {
      if (result.terminal) {
        protocol_error(job, "an event arrived after the terminal state");
        stop(true);
        break;
      }
      std::optional<client::ReceivedFrame> frame;
      try {
        switch (event.event_case()) {
          case v1::JobEvent::kState: {
            const int r = state_rank(event.state().state());
            if (r == 0 || r < rank) {
              protocol_error(job, "state " + v1::JobState_Name(event.state().state()) + " after a later state");
            }
            rank = std::max(rank, r);
            if (r == 3) {
              result.terminal = true;
              result.final_job = event.state();
              if (!assembler.idle()) protocol_error(job, "terminal state while a frame's chunks were still due");
            }
            break;
          }
          case v1::JobEvent::kProgress:
            break;
          case v1::JobEvent::kFrame: {
            const int i = event.frame().frame_index();
            if (i < from_frame || i >= expected_frames) {
              protocol_error(job, "frame " + std::to_string(i) + " outside [" + std::to_string(from_frame) + ", " +
                                      std::to_string(expected_frames) + ")");
            } else if (result.frames.count(i) != 0) {
              protocol_error(job, "frame " + std::to_string(i) + " sent twice in one stream");
            }
            frame = assembler.on_header(event.frame());
            break;
          }
          case v1::JobEvent::kChunk:
            frame = assembler.on_chunk(event.chunk());
            break;
          case v1::JobEvent::EVENT_NOT_SET:
            protocol_error(job, "an empty JobEvent");
            break;
        }
      } catch (const client::CliError& e) {  // CRC, size, chunk order: the frame is corrupted
        ++tally_.corrupted;
        problem(job, e.what());
        stop(true);
        break;
      }
      if (!frame) continue;
      ++tally_.frames;
      ++shared_.frames;
      tally_.frame_bytes += static_cast<std::int64_t>(frame->bytes.size());
      if (verify_frame(job, *frame)) result.frames.insert(frame->index);
      if (on_frame && on_frame(frame->index) == Next::kStop) {
        stop(false);
        break;
      }
    }
    while (reader->Read(&event)) {
    }
    result.status = reader->Finish();
    if (result.stopped_early || result.broken) return result;
    if (result.status.error_code() == grpc::StatusCode::DEADLINE_EXCEEDED) {
      protocol_error(job,
                     "the job did not finish within --job-timeout " + std::to_string(settings_.job_timeout) + " s");
    } else if (!result.status.ok()) {
      protocol_error(job, "WatchJob ended with " + std::to_string(result.status.error_code()) + ": " +
                              result.status.error_message());
    } else if (!result.terminal) {
      protocol_error(job, "WatchJob ended OK without a terminal state");
    }
    return result;
  }

  // RESOURCE_EXHAUSTED is retried (with backoff) until the run's end; returns false when the job was not submitted.
  bool submit(const JobPlan& plan, std::string& id, Clock::time_point& accepted_at) {
    std::uniform_real_distribution<double> jitter(0.5, 1.5);
    double backoff = 0.02;
    for (;;) {
      grpc::ClientContext context;
      context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(30));
      v1::SubmitJobRequest request;
      *request.mutable_spec() = plan.spec;
      v1::SubmitJobResponse response;
      const auto sent_at = Clock::now();
      const grpc::Status status = stub_.SubmitJob(&context, request, &response);
      if (status.ok()) {
        id = response.job_id();
        accepted_at = sent_at;
        ++tally_.submitted;
        return true;
      }
      if (status.error_code() != grpc::StatusCode::RESOURCE_EXHAUSTED) {
        ++tally_.failed;
        problem("", "SubmitJob (" + std::string(kKindNames[static_cast<int>(plan.kind)]) + ") answered " +
                        std::to_string(status.error_code()) + ": " + status.error_message());
        return false;
      }
      ++tally_.rejected;
      if (Clock::now() >= stop_at_) {
        ++tally_.abandoned;
        return false;
      }
      std::this_thread::sleep_for(std::chrono::duration<double>(backoff * jitter(rng_)));
      backoff = std::min(0.5, backoff * 2.0);
    }
  }

  void cancel(const std::string& id, Clock::time_point& cancelled_at) {
    grpc::ClientContext context;
    context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(30));
    v1::CancelJobRequest request;
    request.set_job_id(id);
    v1::Job job;
    cancelled_at = Clock::now();
    const grpc::Status status = stub_.CancelJob(&context, request, &job);
    ++tally_.cancel_requests;
    if (!status.ok()) {
      protocol_error(id, "CancelJob answered " + std::to_string(status.error_code()) + ": " + status.error_message());
    } else if (job.state() == v1::JOB_STATE_FAILED) {
      ++tally_.failed;
      problem(id, "CancelJob shows the job FAILED: " + job.error().message());
    }
  }

  bool upload_inputs(JobPlan& plan) {
    for (std::size_t f = 0; f < plan.particle_frames.size(); ++f) {
      try {
        client::UploadSettings upload;
        upload.deadline = std::chrono::system_clock::now() + std::chrono::seconds(60);
        const auto result =
            client::upload_bytes(stub_, "load_ball_" + std::to_string(f) + ".bin", plan.particle_frames[f], upload);
        plan.spec.mutable_particles()->mutable_frames(static_cast<int>(f))->set_upload_id(result.upload_id);
        ++tally_.uploads;
        tally_.upload_bytes += static_cast<std::int64_t>(plan.particle_frames[f].size());
      } catch (const std::exception& e) {
        ++tally_.failed;
        problem("", std::string("Upload of a particle frame failed: ") + e.what());
        return false;
      }
    }
    return true;
  }

  void run_job(JobPlan plan) {
    if (!upload_inputs(plan)) return;
    std::string id;
    Clock::time_point submitted_at;
    if (!submit(plan, id, submitted_at)) return;
    const int kind = static_cast<int>(plan.kind);
    const auto deadline = submitted_at + std::chrono::duration_cast<Clock::duration>(
                                             std::chrono::duration<double>(settings_.job_timeout));
    Clock::time_point cancelled_at{};
    bool cancel_sent = false;
    if (plan.cancel == CancelMode::kImmediately) {
      cancel(id, cancelled_at);
      cancel_sent = true;
    }
    bool first = true;
    const bool mid_stream = plan.reattach == ReattachMode::kMidStream;
    StreamResult stream = watch(id, 0, plan.frames, deadline, [&](int) {
      if (!first) return Next::kContinue;
      first = false;
      tally_.first_frame[kind].push_back(seconds_between(submitted_at, Clock::now()));
      if (plan.cancel == CancelMode::kAfterFirstFrame) {
        cancel(id, cancelled_at);
        cancel_sent = true;
      }
      return mid_stream ? Next::kStop : Next::kContinue;
    });
    std::set<int> received = stream.frames;
    if (stream.broken) {
      ++shared_.jobs_done;
      return;  // counted already; the job's outcome cannot be judged from this stream
    }
    if (stream.stopped_early) {
      // Re-attach from the first frame not yet received: every frame >= k must come, none below.
      int k = 0;
      while (received.count(k) != 0) ++k;
      ++tally_.reattach_mid;
      stream = watch(id, k, plan.frames, deadline, nullptr);
      if (stream.broken) {
        ++shared_.jobs_done;
        return;
      }
      tally_.reattach_frames += static_cast<std::int64_t>(stream.frames.size());
      if (stream.terminal && stream.final_job.state() == v1::JOB_STATE_SUCCEEDED) {
        for (int i = k; i < plan.frames; ++i) {
          if (stream.frames.count(i) == 0) {
            ++tally_.lost;
            problem(id, "re-attached with from_frame " + std::to_string(k) + " but frame " + std::to_string(i) +
                            " did not arrive");
          }
        }
      }
      received.insert(stream.frames.begin(), stream.frames.end());
    }
    ++shared_.jobs_done;
    if (!stream.terminal) return;  // already counted as a protocol error
    const auto done_at = Clock::now();
    const v1::Job& final_job = stream.final_job;
    switch (final_job.state()) {
      case v1::JOB_STATE_FAILED:
        ++tally_.failed;
        problem(id, std::string(kKindNames[kind]) + " job FAILED: " + final_job.error().message());
        return;
      case v1::JOB_STATE_CANCELLED:
        if (!cancel_sent) {
          ++tally_.failed;
          problem(id, "CANCELLED although nobody cancelled it: " + final_job.error().message());
          return;
        }
        ++tally_.cancelled;
        tally_.cancel_latency.push_back(seconds_between(cancelled_at, done_at));
        return;
      case v1::JOB_STATE_SUCCEEDED:
        break;
      default:
        protocol_error(id, "terminal state " + v1::JobState_Name(final_job.state()));
        return;
    }
    ++tally_.succeeded;
    if (cancel_sent) ++tally_.finished_before_cancel;
    tally_.done[kind].push_back(seconds_between(submitted_at, done_at));
    if (final_job.frames_total() != plan.frames || final_job.frames_done() != plan.frames) {
      protocol_error(id, "SUCCEEDED with frames_done/frames_total " + std::to_string(final_job.frames_done()) + "/" +
                             std::to_string(final_job.frames_total()) + ", expected " + std::to_string(plan.frames));
    }
    for (int i = 0; i < plan.frames; ++i) {
      if (received.count(i) == 0) {
        ++tally_.lost;
        problem(id, "frame " + std::to_string(i) + " of a SUCCEEDED job never arrived (intact)");
      }
    }
    if (plan.reattach == ReattachMode::kAfterDone) {
      const int k = std::uniform_int_distribution<int>(0, plan.frames)(rng_);
      ++tally_.reattach_done;
      const StreamResult again = watch(id, k, plan.frames, Clock::now() + std::chrono::seconds(60), nullptr);
      if (again.broken || !again.terminal) return;
      tally_.reattach_frames += static_cast<std::int64_t>(again.frames.size());
      if (again.final_job.state() != v1::JOB_STATE_SUCCEEDED) {
        protocol_error(id,
                       "re-attached after SUCCEEDED, the stream says " + v1::JobState_Name(again.final_job.state()));
      }
      for (int i = k; i < plan.frames; ++i) {
        if (again.frames.count(i) == 0) {
          ++tally_.lost;
          problem(id, "re-attached after the end with from_frame " + std::to_string(k) + ": frame " +
                          std::to_string(i) + " did not arrive");
        }
      }
    }
  }

  const int index_;
  const Settings& settings_;
  v1::Surfacer::Stub& stub_;
  Shared& shared_;
  const Clock::time_point stop_at_;
  std::mt19937 rng_;
  Tally tally_;
};

// ---------------------------------------------------------------------------------------------------------------
// Report

double percentile(std::vector<double> v, double p) {
  if (v.empty()) return std::nan("");
  std::sort(v.begin(), v.end());
  const auto rank = static_cast<std::size_t>(std::ceil(p / 100.0 * static_cast<double>(v.size())));
  return v[std::min(v.size() - 1, rank == 0 ? 0 : rank - 1)];
}

std::string ms(double seconds) {
  if (std::isnan(seconds)) return "-";
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.1f", seconds * 1e3);
  return buf;
}

void latency_row(const char* name, const std::vector<double>& v) {
  std::printf("  %-28s %7zu %9s %9s %9s %9s\n", name, v.size(), ms(percentile(v, 50)).c_str(),
              ms(percentile(v, 90)).c_str(), ms(percentile(v, 99)).c_str(), ms(percentile(v, 100)).c_str());
}

double process_cpu(double* user, double* sys) {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  *user = static_cast<double>(usage.ru_utime.tv_sec) + usage.ru_utime.tv_usec * 1e-6;
  *sys = static_cast<double>(usage.ru_stime.tv_sec) + usage.ru_stime.tv_usec * 1e-6;
  return *user + *sys;
}

std::string load_average() {
  std::ifstream in("/proc/loadavg");
  std::string one, five, fifteen;
  if (!(in >> one >> five >> fifteen)) return "unknown";
  return one + " " + five + " " + fifteen;
}

constexpr const char* kUsage =
    "usage: load_bench [--clients N] [--seconds S] [--cancel-fraction P] [--reattach-fraction P] [--workers W]\n"
    "                  [--max-queued-jobs Q] [--data-dir DIR] [--server HOST:PORT] [--seed N] [--job-timeout S]\n"
    "                  [--server-logs]\n";

void print_help() {
  std::fputs(R"(
Load test: concurrent clients submit, watch, re-attach to and cancel small jobs on a real server over TCP for a
fixed time; every frame is CRC-checked, Draco-decoded and mesh-checked.

  --clients N            concurrent client threads, 1 to 1024 (default 8)
  --seconds S            how long clients start new jobs (in-flight jobs then finish), 0.1 to 86400 (default 20)
  --cancel-fraction P    share of jobs cancelled (at once or after frame 0), 0 to 1 (default 0.2)
  --reattach-fraction P  share of the other jobs watched again with from_frame = k (mid-stream or after the end),
                         0 to 1 (default 0.25)
  --workers W            embedded server's worker threads, 0 to 1024 (default 0: hardware)
  --max-queued-jobs Q    embedded server's queue length (beyond it SubmitJob answers RESOURCE_EXHAUSTED),
                         1 to 1000000 (default 64)
  --data-dir DIR         embedded server's durable store (SQLite + files; created if missing; default: memory only)
  --server-logs          keep the embedded server's info logs on stderr
  --server HOST:PORT     a running server instead of the embedded one (none of the four flags above with it)
  --seed N               seed of the job mix (client i uses a stream derived from it; default 1)
  --job-timeout S        a job not finished this many seconds after submit fails, 1 to 86400 (default 120)

Examples:
  load_bench --seconds 30 --clients 32                 # embedded server on 127.0.0.1:<free port>
  load_bench --max-queued-jobs 2 --clients 16          # provoke RESOURCE_EXHAUSTED backpressure
  load_bench --data-dir /tmp/load-store                # embedded server with the durable store
  load_bench --server 127.0.0.1:50051 --seconds 60     # against a running surfacer-server
Exit codes: 0 all checks passed, 1 failures (listed), 2 bad flags, 3 --server unreachable.
)",
             stdout);
}

}  // namespace

int main(int argc, char** argv) {
  Settings settings;
  std::string embedded_flag;  // the last flag given that configures the embedded server, which --server replaces
  bench::Args args(argc, argv, "load_bench", kUsage, print_help);
  while (args.next()) {
    const std::string& flag = args.flag();
    if (flag == "--clients") {
      settings.clients = args.integer(1, 1024);
    } else if (flag == "--seconds") {
      settings.seconds = args.number({.min = 0.1, .max = 86400.0});
    } else if (flag == "--cancel-fraction") {
      settings.cancel_fraction = args.number({.min = 0.0, .max = 1.0});
    } else if (flag == "--reattach-fraction") {
      settings.reattach_fraction = args.number({.min = 0.0, .max = 1.0});
    } else if (flag == "--workers") {
      settings.workers = args.integer(0, 1024);
      embedded_flag = flag;
    } else if (flag == "--max-queued-jobs") {
      settings.max_queued_jobs = args.integer(1, 1000000);
      embedded_flag = flag;
    } else if (flag == "--data-dir") {
      settings.data_dir = args.value("a directory");
      embedded_flag = flag;
    } else if (flag == "--server-logs") {
      settings.server_logs = true;
      embedded_flag = flag;
    } else if (flag == "--server") {
      settings.server = args.value("HOST:PORT");
      if (settings.server.empty()) args.error("--server needs HOST:PORT, got ''");
    } else if (flag == "--seed") {
      settings.seed = args.integer<unsigned>(0);
    } else if (flag == "--job-timeout") {
      settings.job_timeout = args.number({.min = 1.0, .max = 86400.0});
    } else {
      args.unknown();
    }
  }
  if (!settings.server.empty() && !embedded_flag.empty()) {
    args.error(embedded_flag +
               " configures the embedded server and cannot be combined with --server; drop it, or give it to the "
               "remote surfacer-server instead");
  }

  std::unique_ptr<server::SurfacerServer> embedded;
  std::string address = settings.server;
  int workers_used = 0;
  if (address.empty()) {
    if (!settings.server_logs) server::set_log_level(server::LogLevel::kWarn);
    server::ServerOptions options;
    options.listen = "127.0.0.1:0";
    options.workers = settings.workers;
    options.max_queued_jobs = settings.max_queued_jobs;
    options.data_dir = settings.data_dir;
    try {
      embedded = server::SurfacerServer::start(options);
    } catch (const std::exception& e) {
      std::fprintf(stderr, "load_bench: cannot start the embedded server: %s\n", e.what());
      return 2;
    }
    address = "127.0.0.1:" + std::to_string(embedded->port());
    workers_used =
        settings.workers > 0 ? settings.workers : std::max(1, static_cast<int>(std::thread::hardware_concurrency()));
  }
  // One channel (one HTTP/2 connection) per client: like independent users, and no single connection's flow control
  // serializes the streams.
  std::vector<std::shared_ptr<grpc::Channel>> channels;
  std::vector<std::unique_ptr<v1::Surfacer::Stub>> stubs;
  for (int i = 0; i < settings.clients; ++i) {
    grpc::ChannelArguments args;
    args.SetInt("load_bench_client", i);  // distinct arguments: a separate subchannel (connection) per client
    channels.push_back(grpc::CreateCustomChannel(address, grpc::InsecureChannelCredentials(), args));
    if (!channels.back()->WaitForConnected(std::chrono::system_clock::now() + std::chrono::seconds(10))) {
      std::fprintf(stderr, "load_bench: cannot connect to %s within 10 s; check --server\n", address.c_str());
      return 3;
    }
    stubs.push_back(v1::Surfacer::NewStub(channels.back()));
  }

  std::printf("load_bench: %d clients for %.1f s against %s (%s), cancel %.2f, re-attach %.2f, seed %u\n",
              settings.clients, settings.seconds, address.c_str(),
              embedded ? ("embedded server, " + std::to_string(workers_used) + " workers, max " +
                          std::to_string(settings.max_queued_jobs) + " queued jobs, " +
                          (settings.data_dir.empty() ? std::string("memory only") : "data dir " + settings.data_dir))
                             .c_str()
                       : "remote server",
              settings.cancel_fraction, settings.reattach_fraction, settings.seed);
  std::printf("  %u hardware threads, load average before: %s\n", std::thread::hardware_concurrency(),
              load_average().c_str());
  std::fflush(stdout);

  Shared shared;
  double user0 = 0, sys0 = 0;
  const double cpu0 = process_cpu(&user0, &sys0);
  const auto start = Clock::now();
  const auto stop_at =
      start + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(settings.seconds));
  std::vector<std::unique_ptr<Client>> clients;
  for (int i = 0; i < settings.clients; ++i) {
    clients.push_back(std::make_unique<Client>(i, settings, *stubs[i], shared, stop_at));
  }
  std::atomic<int> running{settings.clients};
  std::vector<std::thread> threads;
  for (auto& c : clients) {
    threads.emplace_back([&c, &running] {
      c->run();
      --running;
    });
  }
  // A progress line on stderr every 5 s.
  auto next_line = start + std::chrono::seconds(5);
  while (running.load() > 0) {
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
    if (Clock::now() >= next_line) {
      std::fprintf(stderr, "load_bench: %5.1f s  jobs done %lld  frames %lld  problems %lld%s\n",
                   seconds_between(start, Clock::now()), static_cast<long long>(shared.jobs_done.load()),
                   static_cast<long long>(shared.frames.load()), static_cast<long long>(shared.problems.load()),
                   Clock::now() >= stop_at ? "  (finishing jobs in flight)" : "");
      next_line += std::chrono::seconds(5);
    }
  }
  for (auto& t : threads) t.join();
  const double wall = seconds_between(start, Clock::now());
  double user1 = 0, sys1 = 0;
  const double cpu1 = process_cpu(&user1, &sys1);

  Tally total;
  for (const auto& c : clients) total.merge(c->tally());
  std::vector<double> first_all, done_all;
  for (int k = 0; k < kKinds; ++k) {
    first_all.insert(first_all.end(), total.first_frame[k].begin(), total.first_frame[k].end());
    done_all.insert(done_all.end(), total.done[k].begin(), total.done[k].end());
  }
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);

  const auto finished = total.succeeded + total.cancelled + total.failed;
  std::printf("\n  %-34s %12s\n", "counts", "");
  std::printf("  %-34s %12lld\n", "jobs submitted", static_cast<long long>(total.submitted));
  std::printf("  %-34s %12lld\n", "  succeeded", static_cast<long long>(total.succeeded));
  std::printf("  %-34s %12lld\n", "  cancelled", static_cast<long long>(total.cancelled));
  std::printf("  %-34s %12lld   (must be 0)\n", "  failed", static_cast<long long>(total.failed));
  std::printf("  %-34s %12lld   (%lld finished before the cancel)\n", "cancel requests",
              static_cast<long long>(total.cancel_requests), static_cast<long long>(total.finished_before_cancel));
  std::printf("  %-34s %12lld   (retried; %lld still refused at the end)\n", "RESOURCE_EXHAUSTED rejections",
              static_cast<long long>(total.rejected), static_cast<long long>(total.abandoned));
  std::printf("  %-34s %12lld   (%.2f MB)\n", "uploads", static_cast<long long>(total.uploads),
              total.upload_bytes / 1e6);
  std::printf("  %-34s %12lld   (%.2f MB, %.2f M triangles)\n", "frames received and verified",
              static_cast<long long>(total.frames), total.frame_bytes / 1e6, total.triangles / 1e6);
  std::printf("  %-34s %12lld   (%lld mid-stream, %lld after the end; %lld frames)\n", "re-attaches (from_frame k)",
              static_cast<long long>(total.reattach_mid + total.reattach_done),
              static_cast<long long>(total.reattach_mid), static_cast<long long>(total.reattach_done),
              static_cast<long long>(total.reattach_frames));
  std::printf("  %-34s %12lld   (must be 0)\n", "frames lost", static_cast<long long>(total.lost));
  std::printf("  %-34s %12lld   (must be 0)\n", "frames corrupted (CRC/decode/mesh)",
              static_cast<long long>(total.corrupted));
  std::printf("  %-34s %12lld   (must be 0)\n", "protocol errors", static_cast<long long>(total.protocol));

  std::printf("\n  %-34s %12s\n", "throughput", "");
  std::printf("  %-34s %12.2f   (%lld jobs finished in %.2f s, including the in-flight tail)\n", "jobs/s",
              finished / wall, static_cast<long long>(finished), wall);
  std::printf("  %-34s %12.2f\n", "frames/s", total.frames / wall);
  std::printf("  %-34s %12.3f\n", "MB/s (frame bytes received)", total.frame_bytes / 1e6 / wall);

  std::printf("\n  %-28s %7s %9s %9s %9s %9s\n", "latency (ms) from SubmitJob", "n", "p50", "p90", "p99", "max");
  latency_row("to first frame, all", first_all);
  for (int k = 0; k < kKinds; ++k) {
    latency_row(("  " + std::string(kKindNames[k])).c_str(), total.first_frame[k]);
  }
  latency_row("to SUCCEEDED, all", done_all);
  for (int k = 0; k < kKinds; ++k) latency_row(("  " + std::string(kKindNames[k])).c_str(), total.done[k]);
  latency_row("CancelJob to CANCELLED", total.cancel_latency);

  const double cpu = cpu1 - cpu0;
  std::printf("\n  %-34s %12s\n", "CPU", "");
  std::printf("  %-34s %12.2f   (user %.2f, sys %.2f; %.2f cores busy on average)\n", "process CPU s", cpu,
              user1 - user0, sys1 - sys0, cpu / wall);
  std::printf("  %-34s %12.2f   (submit, watch, CRC, Draco decode, mesh checks)\n", "  client threads",
              total.client_cpu);
  std::printf("  %-34s %12.2f   (%s)\n", "  rest", cpu - total.client_cpu,
              embedded ? "embedded server: workers, gRPC" : "gRPC client threads");
  if (finished > 0) std::printf("  %-34s %12.1f\n", "process CPU ms per finished job", cpu / finished * 1e3);
  std::printf("  %-34s %12.1f\n", "peak RSS MB", usage.ru_maxrss / 1024.0);
  std::printf("  load average after: %s\n", load_average().c_str());

  std::vector<std::string> reasons;
  if (total.failed > 0) reasons.push_back(std::to_string(total.failed) + " job(s) failed");
  if (total.lost > 0) reasons.push_back(std::to_string(total.lost) + " frame(s) lost");
  if (total.corrupted > 0) reasons.push_back(std::to_string(total.corrupted) + " frame(s) corrupted");
  if (total.protocol > 0) reasons.push_back(std::to_string(total.protocol) + " protocol error(s)");
  if (total.succeeded == 0) reasons.push_back("no job succeeded, so nothing was verified end to end");
  if (reasons.empty()) {
    std::printf("\nPASS: no job failed, no frame lost or corrupted\n");
    return 0;
  }
  std::printf("\nFAIL:");
  for (const auto& r : reasons) std::printf(" %s;", r.c_str());
  std::printf("\n");
  std::lock_guard lock(shared.mutex);
  for (const auto& m : shared.messages) std::printf("  %s\n", m.c_str());
  if (shared.messages_dropped > 0) {
    std::printf("  ... and %lld more\n", static_cast<long long>(shared.messages_dropped));
  }
  return 1;
}
