// Jobs that build meshes are bounded before the work: polygonization stops as soon as its triangles pass
// --max-triangles (RESOURCE_EXHAUSTED naming the flag, the count reached and the fix) instead of building the whole
// mesh and counting it; a task's mesh memory (and a particle frame's particles) is reserved from --memory-budget as it
// grows, so a job past the budget fails naming it while a job alongside goes on; a cancel during optimize's subdivision
// frees the worker quickly. Memory is read from /proc/<pid>/status of a surfacer-server process.
#include <gtest/gtest.h>

#include <chrono>
#include <string>
#include <thread>

#include "server/runners/runner.h"
#include "tests/server/test_client.h"
#include "tests/support/files.h"
#include "tests/support/server_process.h"
#include "tests/support/test_meshes.h"

namespace surfacer::testing {
namespace {

using Clock = std::chrono::steady_clock;
constexpr std::int64_t kMiB = std::int64_t{1} << 20;

// The unit sphere intersected with a gyroid sheet: dense (hundreds of millions of triangles at 1000 cells for a
// period of 0.02).
v1::JobSpec gyroid_in_sphere(double period, double thickness, int cells, v1::Polygonizer method) {
  v1::JobSpec spec = isosurface_spec({scene_from_json(R"({"root": {"intersection": {"children": [
      {"gyroid": {"period": )" + std::to_string(period) +
                                                      R"(, "thickness": )" + std::to_string(thickness) + R"(}},
      {"sphere": {"radius": 1.0}}]}}})")},
                                     cells);
  spec.mutable_isosurface()->set_method(method);
  return spec;
}

// Runs `spec` to its end on `stub`; the final job.
v1::Job run_job(v1::Surfacer::Stub& stub, const v1::JobSpec& spec) {
  std::string id;
  const grpc::Status submitted = submit(stub, spec, &id);
  EXPECT_TRUE(submitted.ok()) << submitted.error_message();
  // Under a tight budget the watch stream's own reservation can be refused while the job holds the memory (the
  // server says to retry then), as a client retries.
  WatchResult watched = watch_job(stub, id);
  for (int retry = 0; retry < 50 && watched.status.error_code() == grpc::StatusCode::RESOURCE_EXHAUSTED; ++retry) {
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
    watched = watch_job(stub, id);
  }
  EXPECT_TRUE(watched.status.ok()) << watched.status.error_message();
  return watched.final_job;
}

// The issue's case and more: every cells/limit pair fails with the limit's message, and the server's peak RSS stays
// far below what the meshes would take (the 1000-cell one passed 6 GB before it was killed).
TEST(MeshLimits, DensePolygonizationStopsAtMaxTrianglesWithBoundedMemory) {
  const auto dir = fresh_temp_dir("mesh-limits-dense");
  for (const std::int64_t limit : {100'000, 1'000'000}) {
    ServerProcess server(dir, 2, {"--max-triangles", std::to_string(limit)});
    ASSERT_NE(server.port(), 0) << server.log();
    auto stub = make_stub(server.address());
    for (const int cells : {400, 1000}) {
      for (const v1::Polygonizer method : {v1::POLYGONIZER_CUBES, v1::POLYGONIZER_TILES}) {
        SCOPED_TRACE("limit " + std::to_string(limit) + " cells " + std::to_string(cells) + " method " +
                     std::to_string(method));
        const v1::Job job = run_job(*stub, gyroid_in_sphere(0.02, 0.004, cells, method));
        ASSERT_EQ(job.state(), v1::JOB_STATE_FAILED);
        const std::string& message = job.error().message();
        EXPECT_EQ(job.error().code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << message;
        EXPECT_NE(message.find("--max-triangles"), std::string::npos) << message;
        EXPECT_NE(message.find("stopped at "), std::string::npos) << message;  // the count reached
        EXPECT_NE(message.find(std::to_string(limit)), std::string::npos) << message;
        EXPECT_NE(message.find("fewer cells"), std::string::npos) << message;
      }
    }
    const std::optional<std::uint64_t> peak = server.peak_rss_bytes();
    ASSERT_TRUE(peak.has_value());
    // About 200 bytes per triangle of the limit plus the polygonizers' slabs and the server itself.
    EXPECT_LT(static_cast<std::int64_t>(*peak), 256 * kMiB + limit * 400)
        << "peak RSS " << (*peak >> 20) << " MiB under --max-triangles " << limit;
    std::printf("--max-triangles %lld: server peak RSS %llu MiB over 4 dense jobs\n", static_cast<long long>(limit),
                static_cast<unsigned long long>(*peak >> 20));
  }
}

// A job whose mesh does not fit the memory budget fails naming --memory-budget; a job running alongside, which got
// its reservation first, is not disturbed and succeeds; and the budget's bytes come back.
TEST(MeshLimits, AJobPastTheMemoryBudgetFailsWhileOneAlongsideSucceeds) {
  auto options = LoopbackServer::default_options();
  options.workers = 2;
  for (const std::int64_t budget : {64 * kMiB, 160 * kMiB}) {
    SCOPED_TRACE("budget " + std::to_string(budget >> 20) + " MiB");
    options.limits.memory_budget_bytes = budget;
    LoopbackServer s(options);
    // Alongside: a small optimization that runs for a while once its mesh is made (and reserved).
    v1::JobSpec small;
    *small.mutable_optimize()->mutable_scene() = scene_from_json(R"({"root": {"sphere": {"radius": 1}}})");
    small.mutable_optimize()->mutable_polygonize()->set_cells(24);
    small.mutable_optimize()->set_max_iterations(400);
    small.mutable_optimize()->set_tolerance(1e-12);  // never met: every iteration runs
    std::string small_id;
    ASSERT_TRUE(submit(*s.stub, small, &small_id).ok());
    const auto until = Clock::now() + std::chrono::seconds(30);
    while (get_job(*s.stub, small_id).progress().stage() != "optimize" && Clock::now() < until) {
      std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
    ASSERT_EQ(get_job(*s.stub, small_id).progress().stage(), "optimize");

    for (const v1::Polygonizer method : {v1::POLYGONIZER_CUBES, v1::POLYGONIZER_TILES}) {
      const v1::Job big = run_job(*s.stub, gyroid_in_sphere(0.05, 0.01, 400, method));
      ASSERT_EQ(big.state(), v1::JOB_STATE_FAILED) << method;
      EXPECT_EQ(big.error().code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << big.error().message();
      EXPECT_NE(big.error().message().find("--memory-budget"), std::string::npos) << big.error().message();
      EXPECT_NE(big.error().message().find("isosurface frame 0"), std::string::npos) << big.error().message();
    }
    EXPECT_NE(get_job(*s.stub, small_id).state(), v1::JOB_STATE_FAILED);
    const v1::Job done = watch_job(*s.stub, small_id).final_job;
    EXPECT_EQ(done.state(), v1::JOB_STATE_SUCCEEDED) << done.error().message();
    // Everything was given back: a job as large as the budget allows runs now.
    const v1::Job after = run_job(*s.stub, gyroid_in_sphere(0.5, 0.1, 48, v1::POLYGONIZER_CUBES));
    EXPECT_EQ(after.state(), v1::JOB_STATE_SUCCEEDED) << after.error().message();
  }
}

// Decimated frames reserve the decimator's memory too (TaskMemory::kDecimateBytesPerTriangle): under a budget between
// what the engine's mesh takes and what decimating it adds, the plain job runs and the decimating one fails naming
// --memory-budget before it decimates, for both polygonizers (tiles make about twice the triangles).
TEST(MeshLimits, DecimatedFramesReserveTheDecimatorsMemoryToo) {
  for (const v1::Polygonizer method : {v1::POLYGONIZER_CUBES, v1::POLYGONIZER_TILES}) {
    SCOPED_TRACE("method " + std::to_string(method));
    const v1::JobSpec plain = gyroid_in_sphere(0.3, 0.06, 48, method);
    v1::JobSpec decimating = plain;
    decimating.mutable_output()->set_decimate(0.01);
    // The engine's triangles, from a run without a budget.
    std::int64_t triangles = 0;
    {
      LoopbackServer s;
      std::string id;
      ASSERT_TRUE(submit(*s.stub, decimating, &id).ok());
      const WatchResult watched = watch_job(*s.stub, id);
      ASSERT_EQ(watched.final_job.state(), v1::JOB_STATE_SUCCEEDED) << watched.final_job.error().message();
      ASSERT_EQ(watched.frames.size(), 1u);
      const v1::FrameStats& stats = watched.frames.at(0).header.stats();
      triangles = static_cast<std::int64_t>(stats.metrics().at("triangles_before_decimate"));
      EXPECT_LT(stats.triangles(), triangles);
    }
    ASSERT_GT(triangles, 50'000);
    auto options = LoopbackServer::default_options();
    // Between 192 and 288 bytes per triangle (the grid's slabs take a few MiB of the difference).
    options.limits.memory_budget_bytes = triangles * 250;
    LoopbackServer s(options);
    EXPECT_EQ(run_job(*s.stub, plain).state(), v1::JOB_STATE_SUCCEEDED);
    const v1::Job refused = run_job(*s.stub, decimating);
    ASSERT_EQ(refused.state(), v1::JOB_STATE_FAILED);
    EXPECT_EQ(refused.error().code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << refused.error().message();
    EXPECT_NE(refused.error().message().find("--memory-budget"), std::string::npos) << refused.error().message();
  }
}

// A particle frame reserves its particles' memory besides its mesh's (TaskMemory::kParticleBytes): a small ball
// whose particles come many times over (merged as coincident: the mesh is the ball's) fails under a budget the ball
// alone runs in, naming --memory-budget and the frame, and runs under one that holds its particles too.
TEST(MeshLimits, ParticleFramesReserveTheirParticlesToo) {
  const double d = 0.05;
  const std::vector<Vec3> ball = particle_ball(Vec3::Zero(), 0.25, d, 3);
  const auto job = [&](int copies) {
    v1::JobSpec spec;
    v1::ParticlesJob* particles = spec.mutable_particles();
    particles->set_r_inner(0.6 * d);
    particles->set_spacing_factor(3.0);  // a coarse mesh: few triangles for many particles
    v1::ParticleFrame* frame = particles->add_frames();
    for (int k = 0; k < copies; ++k) {
      for (const Vec3& p : ball) {
        for (int a = 0; a < 3; ++a) frame->add_positions(static_cast<float>(p[a]));
      }
    }
    return spec;
  };
  // The ball's triangles, from a run without a budget.
  std::int64_t triangles = 0;
  {
    LoopbackServer s;
    std::string id;
    ASSERT_TRUE(submit(*s.stub, job(1), &id).ok());
    const WatchResult watched = watch_job(*s.stub, id);
    ASSERT_EQ(watched.final_job.state(), v1::JOB_STATE_SUCCEEDED) << watched.final_job.error().message();
    ASSERT_EQ(watched.frames.size(), 1u);
    triangles = watched.frames.at(0).header.stats().triangles();
  }
  ASSERT_GT(triangles, 500);
  // Room for the ball's largest mesh (the initial one: at most 4x the final), its particles and the job's WatchJob
  // stream; far below what the copies' particles take.
  const std::int64_t ball_bytes = static_cast<std::int64_t>(ball.size()) * server::TaskMemory::kParticleBytes;
  const std::int64_t budget = 4 * triangles * server::TaskMemory::kMeshWorkBytesPerTriangle + ball_bytes + 4 * kMiB;
  const int copies = static_cast<int>(2 * budget / ball_bytes) + 1;
  SCOPED_TRACE("ball " + std::to_string(ball.size()) + " particles, " + std::to_string(triangles) +
               " triangles; budget " + std::to_string(budget >> 20) + " MiB; copies " + std::to_string(copies));
  auto options = LoopbackServer::default_options();
  options.limits.memory_budget_bytes = budget;
  {
    LoopbackServer s(options);
    const v1::Job alone = run_job(*s.stub, job(1));
    EXPECT_EQ(alone.state(), v1::JOB_STATE_SUCCEEDED) << alone.error().message();
    const v1::Job refused = run_job(*s.stub, job(copies));
    ASSERT_EQ(refused.state(), v1::JOB_STATE_FAILED);
    EXPECT_EQ(refused.error().code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << refused.error().message();
    EXPECT_NE(refused.error().message().find("--memory-budget"), std::string::npos) << refused.error().message();
    EXPECT_NE(refused.error().message().find("particles frame 0"), std::string::npos) << refused.error().message();
  }
  options.limits.memory_budget_bytes = budget + copies * ball_bytes;
  LoopbackServer s(options);
  const v1::Job done = run_job(*s.stub, job(copies));
  EXPECT_EQ(done.state(), v1::JOB_STATE_SUCCEEDED) << done.error().message();
}

// Optimize with subdivision everywhere (threshold 1e-12) and a large budget, cancelled at several moments of its
// run (in flows, in red-green refinement, in the trial copies): the job queued behind it starts within a bound.
TEST(MeshLimits, CancelDuringOptimizeSubdivisionFreesTheWorker) {
  auto options = LoopbackServer::default_options();
  options.workers = 1;
  for (const int delay_ms : {300, 900, 1700, 2600}) {
    SCOPED_TRACE("cancel " + std::to_string(delay_ms) + " ms into optimize");
    LoopbackServer s(options);
    v1::JobSpec spec;
    auto* job = spec.mutable_optimize();
    *job->mutable_scene() =
        scene_from_json(R"({"root": {"torus": {"major_radius": 0.6, "minor_radius": 0.25, "axis": {"z": 1}}}})");
    job->mutable_polygonize()->set_cells(160);
    job->set_max_iterations(1000);
    job->set_subdivision_threshold(1e-12);
    job->set_triangle_budget(50'000'000);
    std::string slow, next;
    ASSERT_TRUE(submit(*s.stub, spec, &slow).ok());
    ASSERT_TRUE(
        submit(*s.stub, isosurface_spec({scene_from_json(R"({"root": {"sphere": {"radius": 1}}})")}, 8), &next).ok());
    const auto until = Clock::now() + std::chrono::seconds(60);
    while (get_job(*s.stub, slow).progress().stage() != "optimize" && Clock::now() < until) {
      std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(delay_ms));
    if (get_job(*s.stub, slow).state() != v1::JOB_STATE_RUNNING) {
      ADD_FAILURE() << "the job ended before the cancel: " << get_job(*s.stub, slow).error().message();
      continue;
    }
    const auto cancelled_at = Clock::now();
    ASSERT_TRUE(cancel_job(*s.stub, slow).ok());
    while (get_job(*s.stub, next).state() == v1::JOB_STATE_QUEUED &&
           Clock::now() < cancelled_at + std::chrono::seconds(60)) {
      std::this_thread::sleep_for(std::chrono::milliseconds(2));
    }
    const double latency = std::chrono::duration<double>(Clock::now() - cancelled_at).count();
    EXPECT_LT(latency, 1.0) << "the next job started " << latency << " s after the cancel";
    EXPECT_EQ(get_job(*s.stub, slow).state(), v1::JOB_STATE_CANCELLED);
    std::printf("optimize cancelled %d ms in: next job started after %.3f s\n", delay_ms, latency);
  }
}

}  // namespace
}  // namespace surfacer::testing
