// Checkpoints of the evolving jobs (optimize, active): a runner resumed from the state it saved after frame k - 1
// emits frames k.. exactly as the uninterrupted run and nothing before k; a killed server (SIGKILL) resumes an active
// job from its last checkpoint and finishes with every frame.
#include <gtest/gtest.h>

#include <chrono>
#include <filesystem>
#include <map>
#include <mutex>
#include <thread>

#include "server/runners/runner.h"
#include "server/uploads.h"
#include "tests/server/test_client.h"
#include "tests/support/files.h"
#include "tests/support/server_process.h"

namespace surfacer::testing {
namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;

struct RecordingSink final : server::FrameSink {
  std::mutex mutex;
  std::map<int, std::string> frames;       // index -> encoded bytes
  std::map<int, double> iterations;        // index -> the frame's iteration (optimize) or time (active)
  std::map<int, std::string> checkpoints;  // next frame -> state
  std::vector<int> order;

  void emit(int index, server::FrameOutput out) override {
    std::lock_guard lock(mutex);
    order.push_back(index);
    const auto& m = out.stats.metrics();
    iterations[index] = m.count("time") ? m.at("time") : out.stats.iteration();
    frames[index] = std::move(out.bytes);
  }
  void checkpoint(int task, int next_frame, std::string state) override {
    std::lock_guard lock(mutex);
    EXPECT_EQ(task, 0);
    checkpoints[next_frame] = std::move(state);
  }
};

struct Runners {
  server::Limits limits;
  server::UploadStore uploads;
  std::unique_ptr<server::JobRunner> make(const v1::JobSpec& spec) {
    return server::make_job_runner(spec, server::JobContext{limits, uploads, 2});
  }
};

v1::JobSpec optimize_spec() {
  v1::JobSpec spec;
  auto* job = spec.mutable_optimize();
  *job->mutable_scene() = scene_from_json(R"({"root": {"box": {"half_size": {"x": 0.5, "y": 0.4, "z": 0.3}}}})");
  job->mutable_polygonize()->set_cells(20);
  job->set_max_iterations(30);
  job->set_snapshot_every(5);
  job->set_subdivision_threshold(0.0005);
  return spec;
}

v1::JobSpec advect_spec(double h, int frames, double interval) {
  v1::JobSpec spec;
  auto* job = spec.mutable_active();
  job->set_grid_spacing(h);
  auto* advect = job->mutable_advect();
  *advect->mutable_shape() =
      scene_from_json(R"({"root": {"sphere": {"center": {"x": 0.35, "y": 0.35, "z": 0.35}, "radius": 0.15}}})");
  advect->mutable_enright()->set_period(3.0);
  advect->set_frames(frames);
  advect->set_frame_interval(interval);
  return spec;
}

// Runs `spec` straight, then resumes a fresh runner from a checkpoint taken in the middle and checks the frames.
// (The runners pace checkpoints to ~10% of the run time, so under load one may be skipped: the test takes the
// checkpoint nearest to frame `k`.)
void expect_resume_matches(const v1::JobSpec& spec, int k) {
  Runners r;
  RecordingSink straight;
  r.make(spec)->run_task(0, straight, {});
  ASSERT_FALSE(straight.checkpoints.empty());
  // No checkpoint after the last frame (nothing left to resume).
  EXPECT_LT(straight.checkpoints.rbegin()->first, static_cast<int>(straight.frames.size()));
  auto nearest = straight.checkpoints.lower_bound(k);
  if (nearest == straight.checkpoints.end()) --nearest;
  k = nearest->first;
  ASSERT_GE(k, 1);
  ASSERT_GT(static_cast<int>(straight.frames.size()), k);

  auto runner = r.make(spec);
  runner->resume_from(0, k, straight.checkpoints.at(k));
  RecordingSink resumed;
  runner->run_task(0, resumed, {});
  ASSERT_FALSE(resumed.order.empty());
  EXPECT_EQ(resumed.order.front(), k) << "frames before the checkpoint were emitted again";
  EXPECT_EQ(resumed.frames.size(), straight.frames.size() - k);
  for (const auto& [index, bytes] : resumed.frames) {
    ASSERT_TRUE(straight.frames.count(index)) << index;
    EXPECT_EQ(resumed.iterations.at(index), straight.iterations.at(index)) << index;
    EXPECT_EQ(bytes, straight.frames.at(index)) << "frame " << index << " differs from the uninterrupted run";
  }
  // The resumed run keeps checkpointing, with the same states.
  for (const auto& [next, state] : resumed.checkpoints) {
    if (straight.checkpoints.count(next)) {
      EXPECT_EQ(state, straight.checkpoints.at(next)) << next;
    }
  }

  // A damaged checkpoint starts over: every frame again, the same frames.
  auto fallback = r.make(spec);
  std::string bad = straight.checkpoints.at(k);
  bad[bad.size() / 2] = static_cast<char>(bad[bad.size() / 2] ^ 0x55);
  fallback->resume_from(0, k, bad);
  RecordingSink over;
  fallback->run_task(0, over, {});
  EXPECT_EQ(over.frames, straight.frames);
}

TEST(Checkpoint, OptimizeResumesAfterASnapshotWithTheSameFrames) { expect_resume_matches(optimize_spec(), 3); }

TEST(Checkpoint, ActiveAdvectResumesAfterAFrameWithTheSameFrames) {
  expect_resume_matches(advect_spec(1.0 / 32.0, 5, 0.1), 2);
}

// Volume control and tension on top of the advection: still the uninterrupted run's frames.
TEST(Checkpoint, ActiveAdvectWithControlTermsResumesWithTheSameFrames) {
  v1::JobSpec spec = advect_spec(1.0 / 32.0, 5, 0.1);
  spec.mutable_active()->set_delta(1.0);
  spec.mutable_active()->set_beta(0.0005);
  expect_resume_matches(spec, 2);
}

// --- The real server, killed -------------------------------------------------------------------------------------

TEST(Checkpoint, KilledServerResumesAnActiveJobFromItsLastCheckpoint) {
  const fs::path dir = fresh_temp_dir("checkpoint");
  const fs::path data = dir / "data";
  const int frames = 10;  // + the initial one
  const v1::JobSpec spec = advect_spec(1.0 / 48.0, frames, 0.15);
  std::string id;
  int done_before_kill = 0;
  {
    ServerProcess p(dir, 1, {"--data-dir", data.string()});
    ASSERT_GT(p.port(), 0) << p.log();
    auto stub = make_stub(p.address());
    ASSERT_TRUE(submit(*stub, spec, &id).ok());
    // Kill between two frames, half a frame after frame 2 finished: not while the runner writes the checkpoint
    // that follows a frame (the store replaces the checkpoint file before its row, so a kill in between leaves a
    // pair it ignores, and the job would start over).
    auto wait_for = [&](int n) {
      const auto until = std::chrono::steady_clock::now() + 60s;
      while (std::chrono::steady_clock::now() < until) {
        done_before_kill = get_job(*stub, id).frames_done();
        if (done_before_kill >= n) break;
        std::this_thread::sleep_for(5ms);
      }
      return std::chrono::steady_clock::now();
    };
    const auto t2 = wait_for(2);
    const auto t3 = wait_for(3);
    std::this_thread::sleep_for((t3 - t2) / 2);
    done_before_kill = get_job(*stub, id).frames_done();
    p.kill_now();
    ASSERT_GE(done_before_kill, 3) << p.log();
    ASSERT_LT(done_before_kill, frames + 1) << "the job finished before the kill: make frames slower";
  }
  ServerProcess p(dir, 1, {"--data-dir", data.string()});
  ASSERT_GT(p.port(), 0) << p.log();
  auto stub = make_stub(p.address());
  const auto r = watch_job(*stub, id, 0);
  const std::string log = p.log();
  EXPECT_EQ(r.final_job.state(), v1::JOB_STATE_SUCCEEDED) << r.final_job.error().message() << log;
  EXPECT_TRUE(r.integrity_error.empty()) << r.integrity_error;
  ASSERT_EQ(static_cast<int>(r.frames.size()), frames + 1);
  for (int i = 0; i <= frames; ++i) EXPECT_TRUE(r.frames.count(i)) << "frame " << i << " lost";
  // The restarted server took the checkpoint (written after a frame the first server finished) ...
  const auto at = log.find("event=job_checkpoint");
  ASSERT_NE(at, std::string::npos) << log;
  const auto next_at = log.find("next_frame=", at);
  ASSERT_NE(next_at, std::string::npos) << log;
  const int next = std::stoi(log.substr(next_at + 11));
  EXPECT_GE(next, 1);  // the checkpoint after frame 0 at least (the runners pace them to ~10% of the run time)
  EXPECT_LE(next, done_before_kill + 1);  // a frame may finish between the last poll and the kill
  // ... and its frames continue the evolution: simulated times are frame_interval apart all along.
  for (int i = 0; i <= frames; ++i) {
    EXPECT_NEAR(r.frames.at(i).header.stats().metrics().at("time"), 0.15 * i, 1e-9) << i;
  }
  fs::remove_all(dir);
}

}  // namespace
}  // namespace surfacer::testing
