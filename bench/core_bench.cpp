// Core throughput: dense Marching Cubes, Draco encode/decode, mesh checks.
//   build-release/bench/core_bench --benchmark_counters_tabular=true
// Takes Google Benchmark's flags only (--benchmark_filter=REGEX, ...; --help lists them); anything else, or a flag
// Google Benchmark cannot parse, is an error (exit 2).
#include <benchmark/benchmark.h>

#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include "bench/bench_args.h"
#include "core/mesh/mesh_checks.h"
#include "core/mesh/mesh_codec.h"
#include "core/mesh/mesh_io.h"
#include "core/polygonize/marching_cubes.h"

namespace surfacer {
namespace {

enum FieldKind { kSphere = 0, kSines = 1 };

MarchingCubesOptions grid_options(int cells) {
  MarchingCubesOptions o;
  o.bounds = Aabb{Vec3::Zero(), Vec3::Ones()};
  o.cells = {cells, cells, cells};
  return o;
}

// (cells + 1)^3 samples on [0, 1]^3: a sphere of radius 0.4 (sparse surface) or sin-sum sheets with 4 periods per
// axis (dense surface, many more triangles).
std::vector<float> sample_field(FieldKind kind, int cells) {
  const int n = cells + 1;
  std::vector<float> s(static_cast<std::size_t>(n) * n * n);
  const double two_pi = 2.0 * std::acos(-1.0);
  std::size_t k = 0;
  for (int z = 0; z < n; ++z) {
    for (int y = 0; y < n; ++y) {
      for (int x = 0; x < n; ++x, ++k) {
        const Vec3 p(static_cast<double>(x) / cells, static_cast<double>(y) / cells, static_cast<double>(z) / cells);
        s[k] = kind == kSphere ? static_cast<float>((p - Vec3::Constant(0.5)).norm() - 0.4)
                               : static_cast<float>(std::sin(4 * two_pi * p.x()) + std::sin(4 * two_pi * p.y()) +
                                                    std::sin(4 * two_pi * p.z()) - 0.3);
      }
    }
  }
  return s;
}

const std::vector<float>& cached_field(FieldKind kind, int cells) {
  static std::vector<float> cache[2];
  static int cache_cells[2] = {0, 0};
  if (cache_cells[kind] != cells) {
    cache[kind] = sample_field(kind, cells);
    cache_cells[kind] = cells;
  }
  return cache[kind];
}

// Args: field kind, threads. Cells = 256^3.
void BM_MarchingCubesDense(benchmark::State& state) {
  const auto kind = static_cast<FieldKind>(state.range(0));
  const int cells = 256;
  const std::vector<float>& samples = cached_field(kind, cells);
  MarchingCubesOptions o = grid_options(cells);
  o.threads = static_cast<int>(state.range(1));
  std::size_t triangles = 0;
  for (auto _ : state) {
    const Mesh mesh = marching_cubes_samples(samples, o);
    triangles = mesh.triangles.size();
    benchmark::DoNotOptimize(mesh.vertices.data());
  }
  const double cells_total = static_cast<double>(cells) * cells * cells;
  state.counters["cells/s"] = benchmark::Counter(cells_total * state.iterations(), benchmark::Counter::kIsRate);
  state.counters["triangles"] = static_cast<double>(triangles);
  state.SetLabel(kind == kSphere ? "sphere" : "sines");
}
BENCHMARK(BM_MarchingCubesDense)
    ->ArgNames({"field", "threads"})
    ->Args({kSphere, 1})
    ->Args({kSphere, 2})
    ->Args({kSines, 1})
    ->Args({kSines, 2})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

// ~1 M triangles: the sines field on a 184^3 grid.
const Mesh& million_triangle_mesh() {
  static const Mesh mesh = [] {
    const int cells = 184;
    const std::vector<float> s = sample_field(kSines, cells);
    return marching_cubes_samples(s, grid_options(cells));
  }();
  return mesh;
}

double raw_ply_bytes(const Mesh& m) { return static_cast<double>(m.vertices.size()) * 12 + m.triangles.size() * 13.0; }

void BM_DracoEncode(benchmark::State& state) {
  const Mesh& mesh = million_triangle_mesh();
  DracoOptions options;  // 14 bits, speed 7
  options.quantization_bounds = Aabb{Vec3::Zero(), Vec3::Ones()};
  std::size_t bytes = 0;
  for (auto _ : state) {
    const std::string out = encode_draco(mesh, options);
    bytes = out.size();
    benchmark::DoNotOptimize(out.data());
  }
  const double raw = raw_ply_bytes(mesh);
  state.counters["MB/s"] = benchmark::Counter(raw * state.iterations() / 1e6, benchmark::Counter::kIsRate);
  state.counters["triangles/s"] =
      benchmark::Counter(static_cast<double>(mesh.triangles.size()) * state.iterations(), benchmark::Counter::kIsRate);
  state.counters["triangles"] = static_cast<double>(mesh.triangles.size());
  state.counters["ratio"] = raw / static_cast<double>(bytes);
  state.counters["bits/triangle"] = 8.0 * static_cast<double>(bytes) / static_cast<double>(mesh.triangles.size());
}
BENCHMARK(BM_DracoEncode)->Unit(benchmark::kMillisecond)->UseRealTime();

void BM_DracoDecode(benchmark::State& state) {
  const Mesh& mesh = million_triangle_mesh();
  DracoOptions options;
  options.quantization_bounds = Aabb{Vec3::Zero(), Vec3::Ones()};
  const std::string bytes = encode_draco(mesh, options);
  for (auto _ : state) {
    const Mesh decoded = decode_draco(bytes);
    benchmark::DoNotOptimize(decoded.vertices.data());
  }
  const double raw = raw_ply_bytes(mesh);
  state.counters["MB/s"] = benchmark::Counter(raw * state.iterations() / 1e6, benchmark::Counter::kIsRate);
  state.counters["triangles/s"] =
      benchmark::Counter(static_cast<double>(mesh.triangles.size()) * state.iterations(), benchmark::Counter::kIsRate);
  state.counters["ratio"] = raw / static_cast<double>(bytes.size());
}
BENCHMARK(BM_DracoDecode)->Unit(benchmark::kMillisecond)->UseRealTime();

void BM_CheckMesh(benchmark::State& state) {
  const Mesh& mesh = million_triangle_mesh();
  for (auto _ : state) {
    const MeshReport report = check_mesh(mesh);
    benchmark::DoNotOptimize(report.volume);
  }
  state.counters["triangles/s"] =
      benchmark::Counter(static_cast<double>(mesh.triangles.size()) * state.iterations(), benchmark::Counter::kIsRate);
  state.counters["triangles"] = static_cast<double>(mesh.triangles.size());
}
BENCHMARK(BM_CheckMesh)->Unit(benchmark::kMillisecond)->UseRealTime();

void BM_WritePlyBinary(benchmark::State& state) {
  const Mesh& mesh = million_triangle_mesh();
  for (auto _ : state) {
    const std::string out = write_ply(mesh);
    benchmark::DoNotOptimize(out.data());
  }
  state.counters["MB/s"] =
      benchmark::Counter(raw_ply_bytes(mesh) * state.iterations() / 1e6, benchmark::Counter::kIsRate);
}
BENCHMARK(BM_WritePlyBinary)->Unit(benchmark::kMillisecond)->UseRealTime();

constexpr const char* kUsage = "usage: core_bench [--benchmark_<flag>=<value>]... [--v=<verbosity>]\n";

}  // namespace
}  // namespace surfacer

// BENCHMARK_MAIN, as strict as the other benches: Google Benchmark alone exits 1 on an unknown flag and 0 (after its
// help) on a --benchmark_format, --benchmark_out_format, --benchmark_color or --benchmark_time_unit it does not know.
int main(int argc, char** argv) {
  using namespace surfacer;
  bench::Args args(argc, argv, "core_bench", kUsage, [] {
    std::printf("Google Benchmark's flags:\n");
    benchmark::PrintDefaultHelp();
  });
  while (args.next()) {
    if (!args.flag().starts_with("--benchmark_") && !args.flag().starts_with("--v=")) args.unknown();
  }
  // Initialize calls this on a value it does not know instead of exiting 0; a handler cannot capture, hence the static.
  static const bench::Args* const parser = &args;
  benchmark::Initialize(&argc, argv, [] {
    parser->error(
        "--benchmark_format and --benchmark_out_format take console, json or csv, --benchmark_color auto, true or "
        "false, --benchmark_time_unit ns, us, ms or s");
  });
  // Initialize leaves in argv the flags it did not take: unknown ones and values it cannot parse.
  if (argc > 1) args.error("Google Benchmark does not take '" + std::string(argv[1]) + "' (see --help)");
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
