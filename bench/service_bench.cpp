// What the service adds to polygonizing (docs/ALGORITHMS.md §5 "Frames"), with the old path beside the new in the
// same run:
//   1. jobs   : a single-frame isosurface job (cubes and tiles, default 256 cells) through the in-process server,
//               for every codec: the frame's polygonize / encode / check seconds, the job's wall time (submit to
//               the last byte received) and the overhead ratio total / polygonize;
//   2. encode : the frame's encode on 1, 2 and 4 threads (Draco pieces, meshopt) against the standard one-mesh Draco
//               encode (one thread: the old path), as a ratio;
//   3. codecs : bytes per triangle, encode and decode MB/s (of the raw float32 indexed mesh) for every codec;
//   4. checks : check_mesh on 1 and all threads, as a share of the polygonize time;
//   5. sequence: a 24-frame sequence through the in-process server, standard Draco and Draco pieces: wall, CPU
//               seconds and utilization = CPU / (wall x hardware threads);
//   6. RPC    : the same single-frame job through a loopback server against the in-process one;
//   7. the Draco speed sweep (encode s, decode s, bits per triangle).
// Medians of --repeat runs (section 5's sequence runs once). Usage:
//   service_bench [--scene FILE] [--cells N] [--frames F] [--sequence-cells N] [--repeat R]
//                 [--section 1..7 (one only; 4 comes with 1)]
// --frames and --sequence-cells are section 5's, --cells and --repeat every other section's: given with a --section
// they do not apply to, they are refused like a bad value (exit 2).
#include <google/protobuf/util/json_util.h>
#include <grpcpp/grpcpp.h>
#include <sys/resource.h>
#include <time.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <fstream>
#include <functional>
#include <map>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "bench/bench_args.h"
#include "core/mesh/frame_codec.h"
#include "core/mesh/mesh_checks.h"
#include "core/polygonize/polygonize.h"
#include "core/scene/scene.h"
#include "server/server.h"
#include "surfacer/v1/surfacer.grpc.pb.h"
#include "wire/output.h"
#include "wire/scene.h"
#include "wire/uploads.h"

namespace {

using namespace surfacer;
using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point start) { return std::chrono::duration<double>(Clock::now() - start).count(); }

double median(std::vector<double> t) {
  std::sort(t.begin(), t.end());
  return t[t.size() / 2];
}

double median_time(int repeat, const std::function<void()>& f) {
  std::vector<double> t;
  for (int i = 0; i < repeat; ++i) {
    const auto start = Clock::now();
    f();
    t.push_back(seconds_since(start));
  }
  return median(t);
}

double cpu_seconds() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return u.ru_utime.tv_sec + u.ru_stime.tv_sec + 1e-6 * (u.ru_utime.tv_usec + u.ru_stime.tv_usec);
}

// The cores this process gets right now: `threads` busy threads for `seconds`, their CPU time over the wall time. On
// a machine shared with other work (a CI runner, a build) utilization is also printed against this.
double available_cores(int threads, double seconds = 0.5) {
  std::vector<std::thread> spinners;
  std::vector<double> cpu(threads, 0.0);
  for (int t = 0; t < threads; ++t) {
    spinners.emplace_back([&, t] {
      timespec a{}, b{};
      clock_gettime(CLOCK_THREAD_CPUTIME_ID, &a);
      const auto start = Clock::now();
      volatile double x = 0.0;
      while (seconds_since(start) < seconds) x = x + 1.0;
      clock_gettime(CLOCK_THREAD_CPUTIME_ID, &b);
      cpu[t] = (b.tv_sec - a.tv_sec) + 1e-9 * (b.tv_nsec - a.tv_nsec);
    });
  }
  for (auto& s : spinners) s.join();
  double sum = 0.0;
  for (double c : cpu) sum += c;
  return sum / seconds;
}

struct JobResult {
  double wall = 0.0;
  std::int64_t triangles = 0;
  std::size_t bytes = 0;
  std::map<std::string, double> stage_seconds;  // summed over frames

  double stage(const std::string& name) const {
    const auto it = stage_seconds.find(name);
    return it == stage_seconds.end() ? 0.0 : it->second;
  }
};

// Runs the job to the end through `stub`, receiving every byte.
JobResult run_job(v1::Surfacer::Stub& stub, const v1::JobSpec& spec) {
  const auto start = Clock::now();
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
  JobResult result;
  v1::JobState state = v1::JOB_STATE_UNSPECIFIED;
  while (reader->Read(&event)) {
    if (event.has_frame()) {
      result.triangles += event.frame().stats().triangles();
      for (const auto& t : event.frame().stats().timings()) result.stage_seconds[t.stage()] += t.seconds();
    }
    if (event.has_chunk()) result.bytes += event.chunk().data().size();
    if (event.has_state()) state = event.state().state();
  }
  reader->Finish();
  result.wall = seconds_since(start);
  if (state != v1::JOB_STATE_SUCCEEDED || result.bytes == 0) {
    std::fprintf(stderr, "job did not succeed\n");
    std::exit(1);
  }
  return result;
}

// The run of median wall time.
JobResult median_job(int repeat, v1::Surfacer::Stub& stub, const v1::JobSpec& spec) {
  std::vector<JobResult> runs;
  for (int i = 0; i < repeat; ++i) runs.push_back(run_job(stub, spec));
  std::sort(runs.begin(), runs.end(), [](const JobResult& a, const JobResult& b) { return a.wall < b.wall; });
  return runs[runs.size() / 2];
}

const FrameCodec kCodecs[] = {FrameCodec::kDraco, FrameCodec::kDracoPieces, FrameCodec::kMeshopt, FrameCodec::kPly};

constexpr const char* kUsage =
    "usage: service_bench [--scene FILE] [--cells N] [--frames F] [--sequence-cells N] [--repeat R]\n"
    "                     [--section 1..7]\n";

}  // namespace

int main(int argc, char** argv) {
  std::string scene_path = SURFACER_SOURCE_DIR "/examples/scenes/gyroid_in_sphere.json";
  int cells = 256;
  int frames = 24;
  int sequence_cells = 128;
  int repeat = 3;
  int section = 0;  // 0: all
  // The last flag given that only section 5 (the sequence) uses, and the last that only the single-frame sections use.
  std::string sequence_flag, single_frame_flag;
  bench::Args args(argc, argv, "service_bench", kUsage);
  while (args.next()) {
    const std::string& flag = args.flag();
    if (flag == "--scene") {
      scene_path = args.value("a file");
    } else if (flag == "--cells") {
      cells = args.integer(1);
      single_frame_flag = flag;
    } else if (flag == "--frames") {
      frames = args.integer(1);
      sequence_flag = flag;
    } else if (flag == "--sequence-cells") {
      sequence_cells = args.integer(1);
      sequence_flag = flag;
    } else if (flag == "--repeat") {
      repeat = args.integer(1);
      single_frame_flag = flag;
    } else if (flag == "--section") {
      section = args.integer(1, 7);
    } else {
      args.unknown();
    }
  }
  if (section == 5 && !single_frame_flag.empty()) {
    args.error(single_frame_flag + " does not apply to section 5 (the sequence)");
  }
  if (section != 0 && section != 5 && !sequence_flag.empty()) {
    args.error(sequence_flag + " applies to section 5 (the sequence) only");
  }
  std::ifstream in(scene_path);
  std::stringstream ss;
  ss << in.rdbuf();
  v1::Scene scene;
  if (!google::protobuf::util::JsonStringToMessage(ss.str(), &scene).ok()) {
    std::fprintf(stderr, "cannot parse %s\n", scene_path.c_str());
    return 1;
  }
  const int hw = std::max(1u, std::thread::hardware_concurrency());
  const wire::MemoryUploads uploads;
  const FieldPtr field = wire::field_from_scene(scene, "scene", uploads);
  auto make_spec = [&](int n, int job_cells, v1::Polygonizer method, FrameCodec codec) {
    v1::JobSpec spec;
    auto* iso = spec.mutable_isosurface();
    for (int i = 0; i < n; ++i) *iso->add_scenes() = scene;
    iso->set_cells(job_cells);
    iso->set_method(method);
    spec.mutable_output()->set_encoding(wire::mesh_encoding(codec));
    return spec;
  };
  std::printf("scene %s, %d hardware threads, medians of %d\n", scene_path.c_str(), hw, repeat);

  server::ServerOptions local_options;
  local_options.listen = "";
  auto local = server::SurfacerServer::start(local_options);
  auto local_stub = v1::Surfacer::NewStub(local->in_process_channel());

  Mesh cubes_mesh;
  Aabb cubes_box;
  double cubes_polygonize = 0.0;
  // The checks (4) measure section 1's meshes, so 4 runs 1.
  auto want = [&](int k) { return section == 0 || section == k || (k == 1 && section == 4); };
  for (const auto method : {Polygonizer::kCubes, Polygonizer::kTiles}) {
    if (!want(1) && !(method == Polygonizer::kCubes && (want(2) || want(3) || want(6) || want(7)))) continue;
    const auto proto_method = method == Polygonizer::kCubes ? v1::POLYGONIZER_CUBES : v1::POLYGONIZER_TILES;
    PolygonizeOptions options;
    options.method = method;
    options.cells = cells;
    const FieldPtr fields[] = {field};
    const PolygonizeGrid grid = resolve_grid(fields, options);
    Mesh mesh;
    const double polygonize_core = median_time(repeat, [&] { mesh = polygonize(*field, grid); });
    if (method == Polygonizer::kCubes) {
      cubes_box = grid.bounds;
      cubes_polygonize = polygonize_core;
    }
    if (!want(1)) {
      cubes_mesh = std::move(mesh);
      continue;
    }
    std::printf("\n1. single-frame jobs, %s at %d cells: %zu triangles; polygonize alone %.3f s\n",
                std::string(polygonizer_name(method)).c_str(), cells, mesh.triangles.size(), polygonize_core);
    std::printf("   %-13s %10s %8s %8s %8s %10s %8s\n", "codec", "polygonize", "encode", "check", "total", "total/poly",
                "B/tri");
    for (FrameCodec codec : kCodecs) {
      const JobResult r = median_job(repeat, *local_stub, make_spec(1, cells, proto_method, codec));
      const double poly = r.stage("polygonize");
      std::printf("   %-13s %10.3f %8.3f %8.3f %8.3f %10.2f %8.2f\n", std::string(frame_codec_name(codec)).c_str(),
                  poly, r.stage("encode"), r.stage("check"), r.wall, r.wall / poly,
                  static_cast<double>(r.bytes) / static_cast<double>(r.triangles));
    }
    const int one = 1, all = hw;
    const double check_one = median_time(repeat, [&] { check_mesh(mesh, one); });
    const double check_all = median_time(repeat, [&] { check_mesh(mesh, all); });
    std::printf("4. checks: %.3f s on 1 thread, %.3f s on %d (%.1f %% of polygonize; target <= 15 %%)\n", check_one,
                check_all, hw, 100.0 * check_all / polygonize_core);
    if (method == Polygonizer::kCubes) cubes_mesh = std::move(mesh);
  }

  // 2, 3, 6 and 7 on the cubes mesh (the >= 2 M-triangle frame at 256 cells).
  const Mesh& mesh = cubes_mesh;
  FrameCodecOptions options;
  options.draco.quantization_bounds = cubes_box;
  const double raw_mb = (mesh.vertices.size() * 12.0 + mesh.triangles.size() * 12.0) / 1e6;

  if (want(2)) {
    options.codec = FrameCodec::kDraco;
    const double standard = median_time(repeat, [&] { encode_frame(mesh, options, 1); });
    std::printf("\n2. encode of the %zu-triangle cubes frame; old path: one Draco mesh on 1 thread, %.3f s\n",
                mesh.triangles.size(), standard);
    for (FrameCodec codec : {FrameCodec::kDracoPieces, FrameCodec::kMeshopt}) {
      options.codec = codec;
      for (int threads : {1, 2, 4}) {
        const double t = median_time(repeat, [&] { encode_frame(mesh, options, threads); });
        std::printf("   %-13s %d thread%s %8.3f s  %.2fx the old path%s\n",
                    std::string(frame_codec_name(codec)).c_str(), threads, threads == 1 ? " " : "s", t, t / standard,
                    codec == FrameCodec::kDracoPieces && threads == 2 ? " (target <= 0.55x on 2 cores)" : "");
      }
    }
  }

  if (want(3)) {
    std::printf("\n3. codecs on the same frame (MB/s of the raw float32 mesh, %.1f MB; %d threads)\n", raw_mb, hw);
    std::printf("   %-13s %8s %12s %12s\n", "codec", "B/tri", "encode MB/s", "decode MB/s");
    for (FrameCodec codec : kCodecs) {
      options.codec = codec;
      std::string bytes;
      const int all = hw;
      const double enc = median_time(repeat, [&] { bytes = encode_frame(mesh, options, all); });
      const double dec = median_time(repeat, [&] { decode_frame(bytes, codec, all); });
      std::printf("   %-13s %8.2f %12.1f %12.1f\n", std::string(frame_codec_name(codec)).c_str(),
                  static_cast<double>(bytes.size()) / mesh.triangles.size(), raw_mb / enc, raw_mb / dec);
    }
  }

  if (want(5)) {
    std::printf("\n5. a %d-frame sequence at %d cells (cubes) through the in-process server\n", frames, sequence_cells);
    for (FrameCodec codec : {FrameCodec::kDraco, FrameCodec::kDracoPieces, FrameCodec::kMeshopt}) {
      const auto spec = make_spec(frames, sequence_cells, v1::POLYGONIZER_CUBES, codec);
      const double before = available_cores(hw);
      const double cpu0 = cpu_seconds();
      const JobResult r = run_job(*local_stub, spec);
      const double cpu = cpu_seconds() - cpu0;
      const double available = std::min<double>(hw, 0.5 * (before + available_cores(hw)));
      std::printf(
          "   %-13s wall %7.3f s  CPU %7.3f s  utilization %5.1f %% of %d cores (target >= 90 %%), %5.1f %% "
          "of the %.2f cores this process got around it\n",
          std::string(frame_codec_name(codec)).c_str(), r.wall, cpu, 100.0 * cpu / (r.wall * hw), hw,
          100.0 * cpu / (r.wall * available), available);
    }
  }

  if (want(6)) {
    server::ServerOptions tcp_options;
    tcp_options.listen = "127.0.0.1:0";
    auto tcp = server::SurfacerServer::start(tcp_options);
    auto tcp_stub = v1::Surfacer::NewStub(
        grpc::CreateChannel("127.0.0.1:" + std::to_string(tcp->port()), grpc::InsecureChannelCredentials()));
    std::printf("\n6. RPC: the cubes job through a loopback server / in-process (polygonize alone %.3f s)\n",
                cubes_polygonize);
    for (FrameCodec codec : {FrameCodec::kDraco, FrameCodec::kMeshopt}) {
      const auto spec = make_spec(1, cells, v1::POLYGONIZER_CUBES, codec);
      const double t_local = median_job(repeat, *local_stub, spec).wall;
      const double t_tcp = median_job(repeat, *tcp_stub, spec).wall;
      std::printf("   %-13s in-process %7.3f s  loopback %7.3f s  ratio %.2f\n",
                  std::string(frame_codec_name(codec)).c_str(), t_local, t_tcp, t_tcp / t_local);
    }
  }

  if (want(7)) {
    std::printf("\n7. Draco speed sweep on the cubes frame (encode s, decode s, bits per triangle)\n");
    for (int speed : {0, 3, 5, 6, 7, 8, 9, 10}) {
      DracoOptions o = options.draco;
      o.speed = speed;
      std::string bytes;
      const double enc = median_time(repeat, [&] { bytes = encode_draco(mesh, o); });
      const double dec = median_time(repeat, [&] { decode_draco(bytes); });
      std::printf("   speed %2d: %6.3f s  %6.3f s  %5.1f\n", speed, enc, dec,
                  bytes.size() * 8.0 / mesh.triangles.size());
    }
  }
  return 0;
}
