// Open particle sequences (ParticlesJob.open + AppendFrames): frames join a running job and are computed as they
// arrive, the end marker finishes it, a client that goes quiet fails it naming --upload-idle-timeout, a cancel while
// it waits for frames frees it at once, and on a --data-dir server it survives kill -9 with the frames it had.
#include <gtest/gtest.h>

#include <chrono>
#include <cstring>
#include <filesystem>
#include <thread>

#include "server/job.h"
#include "server/runners/runner.h"
#include "tests/server/test_client.h"
#include "tests/support/files.h"
#include "tests/support/server_process.h"
#include "tests/support/test_meshes.h"

namespace surfacer::testing {
namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;

constexpr double kSpacing = 0.05;

std::string as_float32(const std::vector<Vec3>& points) {
  std::string bytes(points.size() * 3 * sizeof(float), '\0');
  char* out = bytes.data();
  for (const Vec3& p : points) {
    for (int a = 0; a < 3; ++a) {
      const auto value = static_cast<float>(p[a]);
      std::memcpy(out, &value, sizeof value);
      out += sizeof value;
    }
  }
  return bytes;
}

// Frame k of a droplet that drifts along x: uploaded, as a ParticleFrame.
v1::ParticleFrame droplet(v1::Surfacer::Stub& stub, int k) {
  v1::ParticleFrame frame;
  frame.set_upload_id(
      upload(stub, as_float32(particle_ball(Vec3(0.02 * k, 0, 0), 0.2, kSpacing, static_cast<unsigned>(k + 1)))));
  return frame;
}

// An open particles job starting with `first`.
v1::JobSpec open_spec(const v1::ParticleFrame& first) {
  v1::JobSpec spec;
  v1::ParticlesJob* job = spec.mutable_particles();
  *job->add_frames() = first;
  job->set_r_inner(kSpacing);
  job->set_open(true);
  return spec;
}

grpc::Status append(v1::Surfacer::Stub& stub, const std::string& id, const std::vector<v1::ParticleFrame>& frames,
                    bool end, v1::Job* answer = nullptr, const std::string& abort_reason = "") {
  grpc::ClientContext context;
  context.set_deadline(std::chrono::system_clock::now() + 30s);
  v1::AppendFramesRequest request;
  request.set_job_id(id);
  for (const auto& f : frames) *request.add_frames() = f;
  request.set_end(end);
  request.set_abort_reason(abort_reason);
  v1::Job job;
  const grpc::Status status = stub.AppendFrames(&context, request, &job);
  if (answer) *answer = job;
  return status;
}

// Polls GetJob until `done` frames are done (or 60 s pass); the last snapshot.
v1::Job wait_frames(v1::Surfacer::Stub& stub, const std::string& id, int done) {
  const auto until = std::chrono::steady_clock::now() + 60s;
  v1::Job job = get_job(stub, id);
  while (job.frames_done() < done && std::chrono::steady_clock::now() < until) {
    std::this_thread::sleep_for(10ms);
    job = get_job(stub, id);
  }
  return job;
}

TEST(OpenSequence, FramesJoinARunningJobUntilTheEndMarker) {
  LoopbackServer s;
  std::string id;
  ASSERT_TRUE(submit(*s.stub, open_spec(droplet(*s.stub, 0)), &id).ok());
  // Frame 0 is surfaced before any other frame exists, and the job waits, running, for more.
  v1::Job job = wait_frames(*s.stub, id, 1);
  EXPECT_EQ(job.frames_done(), 1);
  std::this_thread::sleep_for(100ms);
  job = get_job(*s.stub, id);
  EXPECT_EQ(job.state(), v1::JOB_STATE_RUNNING);
  EXPECT_EQ(job.frames_total(), 1);

  v1::Job answer;
  ASSERT_TRUE(append(*s.stub, id, {droplet(*s.stub, 1)}, false, &answer).ok());
  EXPECT_EQ(answer.frames_total(), 2);
  // A frame the job would refuse is refused by name, and the job goes on.
  v1::ParticleFrame unknown;
  unknown.set_upload_id("u-0000000000000000");
  const grpc::Status refused = append(*s.stub, id, {unknown}, false);
  EXPECT_EQ(refused.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(refused.error_message().find("frames[0]"), std::string::npos) << refused.error_message();
  // One that would leave the quantization box fixed by frame 0 names the field that fixes it.
  v1::ParticleFrame far;
  far.set_upload_id(upload(*s.stub, as_float32(particle_ball(Vec3(5, 0, 0), 0.2, kSpacing, 9))));
  const grpc::Status outside = append(*s.stub, id, {far}, false);
  EXPECT_EQ(outside.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(outside.error_message().find("quantization_bounds"), std::string::npos) << outside.error_message();

  ASSERT_TRUE(append(*s.stub, id, {droplet(*s.stub, 2), droplet(*s.stub, 3)}, true).ok());
  const WatchResult r = watch_job(*s.stub, id);
  EXPECT_TRUE(r.integrity_error.empty()) << r.integrity_error;
  ASSERT_EQ(r.final_job.state(), v1::JOB_STATE_SUCCEEDED) << r.final_job.error().message();
  EXPECT_EQ(r.final_job.frames_total(), 4);
  ASSERT_EQ(r.frames.size(), 4u);
  for (const auto& [index, frame] : r.frames) EXPECT_GT(frame.header.stats().triangles(), 100) << "frame " << index;

  // After the end marker nothing joins; nor does anything join a job that was not submitted open.
  EXPECT_EQ(append(*s.stub, id, {droplet(*s.stub, 4)}, false).error_code(), grpc::StatusCode::FAILED_PRECONDITION);
  v1::JobSpec closed = open_spec(droplet(*s.stub, 0));
  closed.mutable_particles()->set_open(false);
  std::string closed_id;
  ASSERT_TRUE(submit(*s.stub, closed, &closed_id).ok());
  const grpc::Status not_open = append(*s.stub, closed_id, {droplet(*s.stub, 1)}, false);
  EXPECT_EQ(not_open.error_code(), grpc::StatusCode::FAILED_PRECONDITION);
  EXPECT_NE(not_open.error_message().find("not an open sequence"), std::string::npos) << not_open.error_message();
  EXPECT_EQ(watch_job(*s.stub, closed_id).final_job.frames_total(), 1);
}

// A runner of one frame per task that takes appended frames; the test drives the job's transitions itself.
class OpenRunner : public server::JobRunner {
 public:
  std::string kind() const override { return "particles"; }
  int task_count() const override { return 1; }
  int frame_count() const override { return 1; }
  void run_task(int, server::FrameSink&, const RunControl&) override {}
  bool open() const override { return true; }
  void check_appended(const google::protobuf::RepeatedPtrField<v1::ParticleFrame>&, const std::string&) const override {
  }
};

// A watcher that looks only now and then (a busy stream) must never get a frame beyond the frames_total it has been
// told, even when the sequence's last frames joined and were surfaced, and the job finished, between two looks: the
// client takes such a frame for a broken server. Driven on the Job itself, so the interleaving is exact.
TEST(OpenSequence, NoFrameReachesAWatcherBeyondTheTotalItWasTold) {
  for (const int last_batch : {1, 3}) {
    server::JobInit init;
    init.id = "j-open";
    init.runner = std::make_unique<OpenRunner>();
    init.spec = open_spec(v1::ParticleFrame());
    server::Job job(std::move(init));
    server::WatchCursor cursor;
    int told = 0;
    std::vector<int> frames;
    const auto look = [&] {
      v1::JobEvent event;
      while (job.next_event(cursor, event)) {
        if (event.has_state()) told = std::max(told, event.state().frames_total());
        if (event.has_progress()) told = std::max(told, event.progress().frames_total());
        if (event.has_frame()) {
          EXPECT_LT(event.frame().frame_index(), told) << "batch of " << last_batch;
          frames.push_back(event.frame().frame_index());
        }
      }
    };
    const auto surface = [&](int task) {
      ASSERT_TRUE(job.task_started());
      server::FrameOutput output;
      output.bytes = "mesh " + std::to_string(task);
      job.emit(task, std::move(output));
      job.task_succeeded(task);
    };
    surface(0);
    look();
    v1::AppendFramesRequest more;
    more.set_job_id("j-open");
    more.add_frames();
    std::vector<int> tasks;
    ASSERT_TRUE(job.append_frames(more, tasks).ok());
    surface(1);
    look();
    ASSERT_EQ(told, 2);
    more.clear_frames();
    for (int i = 0; i < last_batch; ++i) more.add_frames();
    more.set_end(true);
    tasks.clear();
    ASSERT_TRUE(job.append_frames(more, tasks).ok());
    for (const int task : tasks) surface(task);
    ASSERT_EQ(job.state(), v1::JOB_STATE_SUCCEEDED);
    look();  // the watcher's first look since frame 1
    EXPECT_EQ(static_cast<int>(frames.size()), 2 + last_batch);
    EXPECT_EQ(told, 2 + last_batch);
  }
}

TEST(OpenSequence, AnEndWithoutFramesFinishesAndAnAbortFails) {
  LoopbackServer s;
  std::string ended, aborted;
  ASSERT_TRUE(submit(*s.stub, open_spec(droplet(*s.stub, 0)), &ended).ok());
  ASSERT_TRUE(submit(*s.stub, open_spec(droplet(*s.stub, 0)), &aborted).ok());
  ASSERT_TRUE(append(*s.stub, ended, {}, true).ok());
  ASSERT_TRUE(append(*s.stub, aborted, {}, false, nullptr, "frame 1: the simulation crashed").ok());
  const WatchResult e = watch_job(*s.stub, ended);
  EXPECT_EQ(e.final_job.state(), v1::JOB_STATE_SUCCEEDED);
  EXPECT_EQ(e.frames.size(), 1u);
  const WatchResult a = watch_job(*s.stub, aborted);
  EXPECT_EQ(a.final_job.state(), v1::JOB_STATE_FAILED);
  EXPECT_NE(a.final_job.error().message().find("the simulation crashed"), std::string::npos)
      << a.final_job.error().message();
}

// An abort right after frames joined: they are still computed and kept, then the job fails with the reason.
TEST(OpenSequence, AnAbortKeepsTheFramesTakenAndThenFails) {
  LoopbackServer s;
  std::string id;
  ASSERT_TRUE(submit(*s.stub, open_spec(droplet(*s.stub, 0)), &id).ok());
  ASSERT_TRUE(append(*s.stub, id, {droplet(*s.stub, 1), droplet(*s.stub, 2)}, false).ok());
  ASSERT_TRUE(append(*s.stub, id, {}, false, nullptr, "frame 3: particle 7 is NaN").ok());
  EXPECT_EQ(append(*s.stub, id, {droplet(*s.stub, 3)}, false).error_code(), grpc::StatusCode::FAILED_PRECONDITION);
  const WatchResult r = watch_job(*s.stub, id);
  EXPECT_EQ(r.final_job.state(), v1::JOB_STATE_FAILED);
  EXPECT_NE(r.final_job.error().message().find("after 3 frames: frame 3: particle 7 is NaN"), std::string::npos)
      << r.final_job.error().message();
  ASSERT_EQ(r.frames.size(), 3u);
  for (int i = 0; i < 3; ++i) EXPECT_TRUE(r.frames.count(i)) << "frame " << i;
}

// A client that disconnects mid-sequence (no frame, no end) fails its job after --upload-idle-timeout instead of
// leaving it waiting forever; an upload in progress counts as activity.
TEST(OpenSequence, AQuietClientFailsTheJobNamingTheIdleTimeout) {
  auto options = LoopbackServer::default_options();
  options.upload_idle_timeout = 1500ms;
  LoopbackServer s(options);
  std::string id;
  ASSERT_TRUE(submit(*s.stub, open_spec(droplet(*s.stub, 0)), &id).ok());
  // Uploads keep it alive past the timeout.
  const auto start = std::chrono::steady_clock::now();
  while (std::chrono::steady_clock::now() - start < 2500ms) {
    upload(*s.stub, as_float32(particle_ball(Vec3(0, 0, 0), 0.1, kSpacing, 5)));
    std::this_thread::sleep_for(200ms);
  }
  EXPECT_FALSE(get_job(*s.stub, id).state() == v1::JOB_STATE_FAILED) << get_job(*s.stub, id).error().message();
  const auto quiet = std::chrono::steady_clock::now();
  const WatchResult r = watch_job(*s.stub, id);
  const double waited = std::chrono::duration<double>(std::chrono::steady_clock::now() - quiet).count();
  EXPECT_EQ(r.final_job.state(), v1::JOB_STATE_FAILED);
  EXPECT_EQ(r.final_job.error().code(), static_cast<int>(grpc::StatusCode::DEADLINE_EXCEEDED));
  EXPECT_NE(r.final_job.error().message().find("--upload-idle-timeout"), std::string::npos)
      << r.final_job.error().message();
  EXPECT_EQ(r.frames.size(), 1u);  // the frame done before is kept
  EXPECT_LT(waited, 10.0);
}

// A cancel while the job waits for frames finishes it at once (no task holds a worker), and the worker takes the
// next job.
TEST(OpenSequence, CancelWhileWaitingForFramesFinishesAtOnce) {
  auto options = LoopbackServer::default_options();
  options.workers = 1;
  LoopbackServer s(options);
  std::string id;
  ASSERT_TRUE(submit(*s.stub, open_spec(droplet(*s.stub, 0)), &id).ok());
  ASSERT_EQ(wait_frames(*s.stub, id, 1).frames_done(), 1);
  const auto start = std::chrono::steady_clock::now();
  ASSERT_TRUE(cancel_job(*s.stub, id).ok());
  v1::Job job = get_job(*s.stub, id);
  while (job.state() != v1::JOB_STATE_CANCELLED && std::chrono::steady_clock::now() - start < 5s) {
    std::this_thread::sleep_for(5ms);
    job = get_job(*s.stub, id);
  }
  EXPECT_EQ(job.state(), v1::JOB_STATE_CANCELLED);
  EXPECT_LT(std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count(), 0.5);
  EXPECT_EQ(append(*s.stub, id, {droplet(*s.stub, 1)}, false).error_code(), grpc::StatusCode::FAILED_PRECONDITION);
  // The one worker is free: a closed job runs to the end.
  v1::JobSpec next = open_spec(droplet(*s.stub, 1));
  next.mutable_particles()->set_open(false);
  std::string next_id;
  ASSERT_TRUE(submit(*s.stub, next, &next_id).ok());
  EXPECT_EQ(watch_job(*s.stub, next_id).final_job.state(), v1::JOB_STATE_SUCCEEDED);
}

// kill -9 while a sequence is open: the restarted server has the job with the frames it had taken (done ones kept,
// the others computed again), takes the rest, and ends it; one whose client does not come back fails naming
// --upload-idle-timeout rather than waiting forever.
TEST(OpenSequence, KillNineMidSequenceResumesWithTheFramesAlreadyUploaded) {
  const fs::path dir = fresh_temp_dir("open-sequence-kill9");
  const fs::path data = dir / "data";
  const std::vector<std::string> flags = {"--data-dir", data.string(), "--upload-idle-timeout", "3"};
  std::string id, abandoned;
  {
    ServerProcess p(dir, 1, flags);
    ASSERT_GT(p.port(), 0) << p.log();
    auto stub = make_stub(p.address());
    ASSERT_TRUE(submit(*stub, open_spec(droplet(*stub, 0)), &id).ok());
    ASSERT_TRUE(submit(*stub, open_spec(droplet(*stub, 0)), &abandoned).ok());
    ASSERT_TRUE(append(*stub, id, {droplet(*stub, 1), droplet(*stub, 2)}, false).ok());
    ASSERT_GE(wait_frames(*stub, id, 1).frames_done(), 1) << p.log();
    p.kill_now();
  }
  ServerProcess p(dir, 1, flags);
  ASSERT_GT(p.port(), 0) << p.log();
  auto stub = make_stub(p.address());
  const v1::Job resumed = get_job(*stub, id);
  EXPECT_FALSE(resumed.state() == v1::JOB_STATE_FAILED || resumed.state() == v1::JOB_STATE_SUCCEEDED)
      << resumed.error().message();
  EXPECT_EQ(resumed.frames_total(), 3);
  ASSERT_TRUE(append(*stub, id, {droplet(*stub, 3)}, true).ok()) << p.log();
  const WatchResult r = watch_job(*stub, id);
  EXPECT_TRUE(r.integrity_error.empty()) << r.integrity_error;
  ASSERT_EQ(r.final_job.state(), v1::JOB_STATE_SUCCEEDED) << r.final_job.error().message() << p.log();
  ASSERT_EQ(r.frames.size(), 4u);
  for (int i = 0; i < 4; ++i) EXPECT_TRUE(r.frames.count(i)) << "frame " << i;

  const WatchResult gone = watch_job(*stub, abandoned);
  EXPECT_EQ(gone.final_job.state(), v1::JOB_STATE_FAILED);
  EXPECT_NE(gone.final_job.error().message().find("--upload-idle-timeout"), std::string::npos)
      << gone.final_job.error().message();
}

}  // namespace
}  // namespace surfacer::testing
