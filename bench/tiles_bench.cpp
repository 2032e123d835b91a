// Marching Tiles vs Marching Cubes (issue 3): prints tables, all measured in this process.
//   build-tiles/bench/tiles_bench            (full run, a few minutes on 2 cores)
//   build-tiles/bench/tiles_bench --quick    (smaller grids)
// Times are the best of several runs (the machine is shared; the minimum is the least disturbed run).
//
// 1. Tiles vs cubes on the same fields at the same sample spacing h (cube cell = mean tile edge = h): time, field
//    evaluations (counted by a wrapper Field in a separate run, so counting does not slow the timed runs),
//    triangles, valence histogram, minimum angle. Cubes run dense (every grid point) and sparse (Lipschitz
//    quadtree); tiles are always sparse.
// 2. Dense Marching Cubes throughput on 256^3 pre-sampled fields (anchor: VTK vtkFlyingEdges3D ~190 M cells/s on
//    this 2-core machine) and on a 256^3 analytic field evaluated on the fly.
// 3. Time per field evaluation, tiles / cubes (target: tiles within 2x).
// 4. Parallel speedup of tiles (1 vs 2 threads).
// 5. Sparse scaling: spacing h -> h/2 -> h/4: time, evaluations, triangles and peak memory (ru_maxrss growth of one
//    run in a fresh process), with ratios per halving (surface area: ~4x; volume: ~8x).
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <ctime>
#include <functional>
#include <string>
#include <thread>
#include <vector>

#include "core/marching_cubes.h"
#include "core/marching_tiles.h"
#include "core/mesh_checks.h"
#include "core/scene.h"

namespace surfacer {
namespace {

class CountingField final : public Field {
 public:
  explicit CountingField(const Field& inner) : inner_(inner) {}
  double value(const Vec3& p) const override {
    calls_.fetch_add(1, std::memory_order_relaxed);
    return inner_.value(p);
  }
  double value_and_gradient(const Vec3& p, Vec3& g) const override { return inner_.value_and_gradient(p, g); }
  std::optional<Aabb> bounds() const override { return inner_.bounds(); }
  std::optional<double> lipschitz_bound() const override { return inner_.lipschitz_bound(); }
  std::int64_t calls() const { return calls_.load(); }

 private:
  const Field& inner_;
  mutable std::atomic<std::int64_t> calls_{0};
};

double now_ms() {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

double cpu_ms() {
  timespec t{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
  return static_cast<double>(t.tv_sec) * 1e3 + static_cast<double>(t.tv_nsec) * 1e-6;
}

// Best (smallest) wall time of `reps` runs (ms): the machine is shared, and the minimum is the run least disturbed
// by other processes. `cpu` (if given) receives the smallest process CPU time (all threads) of a run: the work done,
// much less sensitive than wall time to other processes taking a core.
double time_ms(int reps, const std::function<void()>& run, double* cpu = nullptr) {
  double best = HUGE_VAL, best_cpu = HUGE_VAL;
  for (int i = 0; i < reps; ++i) {
    const double t0 = now_ms(), c0 = cpu_ms();
    run();
    best = std::min(best, now_ms() - t0);
    best_cpu = std::min(best_cpu, cpu_ms() - c0);
  }
  if (cpu != nullptr) *cpu = best_cpu;
  return best;
}

// "VmHWM" (peak resident set) of this process in MB, from /proc/self/status. (getrusage's ru_maxrss would carry the
// forking parent's peak across exec.)
double peak_rss_mb() {
  FILE* f = std::fopen("/proc/self/status", "r");
  if (f == nullptr) return -1.0;
  char line[256];
  double kb = -1.0;
  while (std::fgets(line, sizeof line, f) != nullptr) {
    if (std::strncmp(line, "VmHWM:", 6) == 0) kb = std::atof(line + 6);
  }
  std::fclose(f);
  return kb / 1024.0;
}

// Peak resident memory growth (MB) of one run, measured in a fresh process (this binary re-executed with
// --memory-run, so no heap left over from earlier runs can hide the growth): peak RSS after the run minus before.
double peak_growth_mb(const char* method, int field, double spacing) {
  int fd[2];
  if (pipe(fd) != 0) return -1.0;
  const pid_t pid = fork();
  if (pid == 0) {
    close(fd[0]);
    dup2(fd[1], STDOUT_FILENO);
    const std::string f = std::to_string(field), h = std::to_string(spacing);
    execl("/proc/self/exe", "tiles_bench", "--memory-run", method, f.c_str(), h.c_str(), static_cast<char*>(nullptr));
    _exit(127);
  }
  close(fd[1]);
  char buf[64] = {};
  const ssize_t n = read(fd[0], buf, sizeof buf - 1);
  close(fd[0]);
  int status = 0;
  waitpid(pid, &status, 0);
  return n > 0 ? std::atof(buf) : -1.0;
}

struct Named {
  const char* name;
  FieldPtr field;
  Aabb bounds;
};

std::vector<Named> fields() {
  const Vec3 c(0.013, -0.007, 0.004);
  const double a = 0.5, r = 0.22;
  return {
      {"sphere", make_sphere(c, 0.8), Aabb{Vec3::Constant(-1), Vec3::Constant(1)}},
      {"torus", make_torus(c, Vec3(0.3, 0.2, 1.0), 0.6, 0.25), Aabb{Vec3::Constant(-1), Vec3::Constant(1)}},
      {"csg block",
       make_csg(CsgOp::kDifference,
                {make_box(c, Vec3::Constant(a)), make_cylinder(c - Vec3(0.8, 0, 0), c + Vec3(0.8, 0, 0), r),
                 make_cylinder(c - Vec3(0, 0.8, 0), c + Vec3(0, 0.8, 0), r),
                 make_cylinder(c - Vec3(0, 0, 0.8), c + Vec3(0, 0, 0.8), r)}),
       Aabb{Vec3::Constant(-0.7), Vec3::Constant(0.7)}},
      {"gyroid in sphere", make_csg(CsgOp::kIntersection, {make_gyroid(0.8, 0.16), make_sphere(c, 0.7)}),
       Aabb{Vec3::Constant(-0.75), Vec3::Constant(0.75)}},
  };
}

std::string histogram(const MeshReport& r) {
  std::string s;
  const double n = [&] {
    double t = 0;
    for (auto v : r.valence_histogram) t += static_cast<double>(v);
    return t;
  }();
  char buf[32];
  for (int v = 3; v <= 9; ++v) {
    double c = 0;
    if (v < 9) {
      c = v < static_cast<int>(r.valence_histogram.size()) ? static_cast<double>(r.valence_histogram[v]) : 0.0;
    } else {
      for (std::size_t w = 9; w < r.valence_histogram.size(); ++w) c += static_cast<double>(r.valence_histogram[w]);
    }
    std::snprintf(buf, sizeof buf, "%5.1f", 100.0 * c / n);
    s += buf;
  }
  return s;
}

struct RunResult {
  double ms = 0;
  double cpu = 0;  // ms of CPU time, all threads
  std::int64_t evals = 0;
  MeshReport report;
  std::size_t triangles = 0;
};

RunResult run_cubes(const Named& f, double h, bool sparse, int threads, int reps) {
  MarchingCubesOptions o;
  o.bounds = f.bounds;
  for (int a = 0; a < 3; ++a) o.cells[a] = static_cast<int>(std::lround(f.bounds.size()[a] / h));
  o.sparse = sparse;
  o.threads = threads;
  RunResult r;
  r.ms = time_ms(
      reps, [&] { marching_cubes(*f.field, o); }, &r.cpu);
  CountingField counter(*f.field);
  const Mesh m = marching_cubes(counter, o);
  r.evals = counter.calls();
  r.report = check_mesh(m);
  r.triangles = m.triangles.size();
  return r;
}

RunResult run_tiles(const Named& f, double h, int threads, int reps) {
  MarchingTilesOptions o;
  o.bounds = f.bounds;
  o.spacing = h;
  o.threads = threads;
  RunResult r;
  r.ms = time_ms(
      reps, [&] { marching_tiles(*f.field, o); }, &r.cpu);
  CountingField counter(*f.field);
  const Mesh m = marching_tiles(counter, o);
  r.evals = counter.calls();
  r.report = check_mesh(m);
  r.triangles = m.triangles.size();
  return r;
}

void print_row(const char* field, const char* method, const RunResult& r) {
  std::printf("%-17s %-16s %8.1f %8.1f %10lld %8.1f %9zu %5d %6.2f %s\n", field, method, r.ms, r.cpu,
              static_cast<long long>(r.evals), 1e6 * r.cpu / static_cast<double>(std::max<std::int64_t>(1, r.evals)),
              r.triangles, r.report.min_valence, r.report.min_angle_degrees, histogram(r.report).c_str());
}

void section_compare(double h, int reps) {
  std::printf(
      "\n== 1/3. Tiles vs cubes at the same sample spacing h = %.4f (cube cell = mean tile edge), 2 threads ==\n", h);
  std::printf("%-17s %-16s %8s %8s %10s %8s %9s %5s %6s %s\n", "field", "method", "wall ms", "cpu ms", "evals",
              "cpu ns/ev", "triangles", "minV", "minAng", "valence %: 3    4    5    6    7    8   9+");
  for (const Named& f : fields()) {
    const RunResult dense = run_cubes(f, h, false, 2, reps);
    const RunResult sparse = run_cubes(f, h, true, 2, reps);
    const RunResult tiles = run_tiles(f, h, 2, reps);
    // Equal sample density: a tile lattice of spacing s has 1.53 / s^3 points per volume; s = 1.152 h matches the
    // cube grid's 1 / h^3.
    const RunResult tiles_eq = run_tiles(f, 1.152 * h, 2, reps);
    print_row(f.name, "cubes dense", dense);
    print_row(f.name, "cubes sparse", sparse);
    print_row(f.name, "tiles", tiles);
    print_row(f.name, "tiles s=1.152h", tiles_eq);
    const auto per = [](const RunResult& r) { return r.cpu / static_cast<double>(r.evals); };
    std::printf(
        "%-17s tiles/cubes: cpu time %.2f (dense) %.2f (sparse); evals %.3f (dense) %.2f (sparse); "
        "cpu time per eval %.2f (dense) %.2f (sparse); triangles %.2f\n",
        f.name, tiles.cpu / dense.cpu, tiles.cpu / sparse.cpu,
        static_cast<double>(tiles.evals) / static_cast<double>(dense.evals),
        static_cast<double>(tiles.evals) / static_cast<double>(sparse.evals), per(tiles) / per(dense),
        per(tiles) / per(sparse), static_cast<double>(tiles.triangles) / static_cast<double>(dense.triangles));
  }
}

void section_dense_throughput(int cells, int reps) {
  std::printf("\n== 2. Dense Marching Cubes throughput, %d^3 cells ==\n", cells);
  const int n = cells + 1;
  std::vector<float> sphere(static_cast<std::size_t>(n) * n * n), sines(sphere.size());
  const double two_pi = 2.0 * std::acos(-1.0);
  std::size_t k = 0;
  for (int z = 0; z < n; ++z) {
    for (int y = 0; y < n; ++y) {
      for (int x = 0; x < n; ++x, ++k) {
        const Vec3 p(static_cast<double>(x) / cells, static_cast<double>(y) / cells, static_cast<double>(z) / cells);
        sphere[k] = static_cast<float>((p - Vec3::Constant(0.5)).norm() - 0.4);
        sines[k] = static_cast<float>(std::sin(4 * two_pi * p.x()) + std::sin(4 * two_pi * p.y()) +
                                      std::sin(4 * two_pi * p.z()) - 0.3);
      }
    }
  }
  MarchingCubesOptions o;
  o.bounds = Aabb{Vec3::Zero(), Vec3::Ones()};
  o.cells = {cells, cells, cells};
  const double total = static_cast<double>(cells) * cells * cells;
  std::printf("%-34s %8s %9s %12s\n", "input", "threads", "ms", "M cells/s");
  for (const auto& [name, samples] :
       {std::pair<const char*, const std::vector<float>*>{"samples: sphere r=0.4", &sphere},
        std::pair<const char*, const std::vector<float>*>{"samples: sines (4 periods)", &sines}}) {
    for (int threads : {1, 2}) {
      o.threads = threads;
      const double ms = time_ms(reps, [&] { marching_cubes_samples(*samples, o); });
      std::printf("%-34s %8d %9.1f %12.1f\n", name, threads, ms, total / ms / 1e3);
    }
  }
  const FieldPtr f = make_sphere(Vec3::Constant(0.5), 0.4);
  for (bool sparse : {false, true}) {
    for (int threads : {1, 2}) {
      o.threads = threads;
      o.sparse = sparse;
      const double ms = time_ms(reps, [&] { marching_cubes(*f, o); });
      std::printf("%-34s %8d %9.1f %12.1f\n", sparse ? "field: sphere, sparse" : "field: sphere, dense", threads, ms,
                  total / ms / 1e3);
    }
  }
  std::printf("(anchor: VTK vtkFlyingEdges3D on 256^3 samples ~90 ms = ~190 M cells/s on this machine)\n");
}

// Both cores: tiles with 1 and 2 threads on every field. "CPU/wall" is process CPU time over wall time of the best
// 2-thread run: ~2 when both cores were busy (lower when other processes took a core).
void section_threads(double h, int reps) {
  std::printf("\n== 4. Parallel speedup, tiles at spacing %.4f (best of %d) ==\n", h, reps);
  std::printf("%-17s %10s %10s %8s %9s\n", "field", "1 thr ms", "2 thr ms", "speedup", "CPU/wall");
  for (const Named& f : fields()) {
    MarchingTilesOptions o;
    o.bounds = f.bounds;
    o.spacing = h;
    o.threads = 1;
    const double one = time_ms(reps, [&] { marching_tiles(*f.field, o); });
    o.threads = 2;
    double two = HUGE_VAL, utilization = 0.0;
    for (int i = 0; i < reps; ++i) {
      const double w0 = now_ms(), c0 = cpu_ms();
      marching_tiles(*f.field, o);
      const double wall = now_ms() - w0;
      if (wall < two) {
        two = wall;
        utilization = (cpu_ms() - c0) / wall;
      }
    }
    std::printf("%-17s %10.1f %10.1f %8.2f %9.2f\n", f.name, one, two, one / two, utilization);
  }
}

// Child side of peak_growth_mb: prints the growth in MB.
int memory_run(const char* method, int field, double h) {
  const Named f = fields()[static_cast<std::size_t>(field)];
  MarchingTilesOptions to;
  to.bounds = f.bounds;
  to.spacing = h;
  to.threads = 2;
  MarchingCubesOptions co;
  co.bounds = f.bounds;
  for (int a = 0; a < 3; ++a) co.cells[a] = static_cast<int>(std::lround(f.bounds.size()[a] / h));
  co.threads = 2;
  co.sparse = std::strcmp(method, "cubes-sp") == 0;
  const double before = peak_rss_mb();
  const std::size_t triangles = std::strcmp(method, "tiles") == 0 ? marching_tiles(*f.field, to).triangles.size()
                                                                  : marching_cubes(*f.field, co).triangles.size();
  std::printf("%.3f %zu\n", peak_rss_mb() - before, triangles);
  return 0;
}

void section_scaling(int field, double h0, int levels, int reps) {
  const Named f = fields()[static_cast<std::size_t>(field)];
  std::printf("\n== 5. Sparse scaling on '%s': spacing halved per row, 2 threads ==\n", f.name);
  std::printf("%-8s %-8s %8s %8s %10s %9s %8s %8s | %6s %6s %6s %6s %6s\n", "method", "spacing", "wall ms", "cpu ms",
              "evals", "triangles", "peak MB", "mesh MB", "x wall", "x cpu", "x evals", "x tris", "x mem");
  for (const char* method : {"tiles", "cubes-sp", "cubes"}) {
    RunResult prev;
    double prev_mb = 0;
    for (int level = 0; level < levels; ++level) {
      const double h = h0 / static_cast<double>(1 << level);
      const bool tiles = std::strcmp(method, "tiles") == 0;
      const RunResult r =
          tiles ? run_tiles(f, h, 2, reps) : run_cubes(f, h, std::strcmp(method, "cubes-sp") == 0, 2, reps);
      const double mb = peak_growth_mb(method, field, h);
      const double mesh_mb =
          (static_cast<double>(r.triangles) * 12.0 + static_cast<double>(r.triangles) / 2 * 24.0) / 1e6;
      std::printf("%-8s %-8.4f %8.1f %8.1f %10lld %9zu %8.1f %8.1f", method, h, r.ms, r.cpu,
                  static_cast<long long>(r.evals), r.triangles, mb, mesh_mb);
      if (level > 0) {
        std::printf(" | %6.2f %6.2f %7.2f %6.2f %6.2f", r.ms / prev.ms, r.cpu / prev.cpu,
                    static_cast<double>(r.evals) / static_cast<double>(prev.evals),
                    static_cast<double>(r.triangles) / static_cast<double>(prev.triangles), mb / prev_mb);
      }
      std::printf("\n");
      prev = r;
      prev_mb = mb;
    }
  }
}

}  // namespace
}  // namespace surfacer

int main(int argc, char** argv) {
  using namespace surfacer;
  if (argc == 5 && std::strcmp(argv[1], "--memory-run") == 0) {
    return memory_run(argv[2], std::atoi(argv[3]), std::atof(argv[4]));
  }
  const bool quick = argc > 1 && std::strcmp(argv[1], "--quick") == 0;
  std::printf("Marching Tiles bench (%s); hardware threads: %u\n", quick ? "quick" : "full",
              std::thread::hardware_concurrency());
  section_compare(quick ? 0.02 : 0.008, quick ? 1 : 3);
  section_dense_throughput(quick ? 128 : 256, quick ? 1 : 5);
  section_threads(quick ? 0.01 : 0.005, quick ? 2 : 5);
  section_scaling(0, 0.02, quick ? 2 : 3, quick ? 1 : 3);
  return 0;
}
