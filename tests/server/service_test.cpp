// The service through a real gRPC server on a loopback port (and once through the in-process channel).
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <filesystem>
#include <limits>
#include <thread>

#include "core/mesh/mesh_checks.h"
#include "core/mesh/mesh_codec.h"
#include "core/mesh/mesh_io.h"
#include "tests/server/test_client.h"
#include "tests/support/mesh_expectations.h"
#include "tests/support/test_meshes.h"

namespace surfacer::testing {
namespace {

using namespace std::chrono_literals;

const std::string kSphere = R"({"root": {"sphere": {"center": {"x": 0.1}, "radius": 1.0}}})";

// Long-running: a blobby field on a very fine grid.
v1::JobSpec slow_spec() {
  auto scene = scene_from_json(R"({"root": {"blobs": {"points": [
      {"center": {"x": -0.5}, "radius": 1.2}, {"center": {"x": 0.5}, "radius": 1.2},
      {"center": {"y": 0.6}, "radius": 1.0}]}}})");
  return isosurface_spec({scene}, 1000);
}

void wait_for_state(v1::Surfacer::Stub& stub, const std::string& id, v1::JobState state) {
  const auto until = std::chrono::steady_clock::now() + 30s;
  while (get_job(stub, id).state() != state && std::chrono::steady_clock::now() < until) {
    std::this_thread::sleep_for(5ms);
  }
  ASSERT_EQ(get_job(stub, id).state(), state);
}

TEST(Service, SphereJobStreamsAClosedDracoMesh) {
  LoopbackServer s;
  std::string id;
  ASSERT_TRUE(submit(*s.stub, isosurface_spec({scene_from_json(kSphere)}, 40), &id).ok());
  const auto result = watch_job(*s.stub, id);
  ASSERT_TRUE(result.status.ok()) << result.status.error_message();
  EXPECT_EQ(result.integrity_error, "");
  ASSERT_FALSE(result.states.empty());
  EXPECT_EQ(result.states.back(), v1::JOB_STATE_SUCCEEDED);
  ASSERT_EQ(result.frames.size(), 1u);
  const auto& frame = result.frames.at(0);
  EXPECT_EQ(frame.header.encoding(), v1::MESH_ENCODING_DRACO);
  const Mesh mesh = decode_draco(frame.bytes);
  EXPECT_EQ(static_cast<std::int64_t>(mesh.triangles.size()), frame.header.stats().triangles());
  const auto report = check_mesh(mesh);
  EXPECT_TRUE(mesh_has(report, kClosed | kEdgeManifold));
  EXPECT_EQ(report.euler_characteristic, 2);
  EXPECT_TRUE(frame.header.stats().check().closed());
  EXPECT_NEAR(report.volume, sphere_volume(1.0), 0.03 * sphere_volume(1.0));
  // Every vertex near the true sphere (MC error + quantization).
  for (const auto& v : mesh.vertices) EXPECT_NEAR((v - Vec3(0.1, 0, 0)).norm(), 1.0, 0.02);
  // Stage timings are reported.
  std::vector<std::string> stages;
  for (const auto& t : frame.header.stats().timings()) stages.push_back(t.stage());
  EXPECT_NE(std::find(stages.begin(), stages.end(), "polygonize"), stages.end());
  EXPECT_NE(std::find(stages.begin(), stages.end(), "encode"), stages.end());
}

TEST(Service, InProcessChannelWorksWithoutAPort) {
  server::ServerOptions options;
  options.listen = "";
  auto server = server::SurfacerServer::start(options);
  EXPECT_EQ(server->port(), 0);
  auto stub = v1::Surfacer::NewStub(server->in_process_channel());
  std::string id;
  ASSERT_TRUE(submit(*stub, isosurface_spec({scene_from_json(kSphere)}, 24), &id).ok());
  const auto result = watch_job(*stub, id);
  EXPECT_TRUE(result.status.ok());
  EXPECT_EQ(result.frames.size(), 1u);
  EXPECT_TRUE(check_mesh(decode_draco(result.frames.at(0).bytes)).closed);
}

TEST(Service, RawPlyFramesAreLossless) {
  LoopbackServer s;
  auto spec = isosurface_spec({scene_from_json(kSphere)}, 20);
  spec.mutable_output()->set_encoding(v1::MESH_ENCODING_PLY);
  std::string id;
  ASSERT_TRUE(submit(*s.stub, spec, &id).ok());
  const auto result = watch_job(*s.stub, id);
  ASSERT_EQ(result.frames.size(), 1u);
  EXPECT_EQ(result.frames.at(0).header.encoding(), v1::MESH_ENCODING_PLY);
  const Mesh mesh = parse_mesh(result.frames.at(0).bytes, MeshFormat::kPly, "frame");
  EXPECT_TRUE(check_mesh(mesh).closed);
  EXPECT_EQ(static_cast<std::int64_t>(mesh.vertices.size()), result.frames.at(0).header.stats().vertices());
}

TEST(Service, SequenceSharesOneQuantizationGrid) {
  LoopbackServer s;
  // Two spheres that share their left part of the surface exactly? No: same sphere twice must decode identically,
  // and a shifted sphere's vertices must lie on the same quantization lattice.
  auto a = scene_from_json(kSphere);
  auto b = scene_from_json(R"({"root": {"sphere": {"center": {"x": 0.3}, "radius": 0.8}}})");
  auto spec = isosurface_spec({a, b, a}, 32);
  spec.mutable_output()->set_quantization_bits(10);
  std::string id;
  ASSERT_TRUE(submit(*s.stub, spec, &id).ok());
  const auto result = watch_job(*s.stub, id);
  ASSERT_EQ(result.frames.size(), 3u);
  const Mesh m0 = decode_draco(result.frames.at(0).bytes);
  const Mesh m1 = decode_draco(result.frames.at(1).bytes);
  const Mesh m2 = decode_draco(result.frames.at(2).bytes);
  EXPECT_EQ(result.frames.at(0).bytes, result.frames.at(2).bytes);  // same scene: same bytes
  // Quantization lattice: the coordinate differences between frames are whole multiples of one step.
  double step = 0;
  {
    // Recover the step from frame 0: smallest nonzero difference between sorted x coordinates.
    std::vector<double> xs;
    for (const auto& v : m0.vertices) xs.push_back(v.x());
    std::sort(xs.begin(), xs.end());
    step = std::numeric_limits<double>::max();
    for (std::size_t i = 1; i < xs.size(); ++i) {
      if (xs[i] - xs[i - 1] > 1e-9) step = std::min(step, xs[i] - xs[i - 1]);
    }
  }
  ASSERT_GT(step, 0);
  for (const auto& v : m1.vertices) {
    const double k = (v.x() - m0.vertices[0].x()) / step;
    EXPECT_NEAR(k, std::round(k), 1e-3);
  }
}

TEST(Service, LargeFrameOver5MTrianglesStreamsInChunks) {
  LoopbackServer s;
  // A gyroid sheet fills the box with surface: ~5 M triangles at 128 cells.
  auto scene = scene_from_json(R"({"root": {"gyroid": {"period": 1.0, "thickness": 0.3}}})");
  auto spec = isosurface_spec({scene}, 136);
  spec.mutable_isosurface()->set_method(v1::POLYGONIZER_CUBES);  // the chunking is under test, not the polygonizer
  auto* bounds = spec.mutable_isosurface()->mutable_bounds();
  bounds->mutable_min()->set_x(0);
  bounds->mutable_min()->set_y(0);
  bounds->mutable_min()->set_z(0);
  bounds->mutable_max()->set_x(17);
  bounds->mutable_max()->set_y(17);
  bounds->mutable_max()->set_z(17);
  std::string id;
  ASSERT_TRUE(submit(*s.stub, spec, &id).ok());
  const auto result = watch_job(*s.stub, id);
  ASSERT_TRUE(result.status.ok()) << result.status.error_message();
  EXPECT_EQ(result.integrity_error, "");
  ASSERT_EQ(result.frames.size(), 1u);
  const auto& frame = result.frames.at(0);
  EXPECT_GE(frame.header.stats().triangles(), 5'000'000);
  EXPECT_GT(frame.chunks, 1);
  EXPECT_LE(frame.max_chunk_bytes, std::size_t{1} << 20);
  const Mesh mesh = decode_draco(frame.bytes);
  EXPECT_EQ(static_cast<std::int64_t>(mesh.triangles.size()), frame.header.stats().triangles());
}

TEST(Service, CancelStopsARunningJobWithinHalfASecond) {
  LoopbackServer s;
  std::string id;
  ASSERT_TRUE(submit(*s.stub, slow_spec(), &id).ok());
  wait_for_state(*s.stub, id, v1::JOB_STATE_RUNNING);
  std::this_thread::sleep_for(100ms);
  const auto start = std::chrono::steady_clock::now();
  ASSERT_TRUE(cancel_job(*s.stub, id).ok());
  wait_for_state(*s.stub, id, v1::JOB_STATE_CANCELLED);
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  EXPECT_LT(seconds, 0.5);
  // The watcher of a cancelled job ends with the terminal state.
  const auto result = watch_job(*s.stub, id);
  EXPECT_TRUE(result.status.ok());
  ASSERT_FALSE(result.states.empty());
  EXPECT_EQ(result.states.back(), v1::JOB_STATE_CANCELLED);
}

// Frames surfaced in parallel report their own stages; the job's fraction a watcher sees never goes back.
TEST(Service, ProgressNeverGoesBackward) {
  for (const int workers : {1, 2}) {
    auto options = LoopbackServer::default_options();
    options.workers = workers;
    LoopbackServer s(options);
    std::string id;
    const std::vector<v1::Scene> scenes(6, scene_from_json(R"({"root": {"sphere": {"radius": 1}}})"));
    ASSERT_TRUE(submit(*s.stub, isosurface_spec(scenes, 96), &id).ok());
    const auto r = watch_job(*s.stub, id);
    ASSERT_EQ(r.final_job.state(), v1::JOB_STATE_SUCCEEDED) << r.final_job.error().message();
    ASSERT_GE(r.fractions.size(), 2u) << "too few progress events to tell";
    for (std::size_t i = 1; i < r.fractions.size(); ++i) {
      EXPECT_GE(r.fractions[i], r.fractions[i - 1]) << "event " << i << " of " << r.fractions.size();
    }
    EXPECT_LE(r.fractions.back(), 1.0);
  }
}

TEST(Service, WatchFromFrameSkipsEarlierFrames) {
  LoopbackServer s;
  auto a = scene_from_json(kSphere);
  std::string id;
  ASSERT_TRUE(submit(*s.stub, isosurface_spec({a, a, a, a}, 16), &id).ok());
  const auto all = watch_job(*s.stub, id);
  EXPECT_EQ(all.frames.size(), 4u);
  // Reconnecting after the job finished, from frame 2: frames 2 and 3 only, then the final state.
  const auto later = watch_job(*s.stub, id, 2);
  ASSERT_EQ(later.frames.size(), 2u);
  EXPECT_TRUE(later.frames.count(2) && later.frames.count(3));
  EXPECT_EQ(later.states.back(), v1::JOB_STATE_SUCCEEDED);
}

TEST(Service, BadInputGetsNamedFieldsAndTheServerKeepsServing) {
  server::ServerOptions options = LoopbackServer::default_options();
  options.limits.max_grid_cells = 1'000'000;
  LoopbackServer s(options);
  // A long job in the background must be unaffected.
  std::string slow_id;
  ASSERT_TRUE(submit(*s.stub, isosurface_spec({scene_from_json(kSphere)}, 90), &slow_id).ok());

  struct Case {
    std::string scene;
    int cells;
    grpc::StatusCode code;
    std::string must_mention;
  };
  const double nan = std::numeric_limits<double>::quiet_NaN();
  v1::Scene nan_scene = scene_from_json(kSphere);
  nan_scene.mutable_root()->mutable_sphere()->set_radius(nan);
  std::string id;

  auto expect = [&](const v1::JobSpec& spec, grpc::StatusCode code, const std::string& mention) {
    const auto status = submit(*s.stub, spec, &id);
    EXPECT_EQ(status.error_code(), code) << status.error_message();
    EXPECT_NE(status.error_message().find(mention), std::string::npos) << status.error_message();
  };
  expect(isosurface_spec({nan_scene}, 16), grpc::StatusCode::INVALID_ARGUMENT, "scenes[0].root.sphere");
  expect(isosurface_spec({scene_from_json(R"({"root": {"sphere": {"radius": -1}}})")}, 16),
         grpc::StatusCode::INVALID_ARGUMENT, "radius");
  expect(isosurface_spec({scene_from_json(R"({"root": {"box": {"halfSize": {"x": 1, "y": -2, "z": 1}}}})")}, 16),
         grpc::StatusCode::INVALID_ARGUMENT, "half_size");
  expect(isosurface_spec({scene_from_json(kSphere)}, -5), grpc::StatusCode::INVALID_ARGUMENT, "spec.isosurface.cells");
  expect(isosurface_spec({scene_from_json(kSphere)}, 200), grpc::StatusCode::RESOURCE_EXHAUSTED, "--max-grid-cells");
  expect(isosurface_spec({scene_from_json(kSphere)}, 200), grpc::StatusCode::RESOURCE_EXHAUSTED, "204 x 204 x 204");
  // More cells along an axis than the grid holds: the count asked for, not the held 1e9 per axis.
  expect(isosurface_spec({scene_from_json(kSphere)}, 2147483647), grpc::StatusCode::RESOURCE_EXHAUSTED, "e+27 cells");
  expect(isosurface_spec({}, 16), grpc::StatusCode::INVALID_ARGUMENT, "spec.isosurface.scenes");
  expect(isosurface_spec({scene_from_json(R"({"root": {}})")}, 16), grpc::StatusCode::INVALID_ARGUMENT,
         "scenes[0].root");
  expect(isosurface_spec({scene_from_json(R"({"root": {"union": {"children": [{"sphere": {"radius": 1}}]}}})")}, 16),
         grpc::StatusCode::INVALID_ARGUMENT, "union");
  expect(isosurface_spec({scene_from_json(R"({"root": {"plane": {"normal": {"z": 1}}}})")}, 16),
         grpc::StatusCode::INVALID_ARGUMENT, "spec.isosurface.bounds");
  expect(v1::JobSpec(), grpc::StatusCode::INVALID_ARGUMENT, "spec");
  {
    auto spec = isosurface_spec({scene_from_json(kSphere)}, 16);
    spec.mutable_output()->set_quantization_bits(40);
    expect(spec, grpc::StatusCode::INVALID_ARGUMENT, "spec.output.quantization_bits");
  }
  // Unknown job ids.
  grpc::Status status;
  get_job(*s.stub, "j-doesnotexist", &status);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::NOT_FOUND);
  EXPECT_NE(status.error_message().find("job_id"), std::string::npos);
  EXPECT_EQ(watch_job(*s.stub, "j-nope").status.error_code(), grpc::StatusCode::NOT_FOUND);
  EXPECT_EQ(cancel_job(*s.stub, "j-nope").error_code(), grpc::StatusCode::NOT_FOUND);
  // The background job and a fresh one still succeed.
  EXPECT_EQ(watch_job(*s.stub, slow_id).states.back(), v1::JOB_STATE_SUCCEEDED);
  ASSERT_TRUE(submit(*s.stub, isosurface_spec({scene_from_json(kSphere)}, 16), &id).ok());
  EXPECT_EQ(watch_job(*s.stub, id).states.back(), v1::JOB_STATE_SUCCEEDED);
}

TEST(Service, FullQueueAnswersResourceExhausted) {
  server::ServerOptions options = LoopbackServer::default_options();
  options.workers = 1;
  options.max_queued_jobs = 1;
  LoopbackServer s(options);
  std::string running, queued, id;
  ASSERT_TRUE(submit(*s.stub, slow_spec(), &running).ok());
  wait_for_state(*s.stub, running, v1::JOB_STATE_RUNNING);
  ASSERT_TRUE(submit(*s.stub, slow_spec(), &queued).ok());
  const auto status = submit(*s.stub, slow_spec(), &id);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
  EXPECT_NE(status.error_message().find("--max-queued-jobs"), std::string::npos);
  s.server->cancel_jobs("test over");
}

TEST(Service, ListJobsFiltersByState) {
  LoopbackServer s;
  std::string id;
  ASSERT_TRUE(submit(*s.stub, isosurface_spec({scene_from_json(kSphere)}, 12), &id).ok());
  watch_job(*s.stub, id);
  grpc::ClientContext context;
  v1::ListJobsRequest request;
  request.add_states(v1::JOB_STATE_SUCCEEDED);
  v1::ListJobsResponse response;
  ASSERT_TRUE(s.stub->ListJobs(&context, request, &response).ok());
  ASSERT_EQ(response.jobs_size(), 1);
  EXPECT_EQ(response.jobs(0).id(), id);
  EXPECT_EQ(response.jobs(0).kind(), "isosurface");
}

TEST(Service, UploadedGridOver4MiBDrivesAScene) {
  LoopbackServer s;
  // A 110^3 sampled sphere SDF (5.3 MB of float32) uploaded in 1 MiB chunks.
  const int n = 110;
  std::string bytes(static_cast<std::size_t>(n) * n * n * sizeof(float), '\0');
  auto* values = reinterpret_cast<float*>(bytes.data());
  for (int k = 0; k < n; ++k)
    for (int j = 0; j < n; ++j)
      for (int i = 0; i < n; ++i) {
        const Vec3 p = Vec3(i, j, k) * (2.4 / (n - 1)) - Vec3::Constant(1.2);
        values[i + n * (j + n * k)] = static_cast<float>(p.norm() - 1.0);
      }
  grpc::ClientContext context;
  v1::UploadResponse response;
  auto writer = s.stub->Upload(&context, &response);
  for (std::size_t offset = 0; offset < bytes.size(); offset += 1 << 20) {
    v1::UploadChunk chunk;
    if (offset == 0) {
      chunk.set_name("sphere.f32");
      chunk.set_total_bytes(bytes.size());
    }
    chunk.set_data(bytes.substr(offset, 1 << 20));
    ASSERT_TRUE(writer->Write(chunk));
  }
  writer->WritesDone();
  ASSERT_TRUE(writer->Finish().ok());
  EXPECT_EQ(response.bytes(), bytes.size());

  auto scene = scene_from_json(R"({"root": {"grid": {"origin": {"x": -1.2, "y": -1.2, "z": -1.2},
      "spacing": {"x": 0.0220183486, "y": 0.0220183486, "z": 0.0220183486}, "nx": 110, "ny": 110, "nz": 110}}})");
  scene.mutable_root()->mutable_grid()->set_upload_id(response.upload_id());
  std::string id;
  ASSERT_TRUE(submit(*s.stub, isosurface_spec({scene}, 48), &id).ok());
  const auto result = watch_job(*s.stub, id);
  ASSERT_EQ(result.frames.size(), 1u) << result.final_job.error().message();
  const Mesh mesh = decode_draco(result.frames.at(0).bytes);
  EXPECT_TRUE(check_mesh(mesh).closed);
  for (const auto& v : mesh.vertices) EXPECT_NEAR(v.norm(), 1.0, 0.03);
}

TEST(Service, UploadOverTheLimitIsRefused) {
  server::ServerOptions options = LoopbackServer::default_options();
  options.limits.max_upload_bytes = 1000;
  LoopbackServer s(options);
  grpc::ClientContext context;
  v1::UploadResponse response;
  auto writer = s.stub->Upload(&context, &response);
  v1::UploadChunk chunk;
  chunk.set_data(std::string(2000, 'x'));
  writer->Write(chunk);
  writer->WritesDone();
  const auto status = writer->Finish();
  EXPECT_EQ(status.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
  EXPECT_NE(status.error_message().find("--max-upload-bytes"), std::string::npos);
}

TEST(Service, UnknownUploadIdIsInvalidArgument) {
  LoopbackServer s;
  auto scene = scene_from_json(R"({"root": {"grid": {"spacing": {"x": 1, "y": 1, "z": 1},
      "nx": 2, "ny": 2, "nz": 2, "uploadId": "u-missing"}}})");
  const auto status = submit(*s.stub, isosurface_spec({scene}, 8), nullptr);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(status.error_message().find("upload_id"), std::string::npos);
}

TEST(Service, ShutdownDrainsRunningJobs) {
  LoopbackServer s;
  std::string id;
  ASSERT_TRUE(submit(*s.stub, isosurface_spec({scene_from_json(kSphere)}, 160), &id).ok());
  WatchResult watched;
  std::thread watcher([&] { watched = watch_job(*s.stub, id); });
  wait_for_state(*s.stub, id, v1::JOB_STATE_RUNNING);
  s.server->shutdown(server::ShutdownMode::kDrain, std::chrono::seconds(60));
  watcher.join();
  // The running job was allowed to finish and its watcher got the frame and the final state.
  ASSERT_FALSE(watched.states.empty());
  EXPECT_EQ(watched.states.back(), v1::JOB_STATE_SUCCEEDED);
  EXPECT_EQ(watched.frames.size(), 1u);
  // After shutdown nothing is accepted.
  EXPECT_FALSE(submit(*s.stub, isosurface_spec({scene_from_json(kSphere)}, 8), nullptr).ok());
}

TEST(Service, ShutdownWithCancelStopsRunningJobs) {
  LoopbackServer s;
  std::string id;
  ASSERT_TRUE(submit(*s.stub, slow_spec(), &id).ok());
  WatchResult watched;
  std::thread watcher([&] { watched = watch_job(*s.stub, id); });
  wait_for_state(*s.stub, id, v1::JOB_STATE_RUNNING);
  const auto start = std::chrono::steady_clock::now();
  s.server->shutdown(server::ShutdownMode::kCancel, std::chrono::seconds(0));
  watcher.join();
  EXPECT_LT(std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count(), 3.0);
  ASSERT_FALSE(watched.states.empty());
  EXPECT_EQ(watched.states.back(), v1::JOB_STATE_CANCELLED);
}

}  // namespace
}  // namespace surfacer::testing
