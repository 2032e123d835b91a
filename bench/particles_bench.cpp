// Particle surfacing benchmark, with OpenVDB side by side on the same particles in the same run. Data sets are
// generated in-process. Every run (ours, and OpenVDB at each voxel size) happens in its own forked child that also
// generates the particles, so its peak RSS (ru_maxrss) is its own and not the largest of everything before it.
//
//   particles_bench [--sets a,b] [--repeat N] [--threads T] [--write DIR] [--no-openvdb]
//
//   --sets       default block500k,sheet,droplets,flatness; also block, block_fine, spray
//   --repeat     repetitions of every timed run (default 3): wall = the fastest, cpu = the least user + sys time
//   --threads    our threads and OpenVDB's TBB threads, the same count (default 0: hardware threads)
//   --write DIR  our meshes as DIR/<set>.ply
//   --no-openvdb our side only
//
// Ours, per data set: surface_particles end to end (wall and cpu) and particles/s; the Draco encode of the result
// (default DracoOptions, quantization box = the mesh's bounds) and surfacing + encode, since users receive frames
// Draco-encoded; per stage seconds and a normalized cost: ns per particle for distance_field, ns per vertex for
// polygonize, build_b and cleanup, ns per vertex per sweep for laplacian, bilaplacian and polish (vertices: the
// Marching Tiles mesh these stages work on). Peak RSS is printed for the surfacing alone and with the encode.
//
// OpenVDB (bench/openvdb_reference.h): spheres of r_outer, the radius of our initial surface, through
// ParticlesToLevelSet and volumeToMesh (isovalue 0, adaptivity 0), no smoothing, at two voxel sizes:
//  (a) equal triangles: first voxel h = our Marching Tiles spacing, then voxel * sqrt(T_openvdb / T_ours) (triangle
//      count ~ area / voxel^2), corrected once more when still more than 5% off. Also printed with 4 Gaussian
//      LevelSetFilter passes (width 1) at that voxel.
//  (b) equal sample density: the A15 lattice has kPointCount = 8 sites per cell of kCellEdge = 4 lattice units, and a
//      lattice unit is h / kMeanEdge (kMeanEdge = 2.3047; core/polygonize/a15_table.h). A cell is therefore
//      4 h / 2.3047 = 1.736 h wide and holds 8 / (1.736 h)^3 = 1.53 / h^3 samples; a cubic grid of voxel v holds
//      1 / v^3, the same at v = h * 4 / (2.3047 * cbrt(8)) = 0.868 h.
// The ratios are ours / OpenVDB, end to end surfacing without the encode (< 1: we are faster).
//
// Data sets:
//   block500k   100 x 50 x 100 particles (x, y, z) on a cubic lattice of spacing d = 0.01, each coordinate jittered
//               uniformly by +-0.1 d; r_inner = 0.6 d. Target: <= 2.0 s end to end on a 2-core machine, peak RSS
//               <= 600 MB (printed beside the results).
//   block       80^3 = 512,000 particles on a cubic lattice of spacing 1, each jittered uniformly by +-0.25 per axis;
//               r_inner derived (mean nearest-neighbour distance, ~0.78), r_outer = 2 r_inner.
//   block_fine  the same particles with r_inner = 0.5 (SPH "radius = half the spacing"): ~4x the triangles.
//   sheet       a wavy sheet two particles thick, 250 x 250 x 2 = 125,000 particles, r_inner = 1.
//   droplets    1,000 droplets of 8..64 particles (~36,000) scattered in a 400^3 box, r_inner = 0.8.
//   spray       a 40^3 block plus 100,000 single particles scattered over a 1000^3 box (~164,000), r_inner = 0.6,
//               min_particles_per_component = 5: we drop the spray before surfacing, OpenVDB meshes every particle.
//   flatness    square-lattice slabs of 60 x 60 particles and 6 layers in z at spacing d = 0.01 (no jitter),
//               r_inner / d in {0.45, 0.6, 0.7, 1.0}, r_outer = 2 r_inner. The top face: vertices above the top
//               layer and at least 5 d inside the slab's sides; its RMS height deviation about the mean and its
//               peak-to-peak, in % of r_inner (target: RMS < 0.5 %). Ours only: OpenVDB's spheres are not smoothed.
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <charconv>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <functional>
#include <limits>
#include <optional>
#include <random>
#include <sstream>
#include <string>
#include <thread>
#include <type_traits>
#include <vector>

#include "bench/openvdb_reference.h"
#include "core/mesh/mesh_checks.h"
#include "core/mesh/mesh_codec.h"
#include "core/mesh/mesh_io.h"
#include "core/particles/particle_surfacer.h"
#include "core/polygonize/a15_table.h"
#include "core/util/parallel.h"

namespace surfacer {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr double kFlatnessTargetPercent = 0.5;
constexpr int kGaussianPasses = 4;
// Cubic voxel with the sample density of the A15 lattice of mean spacing h, over h (derivation at the top).
const double kEqualDensityVoxel = a15::kCellEdge / (a15::kMeanEdge * std::cbrt(double{a15::kPointCount}));

// ---- Data sets ----------------------------------------------------------------------------------------------------

// The top face of a flatness slab: vertices with z > z_top and lo <= x, y <= hi.
struct FlatTop {
  double z_top = 0.0, lo = 0.0, hi = 0.0;
};

struct DataSet {
  std::vector<Vec3> particles;
  ParticleSurfacingOptions options;
  std::optional<FlatTop> top;  // flatness slabs only
};

// One surfacing run of the bench. `make` runs in the child, so the particles never live in the parent.
struct Case {
  std::string label;  // the --sets name; flatness cases add their r_inner / d
  std::string note;
  std::function<DataSet()> make;
  std::optional<double> target_seconds, target_mb;
};

// n[0] x n[1] x n[2] particles on a cubic lattice of spacing d from the origin, x fastest, each coordinate jittered
// uniformly by +-jitter.
std::vector<Vec3> lattice(std::array<int, 3> n, double d, double jitter, std::uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-jitter, jitter);
  std::vector<Vec3> p;
  p.reserve(static_cast<std::size_t>(n[0]) * n[1] * n[2]);
  for (int k = 0; k < n[2]; ++k) {
    for (int j = 0; j < n[1]; ++j) {
      for (int i = 0; i < n[0]; ++i) {
        // One statement each: the generator's call order must not depend on argument evaluation order.
        const double x = i * d + u(rng);
        const double y = j * d + u(rng);
        const double z = k * d + u(rng);
        p.emplace_back(x, y, z);
      }
    }
  }
  return p;
}

DataSet sheet() {
  DataSet s;
  std::mt19937 rng(2);
  std::uniform_real_distribution<double> u(-0.1, 0.1);
  for (int layer = 0; layer < 2; ++layer) {
    for (int j = 0; j < 250; ++j) {
      for (int i = 0; i < 250; ++i) {
        const double z = layer + 6.0 * std::sin(i / 40.0) * std::cos(j / 55.0);
        s.particles.emplace_back(i + u(rng), j + u(rng), z + u(rng));
      }
    }
  }
  s.options.r_inner = 1.0;
  return s;
}

DataSet droplets() {
  DataSet s;
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> box(0.0, 400.0), u(-1.0, 1.0);
  std::uniform_int_distribution<int> size(8, 64);
  for (int d = 0; d < 1000; ++d) {
    const Vec3 c(box(rng), box(rng), box(rng));
    const int count = size(rng);
    const double radius = 0.62 * std::cbrt(static_cast<double>(count));
    for (int p = 0; p < count;) {
      const Vec3 q(u(rng), u(rng), u(rng));
      if (q.norm() > 1.0) continue;
      s.particles.push_back(c + radius * q);
      ++p;
    }
  }
  s.options.r_inner = 0.8;
  return s;
}

DataSet spray() {
  DataSet s;
  s.particles = lattice({40, 40, 40}, 1.0, 0.2, 4);
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> box(-500.0, 500.0);
  for (int p = 0; p < 100000; ++p) s.particles.emplace_back(box(rng), box(rng), box(rng));
  s.options.r_inner = 0.6;
  s.options.min_particles_per_component = 5;
  return s;
}

// The case of a --sets name other than flatness; nullopt for an unknown name.
std::optional<Case> case_of(const std::string& name) {
  if (name == "block500k") {
    return Case{name, "100 x 50 x 100 lattice, d 0.01, jitter +-0.1 d, r_inner 0.6 d",
                [] {
                  DataSet s;
                  s.particles = lattice({100, 50, 100}, 0.01, 0.001, 7);
                  s.options.r_inner = 0.006;
                  return s;
                },
                2.0, 600.0};
  }
  if (name == "block" || name == "block_fine") {
    const bool fine = name == "block_fine";
    return Case{name,
                fine ? "80^3 lattice, jitter +-0.25, r_inner 0.5" : "80^3 lattice, jitter +-0.25, r_inner derived",
                [fine] {
                  DataSet s;
                  s.particles = lattice({80, 80, 80}, 1.0, 0.25, 1);
                  if (fine) {
                    s.options.r_inner = 0.5;
                  } else {
                    s.options.derive_r_inner = true;
                  }
                  return s;
                },
                std::nullopt, std::nullopt};
  }
  if (name == "sheet") return Case{name, "250 x 250 x 2 wavy sheet, r_inner 1", sheet, std::nullopt, std::nullopt};
  if (name == "droplets") {
    return Case{name, "1000 droplets of 8..64 particles in a 400^3 box, r_inner 0.8", droplets, std::nullopt,
                std::nullopt};
  }
  if (name == "spray") {
    return Case{name, "40^3 block + 100k single particles over 1000^3, r_inner 0.6, min 5 per component", spray,
                std::nullopt, std::nullopt};
  }
  return std::nullopt;
}

constexpr std::array<double, 4> kFlatnessRatios = {0.45, 0.6, 0.7, 1.0};  // r_inner / d

Case flatness_case(double ratio) {
  char label[32];
  std::snprintf(label, sizeof label, "flatness_%.2g", ratio);
  return Case{label, "",
              [ratio] {
                constexpr double d = 0.01;
                constexpr int n = 60, layers = 6;
                constexpr double inset = 5 * d;
                DataSet s;
                s.particles = lattice({n, n, layers}, d, 0.0, 8);
                s.options.r_inner = ratio * d;
                s.options.r_outer = 2.0 * ratio * d;
                s.top = FlatTop{(layers - 1) * d, inset, (n - 1) * d - inset};
                return s;
              },
              std::nullopt, std::nullopt};
}

// ---- Runs in a child process ----------------------------------------------------------------------------------------

double cpu_seconds() {
  rusage ru{};
  getrusage(RUSAGE_SELF, &ru);
  return static_cast<double>(ru.ru_utime.tv_sec + ru.ru_stime.tv_sec) +
         1e-6 * static_cast<double>(ru.ru_utime.tv_usec + ru.ru_stime.tv_usec);
}

double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

// A child hands its result back as the bytes of a trivially copyable struct (same binary, same layout), followed by
// the wall time of every repetition.
template <class T>
std::string to_bytes(const T& value, const std::vector<double>& walls) {
  static_assert(std::is_trivially_copyable_v<T>);
  std::string out(reinterpret_cast<const char*>(&value), sizeof value);
  out.append(reinterpret_cast<const char*>(walls.data()), walls.size() * sizeof(double));
  return out;
}

template <class T>
std::optional<T> from_bytes(const std::string& bytes, std::vector<double>& walls) {
  if (bytes.size() < sizeof(T) || (bytes.size() - sizeof(T)) % sizeof(double) != 0) return std::nullopt;
  T value;
  std::memcpy(&value, bytes.data(), sizeof value);
  walls.resize((bytes.size() - sizeof(T)) / sizeof(double));
  std::memcpy(walls.data(), bytes.data() + sizeof(T), walls.size() * sizeof(double));
  return value;
}

struct ChildOutput {
  std::string bytes;
  double peak_mb = 0.0;
};

// Runs `work` in a forked child; its bytes and the child's peak RSS, or nullopt when it failed (it says why on
// stderr). The parent starts no threads, so forking is safe.
std::optional<ChildOutput> in_child(const std::function<std::string()>& work) {
  int fd[2];
  if (pipe(fd) != 0) return std::nullopt;
  std::fflush(nullptr);
  const pid_t pid = fork();
  if (pid < 0) {
    close(fd[0]);
    close(fd[1]);
    return std::nullopt;
  }
  if (pid == 0) {
    close(fd[0]);
    int code = 0;
    try {
      const std::string bytes = work();
      for (std::size_t done = 0; done < bytes.size();) {
        const ssize_t n = write(fd[1], bytes.data() + done, bytes.size() - done);
        if (n <= 0) std::_Exit(3);
        done += static_cast<std::size_t>(n);
      }
    } catch (const std::exception& e) {
      std::fprintf(stderr, "  child failed: %s\n", e.what());
      code = 1;
    }
    std::_Exit(code);
  }
  close(fd[1]);
  ChildOutput out;
  char buf[1 << 16];
  for (ssize_t n; (n = read(fd[0], buf, sizeof buf)) > 0;) out.bytes.append(buf, static_cast<std::size_t>(n));
  close(fd[0]);
  int status = 0;
  rusage ru{};
  if (wait4(pid, &status, 0, &ru) != pid || !WIFEXITED(status) || WEXITSTATUS(status) != 0) return std::nullopt;
  out.peak_mb = static_cast<double>(ru.ru_maxrss) / 1024.0;
  return out;
}

// RMS about the mean and peak-to-peak of z over the top-face vertices (scene units).
struct Flatness {
  std::size_t vertices = 0;
  double rms = 0.0, peak_to_peak = 0.0;
};

Flatness flatness(const Mesh& mesh, const FlatTop& top) {
  std::vector<double> z;
  for (const Vec3& v : mesh.vertices) {
    if (v.z() > top.z_top && v.x() >= top.lo && v.x() <= top.hi && v.y() >= top.lo && v.y() <= top.hi) {
      z.push_back(v.z());
    }
  }
  Flatness f;
  f.vertices = z.size();
  if (z.empty()) return f;
  double mean = 0.0;
  for (const double h : z) mean += h;
  mean /= static_cast<double>(z.size());
  double sum2 = 0.0;
  for (const double h : z) sum2 += (h - mean) * (h - mean);
  f.rms = std::sqrt(sum2 / static_cast<double>(z.size()));
  const auto [lo, hi] = std::minmax_element(z.begin(), z.end());
  f.peak_to_peak = *hi - *lo;
  return f;
}

struct OursResult {
  std::size_t particles = 0;
  ParticleSurfacingStats stats;  // of the fastest repetition
  double wall = kInf, cpu = kInf, encode = kInf;
  std::size_t draco_bytes = 0;
  double surfacing_peak_mb = 0.0;  // before the encode
  bool closed = false, manifold = false;
  int components = 0;
  int laplacian_sweeps = 0, bilaplacian_sweeps = 0, polish_sweeps = 0;  // the options the set ran with
  Flatness top;                                                         // flatness slabs only
};

std::string run_ours(const Case& c, int repeat, int threads, const std::string& write_dir) {
  DataSet set = c.make();
  set.options.threads = threads;
  OursResult r;
  r.particles = set.particles.size();
  r.laplacian_sweeps = set.options.laplacian_sweeps;
  r.bilaplacian_sweeps = set.options.bilaplacian_sweeps;
  r.polish_sweeps = set.options.polish_sweeps;
  std::vector<double> walls;
  Mesh mesh;
  for (int k = 0; k < repeat; ++k) {
    mesh = {};  // the previous mesh must not add to this run's peak
    ParticleSurfacingStats stats;
    const double c0 = cpu_seconds();
    const auto t0 = std::chrono::steady_clock::now();
    mesh = surface_particles(set.particles, {}, set.options, {}, &stats);
    walls.push_back(seconds_since(t0));
    r.cpu = std::min(r.cpu, cpu_seconds() - c0);
    if (walls.back() < r.wall) {
      r.wall = walls.back();
      r.stats = stats;
    }
  }
  rusage ru{};
  getrusage(RUSAGE_SELF, &ru);
  r.surfacing_peak_mb = static_cast<double>(ru.ru_maxrss) / 1024.0;
  DracoOptions draco;
  draco.quantization_bounds = Aabb::of(mesh.vertices);
  for (int k = 0; k < repeat; ++k) {
    const auto t0 = std::chrono::steady_clock::now();
    r.draco_bytes = encode_draco(mesh, draco).size();
    r.encode = std::min(r.encode, seconds_since(t0));
  }
  const MeshReport report = check_mesh(mesh);
  r.closed = report.closed;
  r.manifold = report.edge_manifold && report.vertex_manifold;
  r.components = report.components;
  if (set.top) r.top = flatness(mesh, *set.top);
  if (!write_dir.empty()) write_mesh(write_dir + "/" + c.label + ".ply", mesh);
  return to_bytes(r, walls);
}

struct VdbResult {
  bench::OpenVdbMesh mesh;  // of the fastest repetition
  double wall = kInf, cpu = kInf;
};

std::string run_openvdb(const Case& c, double radius, double voxel, int gaussian_passes, int repeat, int threads) {
  const DataSet set = c.make();
  VdbResult r;
  std::vector<double> walls;
  for (int k = 0; k < repeat; ++k) {
    const double c0 = cpu_seconds();
    const auto t0 = std::chrono::steady_clock::now();
    const bench::OpenVdbMesh mesh = bench::openvdb_surface(set.particles, radius, voxel, gaussian_passes, threads);
    walls.push_back(seconds_since(t0));
    r.cpu = std::min(r.cpu, cpu_seconds() - c0);
    if (walls.back() < r.wall) {
      r.wall = walls.back();
      r.mesh = mesh;
    }
  }
  return to_bytes(r, walls);
}

// ---- The parent: runs and prints ------------------------------------------------------------------------------------

struct Config {
  int repeat = 3;
  int threads = 0;  // as given; resolve_threads(threads) for both sides
  std::string write_dir;
  bool openvdb = true;
};

template <class T>
struct Measured {
  T result;
  std::vector<double> walls;
  double peak_mb = 0.0;
};

template <class T>
std::optional<Measured<T>> measure(const std::function<std::string()>& work) {
  const std::optional<ChildOutput> out = in_child(work);
  if (!out) return std::nullopt;
  Measured<T> m;
  const std::optional<T> value = from_bytes<T>(out->bytes, m.walls);
  if (!value) return std::nullopt;
  m.result = *value;
  m.peak_mb = out->peak_mb;
  return m;
}

double ns_per(double seconds, double count) { return count > 0 ? 1e9 * seconds / count : 0.0; }

std::string wall_list(const std::vector<double>& walls) {
  std::string s;
  char buf[32];
  for (std::size_t k = 0; k < walls.size(); ++k) {
    std::snprintf(buf, sizeof buf, "%s%.3f", k ? ", " : "", walls[k]);
    s += buf;
  }
  return s;
}

void print_ours(const Case& c, const Measured<OursResult>& m) {
  const OursResult& r = m.result;
  const ParticleSurfacingStats& s = r.stats;
  std::printf("%s  %s\n", c.label.c_str(), c.note.c_str());
  std::printf("  particles %zu (used %zu, %zu clusters dropped)  r_inner %.4g r_outer %.4g spacing %.4g\n", r.particles,
              s.particles_used, s.components_dropped, s.r_inner, s.r_outer, s.spacing);
  std::printf(
      "  mesh: %zu vertices, %zu triangles, %d components, closed %s, manifold %s (Marching Tiles: %zu vertices, "
      "min valence %d)\n",
      s.vertices, s.triangles, r.components, r.closed ? "yes" : "NO", r.manifold ? "yes" : "NO", s.initial_vertices,
      s.initial_min_valence);
  std::printf("  end to end: wall %.3f s (best of %s), cpu %.3f s -> %.0f particles/s", r.wall,
              wall_list(m.walls).c_str(), r.cpu, static_cast<double>(r.particles) / r.wall);
  if (c.target_seconds) std::printf("  [target <= %.1f s on 2 cores]", *c.target_seconds);
  std::printf("\n  Draco encode %.3f s (%.2f MB, default options, box = mesh bounds); surfacing + encode %.3f s\n",
              r.encode, static_cast<double>(r.draco_bytes) / 1e6, r.wall + r.encode);
  std::printf("  peak RSS %.0f MB surfacing, %.0f MB with the encode", r.surfacing_peak_mb, m.peak_mb);
  if (c.target_mb) std::printf("  [target <= %.0f MB]", *c.target_mb);
  std::printf("\n");

  // Every stage after distance_field works on the Marching Tiles mesh.
  const auto vertices = static_cast<double>(s.initial_vertices);
  const auto particles = static_cast<double>(r.particles);
  struct Row {
    const char* stage;
    double seconds, count;
    std::string per;
  };
  const auto sweeps = [](int n) { return "vertex x sweep (" + std::to_string(n) + " sweeps)"; };
  const Row rows[] = {
      {"distance_field", s.seconds_distance_field, particles, "particle"},
      {"polygonize", s.seconds_polygonize, vertices, "vertex"},
      {"laplacian", s.seconds_laplacian, vertices * r.laplacian_sweeps, sweeps(r.laplacian_sweeps)},
      {"build_b", s.seconds_build_b, vertices, "vertex"},
      {"bilaplacian", s.seconds_bilaplacian, vertices * r.bilaplacian_sweeps, sweeps(r.bilaplacian_sweeps)},
      {"polish", s.seconds_polish, vertices * r.polish_sweeps, sweeps(r.polish_sweeps)},
      {"cleanup", s.seconds_cleanup, vertices, "vertex"},
      {"total", s.seconds_total, particles, "particle"},
  };
  std::printf("  %-16s %9s %10s  per\n", "stage (fastest)", "seconds", "ns");
  for (const Row& row : rows) {
    std::printf("  %-16s %9.3f %10.1f  %s\n", row.stage, row.seconds, ns_per(row.seconds, row.count), row.per.c_str());
  }
  std::printf(
      "  faithful %.4f%% after the constrained sweeps, %.4f%% at the end (max violation %.3g); slivers: %lld found, "
      "%lld flips, %lld collapses, %lld left\n",
      100.0 * s.faithful_after_constrained, 100.0 * s.faithful_after_polish, s.max_violation_after_polish,
      static_cast<long long>(s.slivers_found), static_cast<long long>(s.sliver_flips),
      static_cast<long long>(s.sliver_collapses), static_cast<long long>(s.slivers_left));
}

// One OpenVDB run at `voxel`, in a child; prints why when it fails.
std::optional<Measured<VdbResult>> openvdb_run(const Case& c, const Config& cfg, double radius, double voxel,
                                               int gaussian_passes) {
  auto m = measure<VdbResult>(
      [&] { return run_openvdb(c, radius, voxel, gaussian_passes, cfg.repeat, resolve_threads(cfg.threads)); });
  if (!m) std::printf("    OpenVDB at voxel %.4g FAILED\n", voxel);
  return m;
}

void print_openvdb_row(const char* label, double voxel, double spacing, const Measured<VdbResult>& m,
                       const OursResult& ours) {
  const VdbResult& r = m.result;
  std::printf("    %-24s %8.4g %6.3f %7.3f %7.3f %7.3f %7.3f %7.3f %10zu %9zu %6.0f %6.2f %5.2f\n", label, voxel,
              voxel / spacing, r.wall, r.cpu, r.mesh.seconds_rasterize, r.mesh.seconds_filter, r.mesh.seconds_mesh,
              r.mesh.triangles, r.mesh.vertices, m.peak_mb, ours.wall / r.wall, ours.cpu / r.cpu);
  if (r.mesh.particles_too_small > 0) {
    std::printf("      (%zu particles skipped by ParticlesToLevelSet: radius below 1.5 voxels)\n",
                r.mesh.particles_too_small);
  }
}

void compare_openvdb(const Case& c, const Config& cfg, const OursResult& ours) {
  const ParticleSurfacingStats& s = ours.stats;
  if (s.triangles == 0) {
    std::printf("  OpenVDB: skipped (our mesh is empty)\n");
    return;
  }
  std::printf(
      "  OpenVDB %s: spheres of r_outer %.4g -> ParticlesToLevelSet -> volumeToMesh (isovalue 0, adaptivity 0), "
      "%d TBB threads\n",
      bench::openvdb_version()->c_str(), s.r_outer, resolve_threads(cfg.threads));

  // (a) Triangle count ~ area / voxel^2: rescale by the square root of the count ratio until within 5%.
  double voxel = s.spacing;
  std::optional<Measured<VdbResult>> equal;
  std::string trail;
  for (int step = 0; step < 3; ++step) {
    equal = openvdb_run(c, cfg, s.r_outer, voxel, 0);
    if (!equal) return;
    const double ratio = static_cast<double>(equal->result.mesh.triangles) / static_cast<double>(s.triangles);
    char buf[96];
    std::snprintf(buf, sizeof buf, "%svoxel %.4g -> %zu (%+.1f%%)", step ? ", " : "", voxel,
                  equal->result.mesh.triangles, 100.0 * (ratio - 1.0));
    trail += buf;
    if (std::abs(ratio - 1.0) <= 0.05 || ratio == 0.0 || step == 2) break;
    voxel *= std::sqrt(ratio);
  }
  std::printf("    equal triangles (ours %zu): %s\n", s.triangles, trail.c_str());
  const double equal_voxel = voxel;
  const auto smoothed = openvdb_run(c, cfg, s.r_outer, equal_voxel, kGaussianPasses);
  const double density_voxel = kEqualDensityVoxel * s.spacing;
  const auto dense = openvdb_run(c, cfg, s.r_outer, density_voxel, 0);

  std::printf("    %-24s %8s %6s %7s %7s %7s %7s %7s %10s %9s %6s %12s\n", "", "voxel", "/h", "wall s", "cpu s",
              "raster", "filter", "mesh", "triangles", "vertices", "MB", "ours/theirs");
  std::printf("    %-24s %8.4g %6.3f %7.3f %7.3f %7s %7s %7s %10zu %9zu %6.0f %6s %5s\n", "ours", s.spacing, 1.0,
              ours.wall, ours.cpu, "", "", "", s.triangles, s.vertices, ours.surfacing_peak_mb, "wall", "cpu");
  print_openvdb_row("(a) equal triangles", equal_voxel, s.spacing, *equal, ours);
  if (smoothed) print_openvdb_row("(a) + 4 Gaussian passes", equal_voxel, s.spacing, *smoothed, ours);
  if (dense) print_openvdb_row("(b) equal sample density", density_voxel, s.spacing, *dense, ours);
}

bool bench_set(const Case& c, const Config& cfg) {
  const auto ours = measure<OursResult>([&] { return run_ours(c, cfg.repeat, cfg.threads, cfg.write_dir); });
  if (!ours) {
    std::printf("%s FAILED\n\n", c.label.c_str());
    return false;
  }
  print_ours(c, *ours);
  if (!cfg.openvdb) {
    std::printf("  OpenVDB: off (--no-openvdb)\n");
  } else if (!bench::openvdb_version()) {
    std::printf("  %s\n", bench::kOpenVdbMissing);
  } else {
    compare_openvdb(c, cfg, ours->result);
  }
  std::printf("\n");
  std::fflush(stdout);
  return true;
}

bool bench_flatness(const Config& cfg) {
  std::printf(
      "flatness  60 x 60 x 6 square-lattice slabs, d 0.01, no jitter, r_outer = 2 r_inner; top face: vertices above "
      "the top layer, 5 d inside the sides (ours only)\n");
  std::printf("  %9s %9s %10s %8s %7s %9s %8s %8s %11s %8s\n", "r_inner/d", "vertices", "triangles", "wall s", "mesh",
              "top verts", "RMS %", "p-p %", "target RMS", "faithful");
  bool ok = true;
  for (const double ratio : kFlatnessRatios) {
    const Case c = flatness_case(ratio);
    const auto m = measure<OursResult>([&] { return run_ours(c, cfg.repeat, cfg.threads, cfg.write_dir); });
    if (!m) {
      std::printf("  %9.2f FAILED\n", ratio);
      ok = false;
      continue;
    }
    const OursResult& r = m->result;
    const double r_inner = r.stats.r_inner;
    const double rms = 100.0 * r.top.rms / r_inner;
    std::printf("  %9.2f %9zu %10zu %8.3f %7s %9zu %8.3f %8.3f %5s %.1f%% %7.3f%%\n", ratio, r.stats.vertices,
                r.stats.triangles, r.wall, r.closed && r.manifold ? "ok" : "BROKEN", r.top.vertices, rms,
                100.0 * r.top.peak_to_peak / r_inner, rms < kFlatnessTargetPercent ? "met <" : "NOT <",
                kFlatnessTargetPercent, 100.0 * r.stats.faithful_after_polish);
    std::fflush(stdout);
  }
  std::printf("\n");
  return ok;
}

constexpr const char* kUsage =
    "usage: particles_bench [--sets a,b] [--repeat N] [--threads T] [--write DIR] [--no-openvdb]\n"
    "  sets: block500k, sheet, droplets, flatness (default), block, block_fine, spray\n";

[[noreturn]] void usage_error(const std::string& message) {
  std::fprintf(stderr, "particles_bench: %s\n%s", message.c_str(), kUsage);
  std::exit(2);
}

int parse_int(const std::string& flag, const std::string& text, int min) {
  int v = 0;
  const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), v);
  if (ec != std::errc() || end != text.data() + text.size() || v < min) {
    usage_error(flag + " needs an integer >= " + std::to_string(min) + ", got '" + text + "'");
  }
  return v;
}

}  // namespace
}  // namespace surfacer

int main(int argc, char** argv) {
  using namespace surfacer;
  std::vector<std::string> sets = {"block500k", "sheet", "droplets", "flatness"};
  Config cfg;
  for (int a = 1; a < argc; ++a) {
    const std::string arg = argv[a];
    auto value = [&]() -> std::string {
      if (a + 1 >= argc) usage_error(arg + " needs a value");
      return argv[++a];
    };
    if (arg == "--sets") {
      sets.clear();
      std::stringstream ss(value());
      for (std::string item; std::getline(ss, item, ',');) {
        if (item != "flatness" && !case_of(item)) usage_error("unknown data set '" + item + "'");
        sets.push_back(item);
      }
    } else if (arg == "--repeat") {
      cfg.repeat = parse_int(arg, value(), 1);
    } else if (arg == "--threads") {
      cfg.threads = parse_int(arg, value(), 0);
    } else if (arg == "--write") {
      cfg.write_dir = value();
    } else if (arg == "--no-openvdb") {
      cfg.openvdb = false;
    } else {
      usage_error("unknown argument '" + arg + "'");
    }
  }
  double load[3] = {0, 0, 0};
  if (getloadavg(load, 3) < 0) load[0] = -1;
  std::printf(
      "particles_bench: %u hardware threads, %d threads for ours and for OpenVDB, load average %.2f, %d "
      "repetitions per run\n",
      std::thread::hardware_concurrency(), resolve_threads(cfg.threads), load[0], cfg.repeat);
  if (!cfg.openvdb) {
    std::printf("OpenVDB comparison off (--no-openvdb)\n");
  } else if (const auto version = bench::openvdb_version()) {
    std::printf("OpenVDB %s\n", version->c_str());
  } else {
    std::printf("%s\n", bench::kOpenVdbMissing);
  }
  std::printf("(wall = fastest repetition, cpu = least user + sys; every run in its own child process)\n\n");
  std::fflush(stdout);
  bool ok = true;
  for (const std::string& name : sets)
    ok = (name == "flatness" ? bench_flatness(cfg) : bench_set(*case_of(name), cfg)) && ok;
  return ok ? 0 : 1;
}
