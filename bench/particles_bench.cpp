// Particle surfacing benchmark (docs/ALGORITHMS.md §1), with OpenVDB side by side on the same particles in the same
// run. The data sets are generated here, deterministically. Every timed run (ours at each thread count, OpenVDB at
// each voxel size and thread count) happens in a forked child that generates its own particles, so the peak RSS the
// parent reads from wait4 is that run's alone.
//
//   particles_bench [--particles N] [--repeat R] [--vdb-repeat R]
//                   [--section block|flatness|scale|decimate|wide|radii]
//                   [--threads T] [--flatness-sweeps N] [--scale-sizes M,M,...] [--write DIR]
//
//   --particles N   block size (default 500000): the 100 x 50 x 100 block scaled by cbrt(N / 500000) per axis
//   --repeat R      repetitions of each of our timed runs (default 3); seconds are the minimum over them
//   --vdb-repeat R  the same for OpenVDB's runs (default 1: one takes 10-30 s on the 500 k block, 2 cores)
//   --section S     block, flatness, scale, decimate, wide or radii only (default block and flatness; the others run
//                   only when asked); decimate: the block (--particles) and droplets decimated at TOL =
//                   0.1 r_inner, with the largest thread count and with 1 (the two meshes must be identical)
//                   (docs/ALGORITHMS.md §5, CHOICE "Decimation"); wide: lattices with r_inner of 1-3 spacings
//                   (bench_wide); radii: droplets with per-particle radii, one of them 5-100x (bench_radii)
//   --scale-sizes L the scale section's block sizes in millions of particles (default 0.5,2,13.5,50)
//   --threads T     one thread count for both sides (default: 1, then 2)
//   --flatness-sweeps N  Bilaplacian sweeps of the flatness slabs (default: the option's default); many (e.g. 1000)
//                   show where the sweeps converge to
//   --write DIR     our meshes as DIR/<name>_t<threads>.ply
//
// --particles, --repeat and --vdb-repeat are the block's, --flatness-sweeps the flatness slabs'; with the other
// --section alone they would change nothing, so they are refused (exit 2, as any bad flag).
//
// scale: the block at each --scale-sizes (same lattice, jitter and radii, scaled per axis), once each at the largest
// thread count: seconds end to end (surfacing + encode to the .drc and to the .glb, as in block), CPU seconds, peak
// RSS, bytes per particle (peak RSS / particles), triangles, particles/s and particles/s per core (to the .glb, as the
// scale figures were measured with --format glb), with OpenVDB beside it at voxel = our mean
// edge (equal resolution, (b) of block) up to 13.5 M, and splashsurf's published figure as a constant line (their
// 13.35 M frame, coarse cubes and no smoothing, 2.47 s on 14 cores). A size whose peak, projected from the largest
// size run so far (bytes per particle x particles), would pass 90 % of the physical memory is not run: the line says
// so with the projection (a 50 M frame needs < 200 bytes per particle on 24 GB).
//
// Exits 1 when a run fails, or when one of our meshes is not a closed, oriented manifold or differs between thread
// counts; timings are never checked.
//
// block: 100 x 50 x 100 particles (x, y, z) on a cubic lattice of spacing d = 0.01 from the origin, every coordinate
// jittered uniformly by +-0.1 d (std::mt19937, seed 7), r_inner = 0.6 d, r_outer = 2 r_inner. Printed per thread
// count:
//  * per stage of ParticleSurfacingStats: seconds, and ns per vertex per sweep for the sweep stages (laplacian,
//    bilaplacian, polish), ns per vertex (of the Marching Tiles mesh) for polygonize, build_b and cleanup, ns per
//    particle for distance_field;
//  * end to end, as a particles job produces a frame: surfacing with output_grid set plus the encode at 14 bits on
//    the job's box (particle_sequence_box), in seconds (minimum of the repetitions of the sum), to --format drc
//    (one Draco mesh: Draco's encoder runs on one thread) and to the default .glb (Draco pieces on T threads, laid
//    out as a .glb; the target, 1.2 s at 2 threads, is this one); user + sys CPU seconds (surface + .drc) and
//    particles/s;
//    peak RSS of the child;
//  * OpenVDB (bench/openvdb_reference.h): spheres of r_outer (the radius of our initial surface), ParticlesToLevelSet
//    + volumeToMesh, no smoothing, its mesh Draco-encoded exactly as ours, at two voxel sizes:
//     (a) equal triangles: the voxel whose mesh has about our triangle count (equal_triangles_voxel: at most 3
//         meshings from voxel (b), stopping within 3 %; the count found is printed);
//     (b) equal resolution: voxel = the mean edge length of our final mesh, i.e. the same sampling distance along the
//         surface (their quads have sides of about one voxel, so their mesh has more triangles than ours);
//    with the ratios ours / theirs of the surfacing, end-to-end and CPU seconds (< 1: we are faster; on a loaded
//    machine the CPU ratio is the one to trust).
//    Their time is mostly ParticlesToLevelSet, which writes every voxel within r_outer + 3 voxels of every particle,
//    interior ones included (r_outer is about 5 voxels here).
// flatness: square-lattice slabs of 60 x 60 particles and 6 layers at d = 0.01, no jitter, r_inner / d in
// {0.45, 0.6, 0.7, 1.0}, each with r_outer = 2 d and with the default r_outer = 2 r_inner (eq. 3.5 holds for every
// pair; the second is the deeper-cusped case users get by default), at the largest thread count. Top face as in
// tests/core/particle_surfacer_test.cpp: vertices above the top layer and at least 5 d inside the slab's sides. Its
// RMS height deviation about the mean and peak to peak in % of r_inner (target: RMS < 0.5 %), the faithful fraction
// at the end, the smallest angle and the slivers left; one run each. Fixed size: --particles does not apply. Also the
// face's mean height above the top layer beside the highest plane the band allows, sqrt(r_outer^2 - d^2 / 2) (eq.
// 3.5), both in d: a mean above that plane means the face floats above the cusps of the r_outer spheres, held only
// where a vertex lies near one. Each slab also runs with vertex_only_band (the thesis' band, cusps not held: the
// path before the cusps were held) in the same run: its RMS and mean height, and the ratio of surfacing seconds.
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <functional>
#include <limits>
#include <optional>
#include <random>
#include <string>
#include <thread>
#include <type_traits>
#include <vector>

#include "bench/bench_args.h"
#include "bench/openvdb_reference.h"
#include "core/mesh/decimate.h"
#include "core/mesh/frame_codec.h"
#include "core/mesh/mesh_checks.h"
#include "core/mesh/mesh_codec.h"
#include "core/mesh/mesh_io.h"
#include "core/particles/particle_surfacer.h"

namespace surfacer {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr int kDracoBits = 14;
constexpr std::size_t kBlockParticles = 100 * 50 * 100;
constexpr double kBlockTargetSeconds = 1.2;  // end to end to a .glb at 2 threads, issue target
constexpr double kBlockTargetMb = 600.0;
constexpr double kFlatnessTargetPercent = 0.5;
constexpr double kEqualTrianglesTolerance = 0.03;

struct Config {
  std::size_t particles = kBlockParticles;
  int repeat = 3;
  int vdb_repeat = 1;  // an OpenVDB run of the 500 k block takes 10-30 s
  std::vector<int> threads = {1, 2};
  bool block = true, flatness = true, scale = false, decimate = false, wide = false, radii = false;
  std::vector<double> scale_millions = {0.5, 2.0, 13.5, 50.0};
  std::optional<int> flatness_sweeps;
  std::string write_dir;
};

// ---- Data sets ----------------------------------------------------------------------------------------------------

// The top face of a flatness slab: vertices with z > z_top and lo <= x, y <= hi.
struct FlatTop {
  double z_top = 0.0, lo = 0.0, hi = 0.0;
};

struct DataSet {
  std::string name;                              // for --write
  std::function<std::vector<Vec3>()> particles;  // called in the child
  ParticleSurfacingOptions options;
  std::optional<FlatTop> top;  // flatness slabs only
};

// n[0] x n[1] x n[2] particles on a cubic lattice of spacing d from the origin, x fastest, every coordinate jittered
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

constexpr double kBlockSpacing = 0.01;

// The block's particle counts per axis for about `particles` particles (100 x 50 x 100 at 500000).
std::array<int, 3> block_dims(std::size_t particles) {
  const double s = std::cbrt(static_cast<double>(particles) / static_cast<double>(kBlockParticles));
  const auto axis = [s](int n) { return std::max(2, static_cast<int>(std::lround(n * s))); };
  return {axis(100), axis(50), axis(100)};
}

DataSet block_set(std::size_t particles) {
  const std::array<int, 3> n = block_dims(particles);
  DataSet s;
  s.name = "block";
  s.particles = [n] { return lattice(n, kBlockSpacing, 0.1 * kBlockSpacing, 7); };
  s.options.r_inner = 0.6 * kBlockSpacing;
  return s;
}

constexpr std::array<double, 4> kFlatnessRatios = {0.45, 0.6, 0.7, 1.0};  // r_inner / d
constexpr double kFlatnessSpacing = 0.01;                                 // d

// r_outer = 2 d, or (default_outer) the default 2 r_inner.
DataSet flatness_set(double ratio, bool default_outer) {
  constexpr double d = kFlatnessSpacing;
  constexpr int n = 60, layers = 6;
  constexpr double inset = 5 * d;
  char name[40];
  std::snprintf(name, sizeof name, "flatness_%.2f_%s", ratio, default_outer ? "2ri" : "2d");
  DataSet s;
  s.name = name;
  s.particles = [] { return lattice({n, n, layers}, d, 0.0, 8); };
  s.options.r_inner = ratio * d;
  if (!default_outer) s.options.r_outer = 2.0 * d;
  s.top = FlatTop{(layers - 1) * d, inset, (n - 1) * d - inset};
  return s;
}

// The Draco box of a particles job over these particles (one frame, uniform radii).
Aabb job_box(const std::vector<Vec3>& particles, const ParticleSurfacingOptions& options) {
  return particle_sequence_box(Aabb::of(particles), 0.0, options.r_inner, options.r_outer, {}, std::nullopt);
}

// ---- Child processes ------------------------------------------------------------------------------------------------

double cpu_seconds() {
  rusage ru{};
  getrusage(RUSAGE_SELF, &ru);
  return static_cast<double>(ru.ru_utime.tv_sec + ru.ru_stime.tv_sec) +
         1e-6 * static_cast<double>(ru.ru_utime.tv_usec + ru.ru_stime.tv_usec);
}

double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

// Runs `work` in a forked child, which hands its result back as the bytes of a trivially copyable struct (same
// binary, same layout). The result and the child's peak RSS in MB, or nullopt when the child failed (it says why on
// stderr). The parent starts no threads, so forking is safe.
template <class T>
struct InChild {
  T value;
  double peak_mb = 0.0;
};

template <class T>
std::optional<InChild<T>> in_child(const std::function<T()>& work) {
  static_assert(std::is_trivially_copyable_v<T>);
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
    try {
      const T value = work();
      const char* bytes = reinterpret_cast<const char*>(&value);
      for (std::size_t done = 0; done < sizeof value;) {
        const ssize_t n = write(fd[1], bytes + done, sizeof value - done);
        if (n <= 0) std::_Exit(3);
        done += static_cast<std::size_t>(n);
      }
    } catch (const std::exception& e) {
      std::fprintf(stderr, "particles_bench: child failed: %s\n", e.what());
      std::_Exit(1);
    }
    std::_Exit(0);
  }
  close(fd[1]);
  std::string bytes;
  char buf[4096];
  for (ssize_t n; (n = read(fd[0], buf, sizeof buf)) > 0;) bytes.append(buf, static_cast<std::size_t>(n));
  close(fd[0]);
  int status = 0;
  rusage ru{};
  if (wait4(pid, &status, 0, &ru) != pid || !WIFEXITED(status) || WEXITSTATUS(status) != 0) return std::nullopt;
  if (bytes.size() != sizeof(T)) return std::nullopt;
  InChild<T> out;
  std::memcpy(&out.value, bytes.data(), sizeof(T));
  out.peak_mb = static_cast<double>(ru.ru_maxrss) / 1024.0;
  return out;
}

// What both sides report about a mesh.
struct MeshFacts {
  std::size_t vertices = 0, triangles = 0;
  int components = 0;
  bool closed_manifold = false, outward = false;
  double min_angle = 0.0, area = 0.0, mean_edge = 0.0;
  std::uint64_t hash = 0;  // of the vertex bytes and triangles: equal meshes for 1 and 2 threads
};

MeshFacts facts_of(const Mesh& mesh) {
  const MeshReport r = check_mesh(mesh);
  MeshFacts f;
  f.vertices = mesh.vertices.size();
  f.triangles = mesh.triangles.size();
  f.components = r.components;
  f.closed_manifold = r.closed && r.edge_manifold && r.vertex_manifold && r.oriented;
  f.outward = r.volume > 0.0;
  f.min_angle = r.min_angle_degrees;
  f.area = r.area;
  double sum = 0.0;
  for (const Triangle& t : mesh.triangles) {
    for (int k = 0; k < 3; ++k) sum += (mesh.vertices[t[k]] - mesh.vertices[t[(k + 1) % 3]]).norm();
  }
  f.mean_edge = mesh.triangles.empty() ? 0.0 : sum / (3.0 * static_cast<double>(mesh.triangles.size()));
  std::uint64_t h = 1469598103934665603ull;  // FNV-1a
  const auto mix = [&h](const void* data, std::size_t size) {
    for (std::size_t i = 0; i < size; ++i) h = (h ^ static_cast<const unsigned char*>(data)[i]) * 1099511628211ull;
  };
  mix(mesh.vertices.data(), mesh.vertices.size() * sizeof(Vec3));
  mix(mesh.triangles.data(), mesh.triangles.size() * sizeof(Triangle));
  f.hash = h;
  return f;
}

// Mean, RMS about the mean and peak to peak of z over the top-face vertices (scene units).
struct Flatness {
  std::size_t vertices = 0;
  double mean = 0.0, rms = 0.0, peak_to_peak = 0.0;
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
  f.mean = mean;
  f.rms = std::sqrt(sum2 / static_cast<double>(z.size()));
  const auto [lo, hi] = std::minmax_element(z.begin(), z.end());
  f.peak_to_peak = *hi - *lo;
  return f;
}

// Seconds of one side's run: the fastest repetition of surfacing + encode, and its parts. Two outputs are timed
// after each surfacing: `--format drc` (one standard Draco mesh, Draco's encoder on one thread: encode,
// end_to_end, cpu) and the default `.glb` (Draco pieces encoded on the run's threads and laid out as a .glb, what the
// service and the CLI do for it: encode_glb, end_to_end_glb).
struct Timing {
  double surface = kInf, encode = kInf, end_to_end = kInf, cpu = kInf;
  double encode_glb = kInf, end_to_end_glb = kInf;
};

struct Encoded {
  std::size_t draco_bytes = 0;
  double encode = 0.0, encode_glb = 0.0, cpu = 0.0;  // cpu: of the .drc encode
};

// Both outputs of `mesh` on the job's grid, timed.
Encoded encode_both(const Mesh& mesh, const DracoOptions& draco, int threads) {
  Encoded e;
  const double c0 = cpu_seconds();
  const auto t0 = std::chrono::steady_clock::now();
  e.draco_bytes = encode_draco(mesh, draco).size();
  e.encode = seconds_since(t0);
  e.cpu = cpu_seconds() - c0;
  const auto t1 = std::chrono::steady_clock::now();
  FrameCodecOptions pieces;
  pieces.codec = FrameCodec::kDracoPieces;
  pieces.draco = draco;
  const std::string frame = encode_frame(mesh, pieces, threads);
  const std::string glb = to_gltf(
      frame, FrameCodec::kDracoPieces, [&]() -> const Mesh& { return mesh; }, threads);
  e.encode_glb = seconds_since(t1);
  return e;
}

struct OursResult {
  std::size_t particles = 0;
  ParticleSurfacingStats stats;  // of the fastest repetition
  Timing time;
  std::size_t draco_bytes = 0;
  MeshFacts mesh;
  Flatness top;  // flatness slabs only
  int laplacian_sweeps = 0, bilaplacian_sweeps = 0, polish_sweeps = 0;
};

OursResult run_ours(const DataSet& set, int threads, int repeat, const std::string& write_dir) {
  const std::vector<Vec3> particles = set.particles();
  ParticleSurfacingOptions options = set.options;
  options.threads = threads;
  const Aabb box = job_box(particles, options);
  options.output_grid = QuantizationGrid::of(box, kDracoBits);
  DracoOptions draco;
  draco.quantization_bits = kDracoBits;
  draco.quantization_bounds = box;

  OursResult r;
  r.particles = particles.size();
  r.laplacian_sweeps = options.laplacian_sweeps;
  r.bilaplacian_sweeps = options.bilaplacian_sweeps;
  r.polish_sweeps = options.polish_sweeps;
  Mesh mesh;
  for (int k = 0; k < repeat; ++k) {
    mesh = {};  // the previous mesh must not add to this run's peak
    ParticleSurfacingStats stats;
    const double c0 = cpu_seconds();
    const auto t0 = std::chrono::steady_clock::now();
    mesh = surface_particles(particles, {}, options, {}, &stats);
    const double surface = seconds_since(t0);
    const double surface_cpu = cpu_seconds() - c0;
    const Encoded e = encode_both(mesh, draco, threads);
    r.draco_bytes = e.draco_bytes;
    r.time.cpu = std::min(r.time.cpu, surface_cpu + e.cpu);
    if (surface + e.encode < r.time.end_to_end) {
      r.time = {surface, e.encode, surface + e.encode, r.time.cpu, e.encode_glb, surface + e.encode_glb};
      r.stats = stats;
    }
  }
  r.mesh = facts_of(mesh);
  if (set.top) r.top = flatness(mesh, *set.top);
  if (!write_dir.empty()) write_mesh(write_dir + "/" + set.name + "_t" + std::to_string(threads) + ".ply", mesh);
  return r;
}

struct VdbResult {
  Timing time;
  double seconds_rasterize = 0.0, seconds_mesh = 0.0;  // of the fastest repetition
  std::size_t particles_too_small = 0;
  std::size_t draco_bytes = 0;
  MeshFacts mesh;
};

VdbResult run_openvdb(const DataSet& set, double radius, double voxel, int threads, int repeat) {
  const std::vector<Vec3> particles = set.particles();
  DracoOptions draco;
  draco.quantization_bits = kDracoBits;
  draco.quantization_bounds = job_box(particles, set.options);
  VdbResult r;
  Mesh mesh;
  for (int k = 0; k < repeat; ++k) {
    mesh = {};
    const double c0 = cpu_seconds();
    const auto t0 = std::chrono::steady_clock::now();
    bench::OpenVdbSurface out = bench::openvdb_surface(particles, radius, voxel, threads);
    const double surface = seconds_since(t0);
    const double surface_cpu = cpu_seconds() - c0;
    const Encoded e = encode_both(out.mesh, draco, threads);
    r.draco_bytes = e.draco_bytes;
    r.time.cpu = std::min(r.time.cpu, surface_cpu + e.cpu);
    if (surface + e.encode < r.time.end_to_end) {
      r.time = {surface, e.encode, surface + e.encode, r.time.cpu, e.encode_glb, surface + e.encode_glb};
      r.seconds_rasterize = out.seconds_rasterize;
      r.seconds_mesh = out.seconds_mesh;
      r.particles_too_small = out.particles_too_small;
    }
    mesh = std::move(out.mesh);
  }
  r.mesh = facts_of(mesh);
  return r;
}

// The voxel whose OpenVDB mesh has about `triangles` triangles, in at most kSearchTries meshings starting from
// `voxel`: first rescaled by sqrt(T_theirs / T_ours) (triangles ~ area / voxel^2), then by the secant of log T over
// log voxel through the last two tries, since the count of a bumpy sphere union falls faster than 1 / voxel^2 where
// the bumps stop being resolved. The try closest to `triangles`.
struct VoxelSearch {
  double voxel = 0.0;
  std::size_t triangles = 0;
  int tries = 0;
};

constexpr int kSearchTries = 3;

VoxelSearch equal_triangles_voxel(const DataSet& set, double radius, double voxel, std::size_t triangles, int threads) {
  const std::vector<Vec3> particles = set.particles();
  const double target = static_cast<double>(triangles);
  VoxelSearch best;
  double log_v0 = 0.0, log_t0 = 0.0;
  for (int tries = 1; tries <= kSearchTries; ++tries) {
    const std::size_t count = bench::openvdb_surface(particles, radius, voxel, threads).mesh.triangles.size();
    if (count == 0) break;
    const double error = std::abs(std::log(static_cast<double>(count) / target));
    if (tries == 1 || error < std::abs(std::log(static_cast<double>(best.triangles) / target))) {
      best.voxel = voxel;
      best.triangles = count;
    }
    best.tries = tries;
    if (error <= std::log1p(kEqualTrianglesTolerance)) break;
    const double log_v = std::log(voxel), log_t = std::log(static_cast<double>(count));
    double slope = -2.0;
    if (tries > 1 && log_v != log_v0) slope = std::clamp((log_t - log_t0) / (log_v - log_v0), -8.0, -1.0);
    log_v0 = log_v;
    log_t0 = log_t;
    voxel = std::exp(log_v + (std::log(target) - log_t) / slope);
  }
  return best;
}

// ---- Printing -------------------------------------------------------------------------------------------------------

double ns_per(double seconds, double count) { return count > 0 ? 1e9 * seconds / count : 0.0; }

// Per stage, one pair of columns (seconds, ns per unit) per thread count.
void print_stages(const std::vector<int>& threads, const std::vector<InChild<OursResult>>& runs) {
  struct Stage {
    const char* name;
    double ParticleSurfacingStats::*seconds;
    int OursResult::*sweeps;  // nullptr: not a sweep stage
    const char* per;
  };
  const Stage stages[] = {
      {"distance_field", &ParticleSurfacingStats::seconds_distance_field, nullptr, "particle"},
      {"polygonize", &ParticleSurfacingStats::seconds_polygonize, nullptr, "vertex"},
      {"laplacian", &ParticleSurfacingStats::seconds_laplacian, &OursResult::laplacian_sweeps, "vertex per sweep"},
      {"build_b", &ParticleSurfacingStats::seconds_build_b, nullptr, "vertex"},
      {"bilaplacian", &ParticleSurfacingStats::seconds_bilaplacian, &OursResult::bilaplacian_sweeps,
       "vertex per sweep"},
      {"polish", &ParticleSurfacingStats::seconds_polish, &OursResult::polish_sweeps, "vertex per sweep"},
      {"erosion", &ParticleSurfacingStats::seconds_erosion, nullptr, "vertex"},
      {"cleanup", &ParticleSurfacingStats::seconds_cleanup, nullptr, "vertex"},
      {"surface total", &ParticleSurfacingStats::seconds_total, nullptr, "particle"},
  };
  std::printf("  %-15s %6s", "stage", "sweeps");
  for (const int t : threads) std::printf("  %9s %9s", (std::to_string(t) + "T s").c_str(), "ns");
  std::printf("  ns per\n");
  for (const Stage& stage : stages) {
    const OursResult& first = runs.front().value;
    const int sweeps = stage.sweeps ? first.*stage.sweeps : 1;
    std::printf("  %-15s %6s", stage.name, stage.sweeps ? std::to_string(sweeps).c_str() : "");
    for (const InChild<OursResult>& run : runs) {
      const OursResult& r = run.value;
      const double seconds = r.stats.*stage.seconds;
      const bool per_particle = std::strcmp(stage.per, "particle") == 0;
      // Every stage after distance_field works on the Marching Tiles mesh.
      const double count =
          per_particle ? static_cast<double>(r.particles) : static_cast<double>(r.stats.initial_vertices) * sweeps;
      std::printf("  %9.3f %9.1f", seconds, ns_per(seconds, count));
    }
    std::printf("  %s\n", stage.per);
  }
}

void print_row_header() {
  std::printf("  %-28s %2s %8s %7s %9s %7s %7s %7s %7s %7s %7s %8s %5s %8s %7s %7s\n", "", "T", "voxel", "voxel/h",
              "triangles", "surface", "encode", "e2e s", "glb enc", "e2e glb", "cpu s", "Mpart/s", "MB", "surf o/t",
              "e2e o/t", "cpu o/t");
}

void print_row(const char* label, int threads, std::optional<double> voxel, double spacing, std::size_t particles,
               const Timing& t, const MeshFacts& mesh, double peak_mb, const Timing* ours) {
  char v[16] = "", vh[16] = "", surf_ratio[16] = "", e2e_ratio[16] = "", cpu_ratio[16] = "";
  if (voxel) {
    std::snprintf(v, sizeof v, "%.4g", *voxel);
    std::snprintf(vh, sizeof vh, "%.3f", *voxel / spacing);
  }
  if (ours) {
    std::snprintf(surf_ratio, sizeof surf_ratio, "%.2f", ours->surface / t.surface);
    std::snprintf(e2e_ratio, sizeof e2e_ratio, "%.2f", ours->end_to_end / t.end_to_end);
    std::snprintf(cpu_ratio, sizeof cpu_ratio, "%.2f", ours->cpu / t.cpu);
  }
  std::printf("  %-28s %2d %8s %7s %9zu %7.3f %7.3f %7.3f %7.3f %7.3f %7.3f %8.3f %5.0f %8s %7s %7s\n", label, threads,
              v, vh, mesh.triangles, t.surface, t.encode, t.end_to_end, t.encode_glb, t.end_to_end_glb, t.cpu,
              1e-6 * static_cast<double>(particles) / t.end_to_end, peak_mb, surf_ratio, e2e_ratio, cpu_ratio);
}

bool bench_block(const Config& cfg) {
  const DataSet set = block_set(cfg.particles);
  const std::array<int, 3> n = block_dims(cfg.particles);
  std::vector<InChild<OursResult>> ours;
  for (const int t : cfg.threads) {
    const auto run = in_child<OursResult>([&] { return run_ours(set, t, cfg.repeat, cfg.write_dir); });
    if (!run) {
      std::printf("block: our run at %d threads FAILED\n", t);
      return false;
    }
    ours.push_back(*run);
  }
  const OursResult& o = ours.front().value;
  const ParticleSurfacingStats& s = o.stats;
  std::printf(
      "block  %d x %d x %d = %zu particles, d %.3g, jitter +-0.1 d (seed 7), r_inner %.4g (0.6 d), r_outer %.4g\n",
      n[0], n[1], n[2], o.particles, kBlockSpacing, s.r_inner, s.r_outer);
  std::printf(
      "  ours: Marching Tiles spacing h %.4g -> %zu vertices; final %zu vertices, %zu triangles, %d components, "
      "closed manifold oriented %s, mean edge %.4g (%.3f h)\n",
      s.spacing, s.initial_vertices, o.mesh.vertices, o.mesh.triangles, o.mesh.components,
      o.mesh.closed_manifold ? "yes" : "NO", o.mesh.mean_edge, o.mesh.mean_edge / s.spacing);
  std::printf("        faithful at the end %.4f %%, min angle %.2f deg, slivers left %lld, Draco %.2f MB",
              100.0 * s.faithful_after_polish, o.mesh.min_angle, static_cast<long long>(s.slivers_left),
              1e-6 * static_cast<double>(o.draco_bytes));
  bool same = true;
  for (const auto& run : ours) same = same && run.value.mesh.hash == o.mesh.hash;
  std::printf("%s\n",
              ours.size() > 1 ? (same ? ", same mesh at every thread count" : ", MESH DIFFERS ACROSS THREADS") : "");
  print_stages(cfg.threads, ours);

  const int max_threads = *std::max_element(cfg.threads.begin(), cfg.threads.end());
  const double radius = s.r_outer;
  std::printf(
      "  end to end = surface (output_grid on) + encode at %d bits on the job's box: e2e s to --format drc (one Draco "
      "mesh, one thread), e2e glb to the default .glb (Draco pieces on T threads); cpu s: surface + .drc; "
      "OpenVDB %s: spheres of r_outer, ParticlesToLevelSet + volumeToMesh, no smoothing, encoded the same ways\n",
      kDracoBits, bench::openvdb_version().c_str());
  const auto search = in_child<VoxelSearch>(
      [&] { return equal_triangles_voxel(set, radius, o.mesh.mean_edge, o.mesh.triangles, max_threads); });
  if (!search) {
    std::printf("  OpenVDB voxel search FAILED\n");
    return false;
  }
  const double voxels[2] = {search->value.voxel, o.mesh.mean_edge};
  const char* labels[2] = {"OpenVDB (a) equal triangles", "OpenVDB (b) voxel = our edge"};
  print_row_header();
  bool ok = same;
  for (const auto& run : ours) ok = ok && run.value.mesh.closed_manifold;
  for (std::size_t k = 0; k < cfg.threads.size(); ++k) {
    const int t = cfg.threads[k];
    const OursResult& r = ours[k].value;
    print_row("ours", t, std::nullopt, s.spacing, r.particles, r.time, r.mesh, ours[k].peak_mb, nullptr);
    for (int v = 0; v < 2; ++v) {
      const auto vdb = in_child<VdbResult>([&] { return run_openvdb(set, radius, voxels[v], t, cfg.vdb_repeat); });
      if (!vdb) {
        std::printf("  %s at voxel %.4g FAILED\n", labels[v], voxels[v]);
        ok = false;
        continue;
      }
      print_row(labels[v], t, voxels[v], s.spacing, r.particles, vdb->value.time, vdb->value.mesh, vdb->peak_mb,
                &r.time);
      if (k + 1 == cfg.threads.size()) {
        const VdbResult& w = vdb->value;
        std::printf("      raster %.3f s, mesh %.3f s; %zu vertices, %d components, min angle %.2f deg, outward %s%s\n",
                    w.seconds_rasterize, w.seconds_mesh, w.mesh.vertices, w.mesh.components, w.mesh.min_angle,
                    w.mesh.outward ? "yes" : "NO",
                    w.particles_too_small ? " (some particles below 1.5 voxels skipped)" : "");
      }
    }
  }
  std::printf("  (a) voxel found in %d meshings: %zu triangles vs our %zu (%+.1f %%); OpenVDB seconds: min of %d\n",
              search->value.tries, search->value.triangles, o.mesh.triangles,
              100.0 * (static_cast<double>(search->value.triangles) / static_cast<double>(o.mesh.triangles) - 1.0),
              cfg.vdb_repeat);
  for (std::size_t k = 0; k < cfg.threads.size(); ++k) {
    const double e2e = ours[k].value.time.end_to_end_glb, mb = ours[k].peak_mb;
    if (cfg.particles == kBlockParticles && cfg.threads[k] == 2) {
      std::printf("  target at 2 threads: end to end to a .glb <= %.1f s (%s, %.3f s), peak <= %.0f MB (%s, %.0f MB)\n",
                  kBlockTargetSeconds, e2e <= kBlockTargetSeconds ? "met" : "NOT met", e2e, kBlockTargetMb,
                  mb <= kBlockTargetMb ? "met" : "NOT met", mb);
    }
  }
  std::printf("\n");
  std::fflush(stdout);
  return ok;
}

bool bench_flatness(const Config& cfg) {
  const int threads = *std::max_element(cfg.threads.begin(), cfg.threads.end());
  std::printf(
      "flatness  60 x 60 x 6 square-lattice slabs, d 0.01, no jitter, r_outer = 2 d or 2 r_inner (the default); top "
      "face: vertices above the top layer, 5 d inside the sides; %d threads, %s Bilaplacian sweeps\n"
      "  mean/d: the face's mean height above the top layer; plane/d: the highest plane the band allows (eq. 3.5)\n"
      "  thesis: the same slab with vertex_only_band (the thesis' band, cusps not held), run beside it; s/thesis: the\n"
      "  ratio of the surfacing seconds\n",
      threads, cfg.flatness_sweeps ? std::to_string(*cfg.flatness_sweeps).c_str() : "default");
  std::printf("  %9s %8s %9s %10s %9s %8s %8s %11s %7s %8s %10s %9s %7s %8s | %8s %8s %8s\n", "r_inner/d", "r_outer",
              "vertices", "triangles", "top verts", "RMS %ri", "p-p %ri", "RMS < 0.5%", "mean/d", "plane/d",
              "faithful %", "min angle", "slivers", "seconds", "RMS %ri", "mean/d", "s/thesis");
  bool ok = true;
  for (const bool default_outer : {false, true}) {
    for (const double ratio : kFlatnessRatios) {
      if (default_outer && ratio == 1.0) continue;  // 2 r_inner = 2 d: the slab above
      DataSet set = flatness_set(ratio, default_outer);
      if (cfg.flatness_sweeps) set.options.bilaplacian_sweeps = *cfg.flatness_sweeps;
      const char* outer = default_outer ? "2 r_in" : "2 d";
      const auto run = in_child<OursResult>([&] { return run_ours(set, threads, 1, cfg.write_dir); });
      DataSet thesis_set = set;
      thesis_set.name += "_vertex_only_band";
      thesis_set.options.vertex_only_band = true;
      const auto thesis = in_child<OursResult>([&] { return run_ours(thesis_set, threads, 1, cfg.write_dir); });
      if (!run || !thesis) {
        std::printf("  %9.2f %8s FAILED\n", ratio, outer);
        ok = false;
        continue;
      }
      const OursResult& r = run->value;
      const OursResult& t = thesis->value;
      ok = ok && r.mesh.closed_manifold;
      const double r_inner = r.stats.r_inner;
      const double rms = 100.0 * r.top.rms / r_inner, d = kFlatnessSpacing;
      const double plane = std::sqrt(r.stats.r_outer * r.stats.r_outer - d * d / 2.0);
      std::printf(
          "  %9.2f %8s %9zu %10zu %9zu %8.3f %8.3f %11s %7.3f %8.3f %10.4f %9.2f %7lld %8.3f | %8.3f %8.3f %8.2f%s\n",
          ratio, outer, r.mesh.vertices, r.mesh.triangles, r.top.vertices, rms, 100.0 * r.top.peak_to_peak / r_inner,
          rms < kFlatnessTargetPercent ? "yes" : "no", (r.top.mean - set.top->z_top) / d, plane / d,
          100.0 * r.stats.faithful_after_polish, r.mesh.min_angle, static_cast<long long>(r.stats.slivers_left),
          r.time.surface, 100.0 * t.top.rms / r_inner, (t.top.mean - set.top->z_top) / d,
          r.time.surface / t.time.surface, r.mesh.closed_manifold ? "" : "  mesh NOT closed manifold");
      std::fflush(stdout);
    }
  }
  std::printf("\n");
  return ok;
}

// splashsurf's published throughput (their README: a 13.35 M-particle frame in 2.47 s on 14 cores, coarse cubes, no
// smoothing), in particles per second per core.
constexpr double kSplashsurfParticlesPerCoreSecond = 13.35e6 / 2.47 / 14.0;
constexpr double kScaleMemoryShare = 0.9;          // of the physical memory a projected run may take
constexpr double kScaleOpenVdbMaxMillions = 13.5;  // OpenVDB beside ours up to this size

double physical_memory_mb() {
  const long pages = sysconf(_SC_PHYS_PAGES), page = sysconf(_SC_PAGE_SIZE);
  return pages > 0 && page > 0 ? static_cast<double>(pages) * static_cast<double>(page) / (1024.0 * 1024.0) : 0.0;
}

bool bench_scale(const Config& cfg) {
  const int threads = *std::max_element(cfg.threads.begin(), cfg.threads.end());
  const double ram_mb = physical_memory_mb();
  std::printf(
      "scale  the block (d %.3g, jitter +-0.1 d, r_inner 0.6 d) at growing sizes, %d threads, one run each; "
      "B/part = peak RSS / particles; physical memory %.1f GB\n",
      kBlockSpacing, threads, ram_mb / 1024.0);
  std::printf("  %-10s %-8s %10s %9s %8s %8s %8s %8s %7s %10s %9s %11s\n", "particles", "who", "triangles", "tri/part",
              "e2e s", "e2e glb", "cpu s", "peak MB", "B/part", "Mpart/s", "per core", "vs splash");
  bool ok = true;
  double bytes_per_particle = 0.0;  // of the largest size run so far
  for (const double millions : cfg.scale_millions) {
    const DataSet set = block_set(static_cast<std::size_t>(millions * 1e6));
    const std::array<int, 3> n = block_dims(static_cast<std::size_t>(millions * 1e6));
    const double particles = static_cast<double>(n[0]) * n[1] * n[2];
    const double projected_mb = bytes_per_particle * particles / (1024.0 * 1024.0);
    if (bytes_per_particle > 0.0 && projected_mb > kScaleMemoryShare * ram_mb) {
      std::printf("  %-10.4g %-8s not run: projected peak %.1f GB (%.0f B/part) > %.0f %% of %.1f GB\n",
                  particles * 1e-6, "ours", projected_mb / 1024.0, bytes_per_particle, 100.0 * kScaleMemoryShare,
                  ram_mb / 1024.0);
      continue;
    }
    const auto run = in_child<OursResult>([&] { return run_ours(set, threads, 1, cfg.write_dir); });
    if (!run) {
      std::printf("  %-10.4g %-8s FAILED\n", particles * 1e-6, "ours");
      ok = false;
      continue;
    }
    const OursResult& r = run->value;
    ok = ok && r.mesh.closed_manifold;
    bytes_per_particle = run->peak_mb * 1024.0 * 1024.0 / particles;
    const auto row = [&](const char* who, const Timing& t, std::size_t triangles, double peak_mb) {
      const double rate = particles / t.end_to_end_glb;
      std::printf("  %-10.4g %-8s %10zu %9.2f %8.3f %8.3f %8.3f %8.0f %7.0f %10.3f %9.3f %10.2fx\n", particles * 1e-6,
                  who, triangles, static_cast<double>(triangles) / particles, t.end_to_end, t.end_to_end_glb, t.cpu,
                  peak_mb, peak_mb * 1024.0 * 1024.0 / particles, rate * 1e-6, rate * 1e-6 / threads,
                  rate / threads / kSplashsurfParticlesPerCoreSecond);
    };
    row("ours", r.time, r.mesh.triangles, run->peak_mb);
    if (millions <= kScaleOpenVdbMaxMillions) {
      const auto vdb =
          in_child<VdbResult>([&] { return run_openvdb(set, r.stats.r_outer, r.mesh.mean_edge, threads, 1); });
      if (vdb) {
        row("OpenVDB", vdb->value.time, vdb->value.mesh.triangles, vdb->peak_mb);
      } else {
        std::printf("  %-10.4g %-8s FAILED\n", particles * 1e-6, "OpenVDB");
      }
    }
    std::fflush(stdout);
  }
  std::printf(
      "  splashsurf (published): %.3f M particles/s per core (13.35 M in 2.47 s on 14 cores, coarse cubes, no "
      "smoothing); Mpart/s, per core and vs splash to a .glb (e2e glb); vs splash = particles/s per core / theirs\n\n",
      kSplashsurfParticlesPerCoreSecond * 1e-6);
  return ok;
}

// Droplets: balls of radius 2-6 d of jittered lattice particles (spacing d, jitter +-d/6), 12 d apart on a
// 5 x 5 x 5 grid (seed 3).
std::vector<Vec3> droplet_particles(double d) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::vector<Vec3> p;
  for (int k = 0; k < 125; ++k) {
    const Vec3 c = Vec3(k % 5, (k / 5) % 5, k / 25) * 16.0 * d;
    const double radius = d * (2.0 + 4.0 * u(rng));
    const int n = static_cast<int>(radius / d);
    for (int z = -n; z <= n; ++z)
      for (int y = -n; y <= n; ++y)
        for (int x = -n; x <= n; ++x) {
          const double jx = u(rng), jy = u(rng), jz = u(rng);
          const Vec3 q = c + Vec3(x, y, z) * d + (Vec3(jx, jy, jz) - Vec3::Constant(0.5)) * (d / 3);
          if ((q - c).norm() <= radius) p.push_back(q);
        }
  }
  return p;
}

// --section decimate: the block and the droplets surfaced (min_angle_degrees = the decimation's 10), then decimated
// at TOL = 0.1 r_inner under the particle band rule with the largest thread count and with 1 thread; prints the
// triangle ratio, min angle, faithful fraction, closed/manifold, the seconds (wall and process CPU) of surfacing and of
// both decimations, decimate / surfacing, and whether the two decimations are identical (one run each). Fails when a
// mesh is not closed and manifold, a vertex is not faithful or the thread counts disagree.
bool bench_decimate(const Config& cfg) {
  bool ok = true;
  const int threads = *std::max_element(cfg.threads.begin(), cfg.threads.end());
  struct Named {
    const char* name;
    std::vector<Vec3> particles;
  };
  const Named sets[] = {{"block", lattice(block_dims(cfg.particles), kBlockSpacing, 0.1 * kBlockSpacing, 7)},
                        {"droplets", droplet_particles(kBlockSpacing)}};
  std::printf("decimate: TOL = 0.1 r_inner, r_inner 0.6 d, d %.3g, %d threads for the surfacing\n", kBlockSpacing,
              threads);
  for (const Named& set : sets) {
    ParticleSurfacingOptions options;
    options.r_inner = 0.6 * kBlockSpacing;
    options.threads = threads;
    options.min_angle_degrees = DecimateOptions{}.min_angle_degrees;
    ParticleSurfacingStats stats;
    const auto t0 = std::chrono::steady_clock::now();
    const double c0 = cpu_seconds();
    const Mesh mesh = surface_particles(set.particles, {}, options, {}, &stats);
    const double surfacing = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    const double surfacing_cpu = cpu_seconds() - c0;
    const SurfacePointRule rule = particle_band_rule(set.particles, {}, stats.r_inner, stats.r_outer);
    DecimateStats dstats, one_thread;
    const double c1 = cpu_seconds();
    const Mesh out = decimate(mesh, {.tolerance = 0.1 * stats.r_inner, .threads = threads}, rule, {}, &dstats);
    const double decimate_cpu = cpu_seconds() - c1;
    const Mesh out1 = decimate(mesh, {.tolerance = 0.1 * stats.r_inner, .threads = 1}, rule, {}, &one_thread);
    const bool same = out1.vertices == out.vertices && out1.triangles == out.triangles;
    std::size_t faithful = 0;
    for (const Vec3& v : out.vertices) faithful += rule(v) ? 1 : 0;
    const MeshReport before = check_mesh(mesh), after = check_mesh(out);
    const bool closed = after.closed && after.edge_manifold && after.vertex_manifold && after.oriented;
    ok = ok && closed && faithful == out.vertices.size() && same;
    std::printf(
        "  %-8s %zu particles: %zu -> %zu triangles (%.2fx), min angle %.2f -> %.2f deg, faithful %.4f %%, closed "
        "manifold %s; surfacing %.3f s (CPU %.3f s), decimate %.3f s (CPU %.3f s; %.2fx the surfacing's time, %.2fx "
        "its CPU; 1 thread %.3f s, same mesh %s)\n",
        set.name, set.particles.size(), mesh.triangles.size(), out.triangles.size(),
        static_cast<double>(mesh.triangles.size()) /
            static_cast<double>(std::max<std::size_t>(1, out.triangles.size())),
        before.min_angle_degrees, after.min_angle_degrees,
        100.0 * static_cast<double>(faithful) / static_cast<double>(std::max<std::size_t>(1, out.vertices.size())),
        closed ? "yes" : "NO", surfacing, surfacing_cpu, dstats.seconds, decimate_cpu, dstats.seconds / surfacing,
        decimate_cpu / surfacing_cpu, one_thread.seconds, same ? "yes" : "NO");
    std::fflush(stdout);
  }
  std::printf("\n");
  return ok;
}

// --section wide: a 40^3 lattice (d 0.01, no jitter) at r_inner of 1, 2 and 3 d, the radii a user who takes r_inner
// for a kernel radius gives: many outer spheres pass near each vertex, and the cusp search is cubic in them. Printed:
// triangles, vertices holding a cusp, build_b and surface seconds, and the surface seconds without cusps
// (vertex_only_band) beside them.
constexpr std::array<double, 3> kWideRatios = {1.0, 2.0, 3.0};  // r_inner / d

bool bench_wide(const Config& cfg) {
  const int threads = *std::max_element(cfg.threads.begin(), cfg.threads.end());
  constexpr double d = 0.01;
  constexpr int n = 40;
  std::printf(
      "wide  a %d^3 lattice, d %.3g, no jitter, r_inner several spacings wide (r_outer 2 r_inner), %d threads, one "
      "run each; no cusps: vertex_only_band\n",
      n, d, threads);
  std::printf("  %9s %10s %12s %10s %10s %14s %9s\n", "r_inner/d", "triangles", "cusp verts", "build_b s", "surface s",
              "no cusps s", "ratio");
  bool ok = true;
  for (const double ratio : kWideRatios) {
    DataSet set;
    char name[32];
    std::snprintf(name, sizeof name, "wide_%.0fd", ratio);
    set.name = name;
    set.particles = [] { return lattice({n, n, n}, d, 0.0, 9); };
    set.options.r_inner = ratio * d;
    DataSet plain = set;
    plain.name += "_vertex_only_band";
    plain.options.vertex_only_band = true;
    const auto run = in_child<OursResult>([&] { return run_ours(set, threads, 1, cfg.write_dir); });
    const auto bare = in_child<OursResult>([&] { return run_ours(plain, threads, 1, cfg.write_dir); });
    if (!run || !bare) {
      std::printf("  %9.1f FAILED\n", ratio);
      ok = false;
      continue;
    }
    const OursResult& r = run->value;
    ok = ok && r.mesh.closed_manifold;
    std::printf("  %9.1f %10zu %12zu %10.3f %10.3f %14.3f %8.1fx%s\n", ratio, r.mesh.triangles, r.stats.cusp_vertices,
                r.stats.seconds_build_b, r.time.surface, bare->value.time.surface,
                r.time.surface / bare->value.time.surface, r.mesh.closed_manifold ? "" : "  mesh NOT closed manifold");
    std::fflush(stdout);
  }
  std::printf("\n");
  return ok;
}

// --section radii: the droplets (droplet_particles, d = kBlockSpacing) with per-particle radii 0.6 d x U(0.6, 1.5)
// (seed 5), as they are and with one particle's radius (the first one's, at a droplet's surface) multiplied by 5, 20
// and 100: a pscale left at its default among simulation particles. The large particle's sphere adds its own
// triangles, so beside the seconds and their ratio to the droplets alone the line prints microseconds per output
// triangle: one particle should cost about its own surface (docs/ALGORITHMS.md §1, CHOICE "radius tiers"), not
// widen every search to its radius. One run each, each in its own child.
constexpr std::array<double, 4> kOutlierFactors = {1.0, 5.0, 20.0, 100.0};

struct RadiiResult {
  double seconds = 0.0;
  ParticleSurfacingStats stats;
  MeshFacts mesh;
};

bool bench_radii(const Config& cfg) {
  const int threads = *std::max_element(cfg.threads.begin(), cfg.threads.end());
  constexpr double d = kBlockSpacing;
  std::printf(
      "radii  droplets with per-particle radii 0.6 d x U(0.6, 1.5), d %.3g, one radius multiplied by the factor, %d "
      "threads, one run each\n",
      d, threads);
  std::printf("  %7s %10s %10s %10s %10s %12s %9s\n", "factor", "particles", "triangles", "build_b s", "surface s",
              "us/triangle", "ratio");
  bool ok = true;
  double alone = 0.0;
  for (const double factor : kOutlierFactors) {
    const auto run = in_child<RadiiResult>([&] {
      const std::vector<Vec3> particles = droplet_particles(d);
      std::mt19937 rng(5);
      std::uniform_real_distribution<double> u(0.6, 1.5);
      std::vector<double> radii(particles.size());
      for (double& r : radii) r = 0.6 * d * u(rng);
      radii.front() *= factor;
      ParticleSurfacingOptions options;
      options.threads = threads;
      RadiiResult r;
      const auto t0 = std::chrono::steady_clock::now();
      const Mesh mesh = surface_particles(particles, radii, options, {}, &r.stats);
      r.seconds = seconds_since(t0);
      r.mesh = facts_of(mesh);
      return r;
    });
    if (!run) {
      std::printf("  %7.0f FAILED\n", factor);
      ok = false;
      continue;
    }
    const RadiiResult& r = run->value;
    if (factor == 1.0) alone = r.seconds;
    const bool good = r.mesh.closed_manifold && r.stats.faithful_after_polish == 1.0;
    ok = ok && good;
    std::printf("  %7.0f %10zu %10zu %10.3f %10.3f %12.2f %8.2fx%s\n", factor, r.stats.particles, r.mesh.triangles,
                r.stats.seconds_build_b, r.seconds, 1e6 * r.seconds / static_cast<double>(r.mesh.triangles),
                r.seconds / alone, good ? "" : "  mesh NOT closed manifold or NOT faithful");
    std::fflush(stdout);
  }
  std::printf("\n");
  return ok;
}

constexpr const char* kUsage =
    "usage: particles_bench [--particles N] [--repeat R] [--vdb-repeat R]\n"
    "                       [--section block|flatness|scale|decimate|wide|radii] [--threads T] [--flatness-sweeps N]\n"
    "                       [--scale-sizes M,M,...] [--write DIR]\n";

}  // namespace
}  // namespace surfacer

int main(int argc, char** argv) {
  using namespace surfacer;
  Config cfg;
  // The last flag given that only the block, only the flatness slabs, only the scale section use.
  std::string block_flag, flatness_flag, scale_flag;
  bench::Args args(argc, argv, "particles_bench", kUsage);
  while (args.next()) {
    const std::string& flag = args.flag();
    if (flag == "--particles") {
      cfg.particles = args.integer<std::size_t>(8);
      block_flag = flag;
    } else if (flag == "--repeat") {
      cfg.repeat = args.integer(1);
      block_flag = flag;
    } else if (flag == "--vdb-repeat") {
      cfg.vdb_repeat = args.integer(1);
      block_flag = flag;
    } else if (flag == "--section") {
      const std::string section = args.value("block, flatness, scale, decimate, wide or radii");
      if (section != "block" && section != "flatness" && section != "scale" && section != "decimate" &&
          section != "wide" && section != "radii")
        args.error("--section is block, flatness, scale, decimate, wide or radii, got '" + section + "'");
      cfg.block = section == "block";
      cfg.flatness = section == "flatness";
      cfg.scale = section == "scale";
      cfg.decimate = section == "decimate";
      cfg.wide = section == "wide";
      cfg.radii = section == "radii";
    } else if (flag == "--threads") {
      cfg.threads = {args.integer(1)};
    } else if (flag == "--flatness-sweeps") {
      cfg.flatness_sweeps = args.integer(0);
      flatness_flag = flag;
    } else if (flag == "--scale-sizes") {
      cfg.scale_millions.clear();
      const std::string list = args.value("millions of particles, comma-separated (0.5,2,13.5)");
      for (std::size_t at = 0; at <= list.size();) {
        const std::size_t comma = std::min(list.find(',', at), list.size());
        char* end = nullptr;
        const std::string item = list.substr(at, comma - at);
        const double m = std::strtod(item.c_str(), &end);
        if (item.empty() || *end != '\0' || !(m >= 1e-5 && m <= 1e4)) {
          args.error("--scale-sizes: '" + item + "' is not a size in millions of particles (1e-5 .. 1e4)");
        }
        cfg.scale_millions.push_back(m);
        at = comma + 1;
      }
      scale_flag = flag;
    } else if (flag == "--write") {
      cfg.write_dir = args.value("a directory");
    } else {
      args.unknown();
    }
  }
  // The flatness slabs have a fixed size and run once, on our side only; the block keeps the default sweeps.
  if (!cfg.block && !cfg.decimate && !block_flag.empty()) args.error(block_flag + " applies to the block only");
  if (!cfg.flatness && !flatness_flag.empty()) args.error(flatness_flag + " applies to the flatness slabs only");
  if (!cfg.scale && !scale_flag.empty()) args.error(scale_flag + " applies to --section scale only");
  double load[3] = {0, 0, 0};
  if (getloadavg(load, 3) < 0) load[0] = -1;
  std::printf(
      "particles_bench: %u hardware threads, load average %.2f at start, seconds = min of %d repetitions "
      "(OpenVDB: %d), every run in its own child process (MB = its peak RSS)\n\n",
      std::thread::hardware_concurrency(), load[0], cfg.repeat, cfg.vdb_repeat);
  std::fflush(stdout);
  bool ok = true;
  if (cfg.block) ok = bench_block(cfg) && ok;
  if (cfg.flatness) ok = bench_flatness(cfg) && ok;
  if (cfg.wide) ok = bench_wide(cfg) && ok;
  if (cfg.radii) ok = bench_radii(cfg) && ok;
  if (cfg.scale) ok = bench_scale(cfg) && ok;
  if (cfg.decimate) ok = bench_decimate(cfg) && ok;
  if (getloadavg(load, 3) >= 0) std::printf("load average %.2f at the end\n", load[0]);
  return ok ? 0 : 1;
}
