// Service overhead: the isosurface job at ~1 M triangles, timed as
//   core     : marching_cubes alone (the work a library user would do),
//   frame    : core + mesh checks + Draco encode (what the service adds per frame, before any RPC),
//   local    : the whole job through the embedded (in-process) server: submit, watch, receive every chunk,
//   loopback : the same through a real server on 127.0.0.1.
// Prints median seconds and the ratios local/core and loopback/core (target <= 1.10), for one frame and for a
// sequence of frames (where frames run in parallel and encoding overlaps polygonizing), and a Draco speed sweep.
//
// Usage: service_bench [--scene FILE] [--cells N] [--frames F] [--repeat R]
#include <google/protobuf/util/json_util.h>
#include <grpcpp/grpcpp.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <functional>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "core/mesh/mesh_checks.h"
#include "core/mesh/mesh_codec.h"
#include "core/polygonize/marching_cubes.h"
#include "core/scene/scene.h"
#include "server/server.h"
#include "surfacer/v1/surfacer.grpc.pb.h"
#include "wire/scene.h"
#include "wire/uploads.h"

namespace {

using namespace surfacer;
using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point start) { return std::chrono::duration<double>(Clock::now() - start).count(); }

double median_time(int repeat, const std::function<void()>& f) {
  std::vector<double> t;
  for (int i = 0; i < repeat; ++i) {
    const auto start = Clock::now();
    f();
    t.push_back(seconds_since(start));
  }
  std::sort(t.begin(), t.end());
  return t[t.size() / 2];
}

// Runs the job to the end through `stub`, receiving every byte; returns the total triangles.
std::int64_t run_job(v1::Surfacer::Stub& stub, const v1::JobSpec& spec) {
  grpc::ClientContext submit_context;
  v1::SubmitJobRequest request;
  *request.mutable_spec() = spec;
  v1::SubmitJobResponse response;
  const auto status = stub.SubmitJob(&submit_context, request, &response);
  if (!status.ok()) {
    std::fprintf(stderr, "submit failed: %s\n", status.error_message().c_str());
    std::exit(1);
  }
  grpc::ClientContext context;
  v1::WatchJobRequest watch;
  watch.set_job_id(response.job_id());
  auto reader = stub.WatchJob(&context, watch);
  v1::JobEvent event;
  std::int64_t triangles = 0;
  std::size_t bytes = 0;
  v1::JobState state = v1::JOB_STATE_UNSPECIFIED;
  while (reader->Read(&event)) {
    if (event.has_frame()) triangles += event.frame().stats().triangles();
    if (event.has_chunk()) bytes += event.chunk().data().size();
    if (event.has_state()) state = event.state().state();
  }
  reader->Finish();
  if (state != v1::JOB_STATE_SUCCEEDED || bytes == 0) {
    std::fprintf(stderr, "job did not succeed\n");
    std::exit(1);
  }
  return triangles;
}

}  // namespace

int main(int argc, char** argv) {
  std::string scene_path = SURFACER_SOURCE_DIR "/examples/scenes/sphere.json";
  int cells = 330;
  int frames = 8;
  int repeat = 3;
  for (int i = 1; i + 1 < argc; i += 2) {
    if (!std::strcmp(argv[i], "--scene")) scene_path = argv[i + 1];
    if (!std::strcmp(argv[i], "--cells")) cells = std::atoi(argv[i + 1]);
    if (!std::strcmp(argv[i], "--frames")) frames = std::atoi(argv[i + 1]);
    if (!std::strcmp(argv[i], "--repeat")) repeat = std::atoi(argv[i + 1]);
  }
  std::ifstream in(scene_path);
  std::stringstream ss;
  ss << in.rdbuf();
  v1::Scene scene;
  if (!google::protobuf::util::JsonStringToMessage(ss.str(), &scene).ok()) {
    std::fprintf(stderr, "cannot parse %s\n", scene_path.c_str());
    return 1;
  }
  const Aabb bounds{Vec3::Constant(-1.2), Vec3::Constant(1.2)};
  auto make_spec = [&](int n) {
    v1::JobSpec spec;
    auto* iso = spec.mutable_isosurface();
    for (int i = 0; i < n; ++i) *iso->add_scenes() = scene;
    iso->set_cells(cells);                   // cubic bounds: exactly `cells` per axis
    iso->set_method(v1::POLYGONIZER_CUBES);  // the same polygonizer as the core-only baseline
    auto* min = iso->mutable_bounds()->mutable_min();
    auto* max = iso->mutable_bounds()->mutable_max();
    min->set_x(bounds.min.x());
    min->set_y(bounds.min.y());
    min->set_z(bounds.min.z());
    max->set_x(bounds.max.x());
    max->set_y(bounds.max.y());
    max->set_z(bounds.max.z());
    return spec;
  };
  const wire::MemoryUploads uploads;
  const FieldPtr field = wire::field_from_scene(scene, "scene", uploads);
  const int hw = std::max(1u, std::thread::hardware_concurrency());
  MarchingCubesOptions grid;
  grid.bounds = bounds;
  grid.cells = {cells, cells, cells};
  grid.threads = hw;
  grid.sparse = true;  // as the service runs it

  Mesh mesh;
  const double core = median_time(repeat, [&] { mesh = marching_cubes(*field, grid); });
  DracoOptions draco;
  draco.quantization_bounds = bounds;
  std::string encoded;
  const double check = median_time(repeat, [&] { check_mesh(mesh); });
  const double encode = median_time(repeat, [&] { encoded = encode_draco(mesh, draco); });
  const double decode = median_time(repeat, [&] { decode_draco(encoded); });
  const double raw_bytes = mesh.vertices.size() * 12.0 + mesh.triangles.size() * 12.0;
  std::printf("scene %s: %d^3 cells, %zu triangles, %d hardware threads, median of %d\n", scene_path.c_str(), cells,
              mesh.triangles.size(), hw, repeat);
  std::printf("  core     marching_cubes          %8.3f s\n", core);
  std::printf("           check_mesh              %8.3f s\n", check);
  std::printf("           draco encode            %8.3f s  (%.1f M triangles/s)\n", encode,
              mesh.triangles.size() / encode / 1e6);
  std::printf("           draco decode            %8.3f s  (%.1f M triangles/s)\n", decode,
              mesh.triangles.size() / decode / 1e6);
  std::printf("           draco size              %8.2f MB (raw float32 indexed %.2f MB, ratio %.1fx)\n",
              encoded.size() / 1e6, raw_bytes / 1e6, raw_bytes / encoded.size());

  std::printf("  draco speed sweep (encode s, decode s, bits per triangle):\n");
  for (int speed : {0, 3, 5, 6, 7, 8, 9, 10}) {
    DracoOptions o = draco;
    o.speed = speed;
    std::string bytes;
    const double enc = median_time(repeat, [&] { bytes = encode_draco(mesh, o); });
    const double dec = median_time(repeat, [&] { decode_draco(bytes); });
    std::printf("    speed %2d: %6.3f s  %6.3f s  %5.1f\n", speed, enc, dec,
                bytes.size() * 8.0 / mesh.triangles.size());
  }

  server::ServerOptions local_options;
  local_options.listen = "";
  auto local = server::SurfacerServer::start(local_options);
  auto local_stub = v1::Surfacer::NewStub(local->in_process_channel());
  server::ServerOptions tcp_options;
  tcp_options.listen = "127.0.0.1:0";
  auto tcp = server::SurfacerServer::start(tcp_options);
  auto tcp_stub = v1::Surfacer::NewStub(
      grpc::CreateChannel("127.0.0.1:" + std::to_string(tcp->port()), grpc::InsecureChannelCredentials()));

  for (int n : {1, frames}) {
    const auto spec = make_spec(n);
    const double base = n * core;
    const double with_frame = n * (core + check + encode);
    const double t_local = median_time(repeat, [&] { run_job(*local_stub, spec); });
    const double t_tcp = median_time(repeat, [&] { run_job(*tcp_stub, spec); });
    std::printf("%d frame(s):\n", n);
    std::printf("  core only (frames in turn, %d threads each)   %8.3f s\n", hw, base);
    std::printf("  core + checks + encode (in turn)              %8.3f s  ratio %.2f\n", with_frame, with_frame / base);
    std::printf("  --local (in-process server)                   %8.3f s  ratio %.2f\n", t_local, t_local / base);
    std::printf("  loopback server                               %8.3f s  ratio %.2f  (target <= 1.10)\n", t_tcp,
                t_tcp / base);
    std::printf("  RPC alone: loopback / (core + checks + encode in turn) = %.2f; loopback / local = %.2f\n",
                t_tcp / with_frame, t_tcp / t_local);
  }
  return 0;
}
