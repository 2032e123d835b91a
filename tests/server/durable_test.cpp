// The durable store: jobs survive a restart (clean, and kill -9), unfinished ones resume from their last finished
// frame, a re-attaching watcher gets every frame from k on, retention deletes by age and bytes, and a write the disk
// refuses fails the job clearly without damaging the store.
#include <gtest/gtest.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <thread>

#include "server/job.h"
#include "server/store.h"
#include "server/uploads.h"
#include "tests/server/test_client.h"
#include "tests/support/files.h"
#include "tests/support/server_process.h"

namespace surfacer::testing {
namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;

// A sequence of `n` spheres of growing radius.
v1::JobSpec sphere_sequence(int n, int cells, v1::MeshEncoding encoding = v1::MESH_ENCODING_DRACO) {
  std::vector<v1::Scene> scenes;
  for (int i = 0; i < n; ++i) {
    scenes.push_back(scene_from_json(R"({"root": {"sphere": {"radius": )" + std::to_string(0.6 + 0.04 * i) + "}}}"));
  }
  auto spec = isosurface_spec(scenes, cells);
  spec.mutable_isosurface()->mutable_bounds()->mutable_min()->set_x(-1.2);
  spec.mutable_isosurface()->mutable_bounds()->mutable_min()->set_y(-1.2);
  spec.mutable_isosurface()->mutable_bounds()->mutable_min()->set_z(-1.2);
  spec.mutable_isosurface()->mutable_bounds()->mutable_max()->set_x(1.2);
  spec.mutable_isosurface()->mutable_bounds()->mutable_max()->set_y(1.2);
  spec.mutable_isosurface()->mutable_bounds()->mutable_max()->set_z(1.2);
  spec.mutable_output()->set_encoding(encoding);
  return spec;
}

server::ServerOptions durable_options(const fs::path& dir, int workers = 2) {
  auto o = LoopbackServer::default_options();
  o.data_dir = dir.string();
  o.workers = workers;
  return o;
}

TEST(DurableStore, FinishedJobsSurviveARestartAndReattachFromFrameK) {
  const fs::path dir = fresh_temp_dir("durable-restart");
  std::string id;
  std::map<int, std::string> first;
  {
    LoopbackServer s(durable_options(dir));
    ASSERT_TRUE(submit(*s.stub, sphere_sequence(5, 32), &id).ok());
    const auto r = watch_job(*s.stub, id);
    ASSERT_EQ(r.final_job.state(), v1::JOB_STATE_SUCCEEDED);
    ASSERT_EQ(r.frames.size(), 5u);
    for (const auto& [i, f] : r.frames) first[i] = f.bytes;
  }
  ASSERT_TRUE(fs::exists(dir / "surfacer.db"));
  LoopbackServer s(durable_options(dir));
  const v1::Job job = get_job(*s.stub, id);
  EXPECT_EQ(job.state(), v1::JOB_STATE_SUCCEEDED);
  EXPECT_EQ(job.frames_done(), 5);
  const auto r = watch_job(*s.stub, id, 2);
  EXPECT_TRUE(r.integrity_error.empty()) << r.integrity_error;
  ASSERT_EQ(r.frames.size(), 3u);
  for (int i = 2; i < 5; ++i) EXPECT_EQ(r.frames.at(i).bytes, first[i]) << "frame " << i;
  EXPECT_EQ(r.final_job.state(), v1::JOB_STATE_SUCCEEDED);
}

TEST(DurableStore, KillNineMidJobResumesFromTheLastFinishedFrame) {
  const fs::path dir = fresh_temp_dir("durable-kill9");
  const fs::path data = dir / "data";
  const int frames = 8;
  std::string id;
  int done_before_kill = 0;
  {
    ServerProcess p(dir, 1, {"--data-dir", data.string()});
    ASSERT_GT(p.port(), 0) << p.log();
    auto stub = make_stub(p.address());
    ASSERT_TRUE(submit(*stub, sphere_sequence(frames, 150), &id).ok());
    const auto until = std::chrono::steady_clock::now() + 60s;
    while (std::chrono::steady_clock::now() < until) {
      done_before_kill = get_job(*stub, id).frames_done();
      if (done_before_kill >= 2) break;
      std::this_thread::sleep_for(10ms);
    }
    p.kill_now();
    ASSERT_GE(done_before_kill, 2) << p.log();
    ASSERT_LT(done_before_kill, frames) << "the job finished before the kill: make frames slower";
  }
  ServerProcess p(dir, 1, {"--data-dir", data.string()});
  ASSERT_GT(p.port(), 0) << p.log();
  auto stub = make_stub(p.address());
  const auto r = watch_job(*stub, id, 0);
  EXPECT_EQ(r.final_job.state(), v1::JOB_STATE_SUCCEEDED) << r.final_job.error().message() << p.log();
  EXPECT_TRUE(r.integrity_error.empty()) << r.integrity_error;
  ASSERT_EQ(static_cast<int>(r.frames.size()), frames);
  for (int i = 0; i < frames; ++i) EXPECT_TRUE(r.frames.count(i)) << "frame " << i << " lost";
  // Only the unfinished frames were computed again.
  const std::string log = p.log();
  const auto at = log.find("event=job_resumed");
  ASSERT_NE(at, std::string::npos) << log;
  const auto tasks_at = log.find("tasks=", at);
  const int resumed_tasks = std::stoi(log.substr(tasks_at + 6));
  EXPECT_LE(resumed_tasks, frames - done_before_kill);
  // A watcher re-attaching from frame k gets exactly the frames >= k.
  const auto tail = watch_job(*stub, id, 5);
  EXPECT_EQ(tail.frames.size(), 3u);
  EXPECT_EQ(tail.frames.begin()->first, 5);
}

// CancelJob's OK means the cancel is in the store: a kill -9 right after it does not bring the job back. Whether the
// job was queued behind another or running, and whichever frame it was on.
TEST(DurableStore, ACancelIsDurableBeforeItIsAcknowledged) {
  for (const bool queued : {false, true}) {
    const fs::path dir = fresh_temp_dir(queued ? "durable-cancel-queued" : "durable-cancel-running");
    const fs::path data = dir / "data";
    const int frames = 8;
    std::string id, other;
    {
      ServerProcess p(dir, 1, {"--data-dir", data.string()});
      ASSERT_GT(p.port(), 0) << p.log();
      auto stub = make_stub(p.address());
      if (queued) ASSERT_TRUE(submit(*stub, sphere_sequence(frames, 150), &other).ok());  // holds the one worker
      ASSERT_TRUE(submit(*stub, sphere_sequence(frames, 150), &id).ok());
      const auto until = std::chrono::steady_clock::now() + 60s;
      const std::string& busy = queued ? other : id;
      while (std::chrono::steady_clock::now() < until && get_job(*stub, busy).frames_done() < 1) {
        std::this_thread::sleep_for(5ms);
      }
      v1::Job answer;
      ASSERT_TRUE(cancel_job(*stub, id, &answer).ok());
      p.kill_now();
      ASSERT_LT(answer.frames_done(), frames) << "the job finished before the cancel: make frames slower";
    }
    ServerProcess p(dir, 1, {"--data-dir", data.string()});
    ASSERT_GT(p.port(), 0) << p.log();
    auto stub = make_stub(p.address());
    const v1::Job job = get_job(*stub, id);
    EXPECT_EQ(job.state(), v1::JOB_STATE_CANCELLED) << (queued ? "queued: " : "running: ") << p.log();
    EXPECT_EQ(job.error().code(), static_cast<int>(grpc::StatusCode::CANCELLED));
    // Nothing of it runs after the restart, and a watcher gets its terminal state.
    const auto r = watch_job(*stub, id, 0);
    EXPECT_EQ(r.final_job.state(), v1::JOB_STATE_CANCELLED);
    EXPECT_EQ(p.log().find("event=job_started job=" + id), std::string::npos) << p.log();
  }
}

// A job running each time its server is killed (say it is what brings the server down) resumes, counting the
// interruptions; the kMaxInterruptedRuns-th restart fails it instead of running it again.
TEST(DurableStore, AJobInterruptedRepeatedlyIsFailedNotResumedForever) {
  const fs::path dir = fresh_temp_dir("durable-interrupted");
  const fs::path data = dir / "data";
  const int frames = 12;
  std::string id;
  int done = 0;
  for (int life = 0; life < server::Job::kMaxInterruptedRuns; ++life) {
    ServerProcess p(dir, 1, {"--data-dir", data.string()});
    ASSERT_GT(p.port(), 0) << p.log();
    auto stub = make_stub(p.address());
    if (life == 0) ASSERT_TRUE(submit(*stub, sphere_sequence(frames, 150), &id).ok());
    EXPECT_EQ(get_job(*stub, id).interrupted_runs(), life);
    // Killed once it has made a frame in this life (so it was running, and the store says so).
    const int before = done;
    const auto until = std::chrono::steady_clock::now() + 60s;
    while (std::chrono::steady_clock::now() < until && (done = get_job(*stub, id).frames_done()) <= before) {
      std::this_thread::sleep_for(5ms);
    }
    p.kill_now();
    ASSERT_GT(done, before) << p.log();
    ASSERT_LT(done, frames) << "the job finished before the kill: make frames slower";
  }
  ServerProcess p(dir, 1, {"--data-dir", data.string()});
  ASSERT_GT(p.port(), 0) << p.log();
  auto stub = make_stub(p.address());
  const v1::Job job = get_job(*stub, id);
  EXPECT_EQ(job.state(), v1::JOB_STATE_FAILED) << p.log();
  EXPECT_EQ(job.interrupted_runs(), server::Job::kMaxInterruptedRuns);
  EXPECT_EQ(job.error().code(), static_cast<int>(grpc::StatusCode::ABORTED));
  EXPECT_NE(job.error().message().find("the server stopped 3 times while this job was running"), std::string::npos)
      << job.error().message();
  EXPECT_EQ(job.frames_done(), done);  // what it made is kept
  EXPECT_EQ(p.log().find("event=job_started job=" + id), std::string::npos) << p.log();
}

TEST(DurableStore, AServerStoppingPastItsDrainDeadlineLeavesUnfinishedJobsToTheNext) {
  const fs::path dir = fresh_temp_dir("durable-suspend");
  const int frames = 8;
  std::string id;
  int done_before = 0;
  {
    LoopbackServer s(durable_options(dir, 1));
    ASSERT_TRUE(submit(*s.stub, sphere_sequence(frames, 150), &id).ok());
    const auto until = std::chrono::steady_clock::now() + 60s;
    while (std::chrono::steady_clock::now() < until && (done_before = get_job(*s.stub, id).frames_done()) < 1) {
      std::this_thread::sleep_for(5ms);
    }
    s.server->shutdown(server::ShutdownMode::kDrain, 0ms);  // a redeploy whose drain deadline has passed
  }
  ASSERT_GE(done_before, 1);
  // Suspended cleanly more often than a crash would be tolerated: not an interruption.
  for (int redeploy = 0; redeploy < server::Job::kMaxInterruptedRuns; ++redeploy) {
    LoopbackServer s(durable_options(dir, 1));
    const auto until = std::chrono::steady_clock::now() + 60s;
    while (std::chrono::steady_clock::now() < until && get_job(*s.stub, id).state() != v1::JOB_STATE_RUNNING) {
      std::this_thread::sleep_for(5ms);
    }
    s.server->shutdown(server::ShutdownMode::kDrain, 0ms);
  }
  LoopbackServer s(durable_options(dir));
  const auto r = watch_job(*s.stub, id);
  EXPECT_EQ(r.final_job.state(), v1::JOB_STATE_SUCCEEDED) << r.final_job.error().message();
  EXPECT_EQ(r.final_job.interrupted_runs(), 0);
  EXPECT_EQ(static_cast<int>(r.frames.size()), frames);
  EXPECT_TRUE(r.integrity_error.empty()) << r.integrity_error;
}

TEST(DurableStore, AFullDiskFailsTheJobClearlyAndLeavesTheStoreUsable) {
  const fs::path dir = fresh_temp_dir("durable-full");
  const fs::path data = dir / "data";
  std::string ok_id, id;
  {
    // Raw PLY frames of ~1 MB each against a 3 MB file-size limit: the database and the first small job fit,
    // the big frames do not.
    ServerProcess p(dir, 1, {"--data-dir", data.string()}, 3u << 20);
    ASSERT_GT(p.port(), 0) << p.log();
    auto stub = make_stub(p.address());
    ASSERT_TRUE(submit(*stub, sphere_sequence(1, 24), &ok_id).ok());
    EXPECT_EQ(watch_job(*stub, ok_id).final_job.state(), v1::JOB_STATE_SUCCEEDED);
    ASSERT_TRUE(submit(*stub, sphere_sequence(3, 200, v1::MESH_ENCODING_PLY), &id).ok());
    const auto r = watch_job(*stub, id);
    EXPECT_EQ(r.final_job.state(), v1::JOB_STATE_FAILED);
    EXPECT_EQ(r.final_job.error().code(), static_cast<int>(grpc::StatusCode::RESOURCE_EXHAUSTED));
    EXPECT_NE(r.final_job.error().message().find("data-dir"), std::string::npos) << r.final_job.error().message();
    // The server keeps serving.
    std::string again;
    ASSERT_TRUE(submit(*stub, sphere_sequence(1, 24), &again).ok());
    EXPECT_EQ(watch_job(*stub, again).final_job.state(), v1::JOB_STATE_SUCCEEDED);
    p.kill_now();
  }
  // No temporary or orphan file is left, and everything recorded is readable after a restart.
  ServerProcess p(dir, 1, {"--data-dir", data.string()});
  ASSERT_GT(p.port(), 0) << p.log();
  auto stub = make_stub(p.address());
  const auto ok = watch_job(*stub, ok_id);
  EXPECT_EQ(ok.final_job.state(), v1::JOB_STATE_SUCCEEDED);
  EXPECT_EQ(ok.frames.size(), 1u);
  EXPECT_TRUE(ok.integrity_error.empty());
  const auto failed = watch_job(*stub, id);
  EXPECT_EQ(failed.final_job.state(), v1::JOB_STATE_FAILED);
  EXPECT_TRUE(failed.integrity_error.empty());
  for (const auto& f : fs::recursive_directory_iterator(data / "frames")) {
    EXPECT_EQ(f.path().extension() == ".tmp", false) << f.path();
  }
}

TEST(DurableStore, AStateTheFullDiskRefusedIsKeptAndWrittenOnceItCanBe) {
  const fs::path dir = fresh_temp_dir("durable-full-state");
  const fs::path data = dir / "data";
  std::string id;
  {
    // 512 KiB per file: the frames (a few kB each) fit, but the database's write-ahead log fills up mid-job, so the
    // job fails and its FAILED state cannot be written either.
    ServerProcess p(dir, 1, {"--data-dir", data.string()}, 512u << 10);
    ASSERT_GT(p.port(), 0) << p.log();
    auto stub = make_stub(p.address());
    for (int attempt = 0; attempt < 10 && id.empty(); ++attempt) {
      std::string job;
      if (!submit(*stub, sphere_sequence(60, 12), &job).ok()) continue;
      const auto r = watch_job(*stub, job);
      if (r.final_job.state() == v1::JOB_STATE_FAILED) id = job;
    }
    ASSERT_FALSE(id.empty()) << "no job failed on the full store:\n" << p.log();
    EXPECT_EQ(get_job(*stub, id).error().code(), static_cast<int>(grpc::StatusCode::RESOURCE_EXHAUSTED));
    // The state waited in memory, and the server wrote it once the log's space was given back.
    const auto until = std::chrono::steady_clock::now() + 20s;
    while (p.log().find("event=store_write_recovered job=" + id) == std::string::npos &&
           std::chrono::steady_clock::now() < until) {
      std::this_thread::sleep_for(50ms);
    }
    EXPECT_NE(p.log().find("event=store_write_failed job=" + id), std::string::npos) << p.log();
    EXPECT_NE(p.log().find("event=store_write_recovered job=" + id), std::string::npos) << p.log();
    p.kill_now();
  }
  // After a crash the job is as it was reported: FAILED, not resumed (and then perhaps SUCCEEDED).
  ServerProcess p(dir, 1, {"--data-dir", data.string()});
  ASSERT_GT(p.port(), 0) << p.log();
  auto stub = make_stub(p.address());
  EXPECT_EQ(get_job(*stub, id).state(), v1::JOB_STATE_FAILED) << p.log();
  EXPECT_EQ(watch_job(*stub, id).final_job.state(), v1::JOB_STATE_FAILED);
}

TEST(DurableStore, RetentionRemovesTheOldestFinishedJobsByBytesThenByAge) {
  const fs::path dir = fresh_temp_dir("durable-retention");
  auto o = durable_options(dir);
  o.retention_interval = std::chrono::hours(1);  // run by hand below
  std::vector<std::string> ids;
  std::int64_t per_job = 0;
  {
    LoopbackServer s(o);
    for (int i = 0; i < 3; ++i) {
      std::string id;
      ASSERT_TRUE(submit(*s.stub, sphere_sequence(2, 40), &id).ok());
      const auto r = watch_job(*s.stub, id);
      ASSERT_EQ(r.final_job.state(), v1::JOB_STATE_SUCCEEDED);
      std::int64_t bytes = 0;
      for (const auto& [k, f] : r.frames) bytes += static_cast<std::int64_t>(f.bytes.size());
      per_job = std::max(per_job, bytes);
      ids.push_back(id);
      std::this_thread::sleep_for(1100ms);  // distinct finish seconds, so "oldest" is well defined after restart
    }
  }
  // Room for about two jobs: the oldest goes, with its rows and files.
  o.retain_bytes = per_job * 5 / 2;
  {
    LoopbackServer s(o);
    s.server->run_retention();
    grpc::Status status;
    get_job(*s.stub, ids[0], &status);
    EXPECT_EQ(status.error_code(), grpc::StatusCode::NOT_FOUND);
    EXPECT_FALSE(fs::exists(dir / "frames" / ids[0]));
    for (int i = 1; i < 3; ++i) {
      EXPECT_EQ(get_job(*s.stub, ids[i], &status).state(), v1::JOB_STATE_SUCCEEDED) << status.error_message();
      EXPECT_TRUE(fs::exists(dir / "frames" / ids[i]));
    }
  }
  // By age: everything finished more than a second ago goes.
  o.retain_bytes = 0;
  o.keep_finished = std::chrono::seconds(1);
  LoopbackServer s(o);
  std::this_thread::sleep_for(1100ms);
  s.server->run_retention();
  for (const auto& id : ids) {
    grpc::Status status;
    get_job(*s.stub, id, &status);
    EXPECT_EQ(status.error_code(), grpc::StatusCode::NOT_FOUND) << id;
  }
  EXPECT_TRUE(fs::is_empty(dir / "frames"));
}

TEST(DurableStore, OneServerPerDataDirectory) {
  const fs::path dir = fresh_temp_dir("durable-lock");
  LoopbackServer s(durable_options(dir));
  try {
    server::SurfacerServer::start(durable_options(dir));
    ADD_FAILURE() << "a second server opened the same data directory";
  } catch (const std::exception& e) {
    EXPECT_NE(std::string(e.what()).find("in use by another surfacer-server (pid " + std::to_string(getpid())),
              std::string::npos)
        << e.what();
  }
  s.server->shutdown(server::ShutdownMode::kCancel, 0ms);
  s.server.reset();
  EXPECT_NO_THROW(server::SurfacerServer::start(durable_options(dir))) << "the lock goes with the server";
}

TEST(DurableStore, OnlyServerGeneratedIdsBecomePaths) {
  EXPECT_TRUE(server::Store::valid_id("j-0123456789abcdef"));
  EXPECT_TRUE(server::Store::valid_id("u-0123456789abcdef"));
  for (const char* bad : {"../../etc/passwd", "j-0123456789abcde/", "j-../../../../x", "u-0123456789ABCDEF", "",
                          "j-0123456789abcdef0", "x-0123456789abcdef"}) {
    EXPECT_FALSE(server::Store::valid_id(bad)) << bad;
  }
  // A request naming a path gets NOT_FOUND and touches nothing on disk.
  const fs::path dir = fresh_temp_dir("durable-paths");
  LoopbackServer s(durable_options(dir));
  grpc::Status status;
  get_job(*s.stub, "../../../../etc/passwd", &status);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::NOT_FOUND);
  auto spec = sphere_sequence(1, 16);
  auto* grid = spec.mutable_isosurface()->mutable_scenes(0)->mutable_root()->mutable_grid();
  grid->set_upload_id("../../../etc/passwd");
  std::string id;
  status = submit(*s.stub, spec, &id);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(status.error_message().find("no upload"), std::string::npos) << status.error_message();
}

}  // namespace
}  // namespace surfacer::testing
