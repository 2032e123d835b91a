// Particle surfacing benchmark: generates data sets in-process, surfaces each with surface_particles and
// prints particles/s, time per stage and peak memory. Each data set runs in its own child process, so its peak RSS
// (wait4 ru_maxrss) is its own and not the largest of everything before it.
//
//   particles_bench [--sets block,sheet,droplets,spray,block_fine] [--repeat N] [--threads T] [--write DIR]
//
// Data sets (d = lattice spacing 1):
//   block       80^3 = 512,000 particles on a cubic lattice, each jittered uniformly by +-0.25 d per axis;
//               r_inner derived (mean nearest-neighbour distance, ~0.78 d), r_outer = 2 r_inner. The target
//               (<= 2.5 s including all smoothing, <= 1.5 GB) is for this set.
//   block_fine  the same particles with r_inner = 0.5 d (SPH "radius = half the spacing"): ~4x the triangles.
//   sheet       a wavy sheet two particles thick, 250 x 250 x 2 = 125,000 particles, r_inner = d.
//   droplets    1,000 droplets of 8..64 particles (~36,000) scattered in a 400 d box, r_inner = 0.8 d.
//   spray       a 40^3 block plus 100,000 single particles scattered over a 1000 d box (~164,000), r_inner = 0.6 d,
//               min_particles_per_component = 5 (the spray is dropped before surfacing).
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <random>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "core/mesh/mesh_checks.h"
#include "core/mesh/mesh_io.h"
#include "core/particles/particle_surfacer.h"

namespace {

using surfacer::Vec3;

struct DataSet {
  std::string name;
  std::vector<Vec3> particles;
  surfacer::ParticleSurfacingOptions options;
};

DataSet jittered_block(int n, double jitter, std::uint32_t seed) {
  DataSet s;
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-jitter, jitter);
  s.particles.reserve(static_cast<std::size_t>(n) * n * n);
  for (int k = 0; k < n; ++k) {
    for (int j = 0; j < n; ++j) {
      for (int i = 0; i < n; ++i) {
        // One statement each: the generator's call order must not depend on argument evaluation order
        // (bench/openvdb_particles.cpp regenerates the same block).
        const double x = i + u(rng);
        const double y = j + u(rng);
        const double z = k + u(rng);
        s.particles.emplace_back(x, y, z);
      }
    }
  }
  return s;
}

std::string note_of(const std::string& name) {
  if (name == "block") return "80^3 lattice, jitter +-0.25, r_inner derived";
  if (name == "block_fine") return "80^3 lattice, jitter +-0.25, r_inner 0.5";
  if (name == "sheet") return "250 x 250 x 2 wavy sheet, r_inner 1";
  if (name == "droplets") return "1000 droplets of 8..64 particles in a 400^3 box, r_inner 0.8";
  if (name == "spray") return "40^3 block + 100k single particles over 1000^3, r_inner 0.6, min 5 per component";
  return "";
}

DataSet make_set(const std::string& name) {
  DataSet s;
  if (name == "block" || name == "block_fine") {
    s = jittered_block(80, 0.25, 1);
    if (name == "block") {
      s.options.derive_r_inner = true;
    } else {
      s.options.r_inner = 0.5;
    }
  } else if (name == "sheet") {
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
  } else if (name == "droplets") {
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
  } else if (name == "spray") {
    s = jittered_block(40, 0.2, 4);
    std::mt19937 rng(5);
    std::uniform_real_distribution<double> box(-500.0, 500.0);
    for (int p = 0; p < 100000; ++p) s.particles.emplace_back(box(rng), box(rng), box(rng));
    s.options.r_inner = 0.6;
    s.options.min_particles_per_component = 5;
  } else {
    std::fprintf(stderr, "unknown data set '%s'\n", name.c_str());
    std::exit(2);
  }
  s.name = name;
  return s;
}

struct Result {
  std::size_t particles = 0;
  std::vector<double> wall;  // per repetition
  double cpu = 0.0;          // user + system seconds of the last repetition
  surfacer::ParticleSurfacingStats stats;
  bool closed = false, manifold = false;
  int components = 0;
};

double cpu_seconds() {
  rusage ru{};
  getrusage(RUSAGE_SELF, &ru);
  return static_cast<double>(ru.ru_utime.tv_sec + ru.ru_stime.tv_sec) +
         1e-6 * static_cast<double>(ru.ru_utime.tv_usec + ru.ru_stime.tv_usec);
}

// Runs in the child: generate, surface `repeat` times, write a result line to fd.
void child(const std::string& name, int repeat, int threads, const std::string& write_dir, int fd) {
  DataSet set = make_set(name);
  set.options.threads = threads;
  Result r;
  r.particles = set.particles.size();
  surfacer::Mesh mesh;
  for (int k = 0; k < repeat; ++k) {
    const double c0 = cpu_seconds();
    const auto t0 = std::chrono::steady_clock::now();
    mesh = surfacer::surface_particles(set.particles, {}, set.options, {}, &r.stats);
    r.wall.push_back(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
    r.cpu = cpu_seconds() - c0;
  }
  const surfacer::MeshReport report = surfacer::check_mesh(mesh);
  if (!write_dir.empty()) surfacer::write_mesh(write_dir + "/" + name + ".ply", mesh);
  const auto& s = r.stats;
  std::ostringstream out;
  out.precision(6);
  out << r.particles << ' ' << s.particles_used << ' ' << s.vertices << ' ' << s.triangles << ' ' << r.cpu << ' '
      << s.r_inner << ' ' << s.r_outer << ' ' << s.spacing << ' ' << s.seconds_distance_field << ' '
      << s.seconds_polygonize << ' ' << s.seconds_laplacian << ' ' << s.seconds_build_b << ' ' << s.seconds_bilaplacian
      << ' ' << s.seconds_polish << ' ' << s.seconds_total << ' ' << s.faithful_after_constrained << ' '
      << s.faithful_after_polish << ' ' << s.max_violation_after_polish << ' ' << s.seam_fraction << ' '
      << s.field_evaluations << ' ' << report.closed << ' ' << (report.edge_manifold && report.vertex_manifold) << ' '
      << report.components << ' ' << s.initial_min_valence << ' ' << s.components_dropped;
  for (const double w : r.wall) out << ' ' << w;
  out << '\n';
  const std::string line = out.str();
  if (write(fd, line.data(), line.size()) != static_cast<ssize_t>(line.size())) std::_Exit(3);
}

}  // namespace

int main(int argc, char** argv) {
  std::vector<std::string> sets = {"block", "sheet", "droplets", "spray"};
  int repeat = 3;
  int threads = 0;
  std::string write_dir;
  for (int a = 1; a < argc; ++a) {
    const std::string arg = argv[a];
    auto value = [&]() -> std::string {
      if (a + 1 >= argc) {
        std::fprintf(stderr, "%s needs a value\n", arg.c_str());
        std::exit(2);
      }
      return argv[++a];
    };
    if (arg == "--sets") {
      sets.clear();
      std::stringstream ss(value());
      for (std::string item; std::getline(ss, item, ',');) sets.push_back(item);
    } else if (arg == "--repeat") {
      repeat = std::max(1, std::atoi(value().c_str()));
    } else if (arg == "--threads") {
      threads = std::atoi(value().c_str());
    } else if (arg == "--write") {
      write_dir = value();
    } else {
      std::fprintf(stderr,
                   "usage: particles_bench [--sets block,block_fine,sheet,droplets,spray] [--repeat N] [--threads T] "
                   "[--write DIR]\n");
      return 2;
    }
  }
  double load[3] = {0, 0, 0};
  if (getloadavg(load, 3) < 0) load[0] = -1;
  std::printf("particles_bench: %u hardware threads, threads=%d, load average %.2f, %d repetitions per set\n",
              std::thread::hardware_concurrency(), threads, load[0], repeat);
  std::printf("(wall = best of the repetitions; cpu = user+sys of the last; peak RSS of the child process)\n\n");
  std::fflush(stdout);
  bool all_ok = true;
  for (const std::string& name : sets) {
    int pipefd[2];
    if (pipe(pipefd) != 0) return 3;
    const pid_t pid = fork();
    if (pid == 0) {
      close(pipefd[0]);
      child(name, repeat, threads, write_dir, pipefd[1]);
      close(pipefd[1]);
      std::_Exit(0);
    }
    close(pipefd[1]);
    std::string line;
    char buf[4096];
    for (ssize_t n; (n = read(pipefd[0], buf, sizeof buf)) > 0;) line.append(buf, static_cast<std::size_t>(n));
    close(pipefd[0]);
    int status = 0;
    rusage ru{};
    wait4(pid, &status, 0, &ru);
    if (!WIFEXITED(status) || WEXITSTATUS(status) != 0 || line.empty()) {
      std::printf("%-10s FAILED (status %d)\n", name.c_str(), status);
      all_ok = false;
      continue;
    }
    std::istringstream in(line);
    std::size_t particles, used, vertices, triangles;
    double cpu, r_in, r_out, h, t_df, t_poly, t_lap, t_b, t_bilap, t_polish, t_total, faithful, faithful_polish,
        violation, seam;
    long long evaluations;
    int closed, manifold, components, min_valence;
    std::size_t dropped;
    in >> particles >> used >> vertices >> triangles >> cpu >> r_in >> r_out >> h >> t_df >> t_poly >> t_lap >> t_b >>
        t_bilap >> t_polish >> t_total >> faithful >> faithful_polish >> violation >> seam >> evaluations >> closed >>
        manifold >> components >> min_valence >> dropped;
    std::vector<double> walls;
    for (double w; in >> w;) walls.push_back(w);
    const double best = *std::min_element(walls.begin(), walls.end());
    const double peak_mb = static_cast<double>(ru.ru_maxrss) / 1024.0;
    std::printf("%-10s %s\n", name.c_str(), note_of(name).c_str());
    std::printf("  particles %zu (used %zu, %zu spray clusters dropped)  r_inner %.4g r_outer %.4g spacing %.4g\n",
                particles, used, dropped, r_in, r_out, h);
    std::printf(
        "  mesh: %zu vertices, %zu triangles, %d components, closed %s, manifold %s; Marching Tiles min valence %d\n",
        vertices, triangles, components, closed ? "yes" : "NO", manifold ? "yes" : "NO", min_valence);
    std::printf("  wall %.3f s best (", best);
    for (std::size_t k = 0; k < walls.size(); ++k) std::printf("%s%.3f", k ? ", " : "", walls[k]);
    std::printf(")  cpu %.3f s  ->  %.0f particles/s (%.0f per cpu-second)\n", cpu, particles / best, particles / cpu);
    std::printf(
        "  stages (last run, s): distance_field %.3f  polygonize %.3f  laplacian %.3f  build_B %.3f  "
        "bilaplacian %.3f  polish %.3f  total %.3f\n",
        t_df, t_poly, t_lap, t_b, t_bilap, t_polish, t_total);
    std::printf(
        "  field samples %lld, serial seam %.1f%%, faithful %.4f%% after constrained sweeps, %.2f%% after "
        "polish (max violation %.3g)\n",
        evaluations, 100.0 * seam, 100.0 * faithful, 100.0 * faithful_polish, violation);
    std::printf("  peak RSS %.0f MB\n\n", peak_mb);
    std::fflush(stdout);
  }
  return all_ok ? 0 : 1;
}
