// Cancel in every stage of every job type frees the worker: on a one-worker server, a job is cancelled the moment
// its progress shows the stage under test, and the test measures when the job queued behind it starts. The stages
// are made long (up to seconds) so that the cancel lands inside them.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <functional>
#include <random>
#include <thread>

#include "core/util/geometry.h"
#include "tests/server/test_client.h"
#include "tests/support/files.h"

namespace surfacer::testing {
namespace {

using namespace std::chrono_literals;
using Clock = std::chrono::system_clock;

// The README promises 0.5 s; the bound leaves room for a loaded CI machine (the worker used to stay busy for
// seconds after a cancel in encode or check).
constexpr double kBoundSeconds = 1.0;

std::string upload(v1::Surfacer::Stub& stub, const std::string& bytes) {
  grpc::ClientContext context;
  v1::UploadResponse response;
  auto writer = stub.Upload(&context, &response);
  for (std::size_t offset = 0; offset < bytes.size(); offset += 1 << 20) {
    v1::UploadChunk chunk;
    if (offset == 0) chunk.set_total_bytes(bytes.size());
    chunk.set_data(bytes.substr(offset, 1 << 20));
    EXPECT_TRUE(writer->Write(chunk));
  }
  writer->WritesDone();
  EXPECT_TRUE(writer->Finish().ok());
  return response.upload_id();
}

// A jittered ball of particles (float32 x y z records) of spacing d.
std::string particle_ball(double radius, double d) {
  std::mt19937 rng(1);
  std::uniform_real_distribution<double> jitter(-0.15 * d, 0.15 * d);
  std::string bytes;
  const int n = static_cast<int>(std::ceil(radius / d));
  for (int i = -n; i <= n; ++i)
    for (int j = -n; j <= n; ++j)
      for (int k = -n; k <= n; ++k) {
        const Vec3 p = Vec3(i, j, k) * d;
        if (p.norm() > radius) continue;
        const float xyz[3] = {static_cast<float>(p.x() + jitter(rng)), static_cast<float>(p.y() + jitter(rng)),
                              static_cast<float>(p.z() + jitter(rng))};
        bytes.append(reinterpret_cast<const char*>(xyz), sizeof xyz);
      }
  return bytes;
}

void set_box(v1::Bounds* b, double lo, double hi) {
  b->mutable_min()->set_x(lo);
  b->mutable_min()->set_y(lo);
  b->mutable_min()->set_z(lo);
  b->mutable_max()->set_x(hi);
  b->mutable_max()->set_y(hi);
  b->mutable_max()->set_z(hi);
}

// A gyroid sheet filling a box: millions of triangles, polygonized in about a second, long to encode.
v1::JobSpec big_frame(v1::MeshEncoding encoding) {
  v1::JobSpec spec =
      isosurface_spec({scene_from_json(R"({"root": {"gyroid": {"period": 1.0, "thickness": 0.3}}})")}, 110);
  spec.mutable_isosurface()->set_method(v1::POLYGONIZER_CUBES);
  set_box(spec.mutable_isosurface()->mutable_bounds(), 0, 14);
  spec.mutable_output()->set_encoding(encoding);
  return spec;
}

v1::JobSpec slow_polygonize() {
  return isosurface_spec({scene_from_json(R"({"root": {"blobs": {"points": [
      {"center": {"x": -0.5}, "radius": 1.2}, {"center": {"x": 0.5}, "radius": 1.2},
      {"center": {"y": 0.6}, "radius": 1.0}]}}})")},
                         1000);
}

// The unit sphere intersected with a fine gyroid sheet at 1000 cells: hundreds of millions of triangles, so the
// polygonization runs until --max-triangles stops it (seconds at the default) unless cancelled.
v1::JobSpec dense_polygonize(v1::Polygonizer method) {
  v1::JobSpec spec = isosurface_spec({scene_from_json(R"({"root": {"intersection": {"children": [
      {"gyroid": {"period": 0.02, "thickness": 0.004}}, {"sphere": {"radius": 1.0}}]}}})")},
                                     1000);
  spec.mutable_isosurface()->set_method(method);
  return spec;
}

v1::JobSpec particles(v1::Surfacer::Stub& stub) {
  v1::JobSpec spec;
  auto* job = spec.mutable_particles();
  job->add_frames()->set_upload_id(upload(stub, particle_ball(0.6, 0.012)));
  job->set_r_inner(0.012);
  job->set_bilaplacian_sweeps(200);
  return spec;
}

v1::JobSpec optimize(int start_cells, int iterations) {
  v1::JobSpec spec;
  auto* job = spec.mutable_optimize();
  *job->mutable_scene() = scene_from_json(
      R"({"root": {"difference": {"children": [{"box": {"half_size": {"x": 1, "y": 0.6, "z": 0.4}}},
          {"cylinder": {"a": {"z": -1}, "b": {"z": 1}, "radius": 0.25}}]}}})");
  job->mutable_polygonize()->set_cells(start_cells);
  job->set_max_iterations(iterations);
  job->set_tolerance(1e-12);  // never met: the iterations run to the end
  return spec;
}

v1::JobSpec active_advect() {
  v1::JobSpec spec;
  auto* job = spec.mutable_active();
  *job->mutable_advect()->mutable_shape() =
      scene_from_json(R"({"root": {"sphere": {"center": {"x": 0.35, "y": 0.35, "z": 0.35}, "radius": 0.15}}})");
  job->mutable_advect()->mutable_enright();
  job->mutable_advect()->set_frame_interval(0.5);
  job->mutable_advect()->set_frames(4);
  job->set_grid_spacing(0.004);
  return spec;
}

struct StageCase {
  std::string name;
  std::string stage;  // the progress stage to cancel in
  std::function<v1::JobSpec(v1::Surfacer::Stub&)> spec;
  bool durable = false;  // the store's write: a data directory whose frame file is a slowly read FIFO
};

std::vector<StageCase> stage_cases() {
  auto iso = [](v1::JobSpec spec) { return [spec](v1::Surfacer::Stub&) { return spec; }; };
  return {
      {"isosurface_polygonize", "polygonize", iso(slow_polygonize())},
      {"isosurface_polygonize_dense_cubes", "polygonize", iso(dense_polygonize(v1::POLYGONIZER_CUBES))},
      {"isosurface_polygonize_dense_tiles", "polygonize", iso(dense_polygonize(v1::POLYGONIZER_TILES))},
      {"isosurface_check", "check", iso(big_frame(v1::MESH_ENCODING_DRACO))},
      {"isosurface_encode_draco", "encode", iso(big_frame(v1::MESH_ENCODING_DRACO))},
      {"isosurface_encode_draco_pieces", "encode", iso(big_frame(v1::MESH_ENCODING_DRACO_PIECES))},
      {"isosurface_store_write", "store", iso(big_frame(v1::MESH_ENCODING_PLY)), true},
      {"particles_field", "distance_field", particles},
      {"particles_polygonize", "polygonize", particles},
      {"particles_smoothing", "bilaplacian", particles},
      {"optimize_polygonize", "polygonize", iso(optimize(700, 10))},
      {"optimize_flows", "optimize", iso(optimize(160, 100000))},
      {"active_field", "evolve", iso(active_advect())},
  };
}

void PrintTo(const StageCase& c, std::ostream* out) { *out << c.name; }

class CancelStage : public ::testing::TestWithParam<StageCase> {};

TEST_P(CancelStage, TheNextQueuedJobStartsWithinHalfASecond) {
  const StageCase& c = GetParam();
  server::ServerOptions options = LoopbackServer::default_options();
  options.workers = 1;
  const auto dir = fresh_temp_dir("cancel_" + c.name);
  if (c.durable) options.data_dir = (dir / "data").string();
  LoopbackServer s(options);

  std::string slow, next;
  const grpc::Status submitted = submit(*s.stub, c.spec(*s.stub), &slow);
  ASSERT_TRUE(submitted.ok()) << submitted.error_message();
  ASSERT_TRUE(
      submit(*s.stub, isosurface_spec({scene_from_json(R"({"root": {"sphere": {"radius": 1}}})")}, 8), &next).ok());

  // The store's frame file as a FIFO read at ~20 MB/s: the write takes seconds, in pieces.
  std::atomic<bool> reading{true};
  std::thread reader;
  if (c.durable) {
    const auto frames = std::filesystem::path(options.data_dir) / "frames" / slow;
    std::filesystem::create_directories(frames);
    const auto fifo = frames / ".0.frame.tmp";
    ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
    reader = std::thread([fifo, &reading] {
      const int fd = ::open(fifo.c_str(), O_RDONLY);
      std::string buffer(1 << 16, '\0');
      std::size_t since_pause = 0;
      ssize_t n = 0;
      while (fd >= 0 && (n = ::read(fd, buffer.data(), buffer.size())) > 0) {
        since_pause += static_cast<std::size_t>(n);
        if (reading && since_pause >= (1u << 20)) {
          std::this_thread::sleep_for(50ms);
          since_pause = 0;
        }
      }
      if (fd >= 0) ::close(fd);
    });
  }

  // Follow the slow job until the stage begins.
  grpc::ClientContext watch_context;
  watch_context.set_deadline(Clock::now() + 120s);
  v1::WatchJobRequest request;
  request.set_job_id(slow);
  auto stream = s.stub->WatchJob(&watch_context, request);
  v1::JobEvent event;
  std::vector<std::string> stages;
  int frames_before = 0;  // frames the job finished before the stage (an evolving job's earlier frames)
  bool in_stage = false;
  while (!in_stage && stream->Read(&event)) {
    if (event.has_frame()) ++frames_before;
    if (!event.has_progress()) continue;
    if (stages.empty() || stages.back() != event.progress().stage()) stages.push_back(event.progress().stage());
    in_stage = event.progress().stage() == c.stage;
  }
  ASSERT_TRUE(in_stage) << "never saw stage " << c.stage << "; saw " << ::testing::PrintToString(stages);

  const auto cancelled_at = Clock::now();
  ASSERT_TRUE(cancel_job(*s.stub, slow).ok());
  // Measured here (the server's timestamps may be whole seconds): the first GetJob that finds it started.
  const auto until = Clock::now() + 60s;
  while (get_job(*s.stub, next).state() == v1::JOB_STATE_QUEUED && Clock::now() < until) {
    std::this_thread::sleep_for(2ms);
  }
  const double latency = std::chrono::duration<double>(Clock::now() - cancelled_at).count();
  reading = false;
  watch_context.TryCancel();
  if (reader.joinable()) reader.join();

  ASSERT_NE(get_job(*s.stub, next).state(), v1::JOB_STATE_QUEUED) << "the next job never started";
  RecordProperty("next_job_start_seconds", std::to_string(latency));
  EXPECT_LT(latency, kBoundSeconds) << "the next job started " << latency << " s after the cancel in stage " << c.stage;
  const v1::Job cancelled = get_job(*s.stub, slow);
  EXPECT_EQ(cancelled.state(), v1::JOB_STATE_CANCELLED);
  EXPECT_EQ(cancelled.frames_done(), frames_before) << "the cancel came after the stage: its frame was finished";
}

INSTANTIATE_TEST_SUITE_P(EveryStage, CancelStage, ::testing::ValuesIn(stage_cases()),
                         [](const auto& info) { return info.param.name; });

}  // namespace
}  // namespace surfacer::testing
