// OpenVDB reference for bench/particles_bench.sh (optional, bench-only; not part of the CMake build): the same
// jittered 80^3 block as particles_bench's "block" set, rasterized as spheres of radius r_outer with
// tools::ParticlesToLevelSet, optionally smoothed with tools::LevelSetFilter (Gaussian), meshed with
// tools::volumeToMesh (adaptivity 0). Built by particles_bench.sh with g++ when libopenvdb-dev is installed.
//
//   openvdb_particles --radius R --spacing H [--repeat N] [--ours SECONDS] [--ours-cpu SECONDS]
//
// Two voxel sizes: H (the Marching Tiles sample spacing) and H/2 (about the vertex density Marching Tiles gives at
// spacing H, which places ~5 vertices per H^2). Times are wall seconds, best of N.
#include <openvdb/openvdb.h>
#include <openvdb/tools/LevelSetFilter.h>
#include <openvdb/tools/ParticlesToLevelSet.h>
#include <openvdb/tools/VolumeToMesh.h>
#include <sys/resource.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <random>
#include <string>
#include <vector>

namespace {

struct Particles {
  using PosType = openvdb::Vec3R;
  std::vector<openvdb::Vec3R> positions;
  double radius = 1.0;
  size_t size() const { return positions.size(); }
  void getPos(size_t n, openvdb::Vec3R& xyz) const { xyz = positions[n]; }
  void getPosRad(size_t n, openvdb::Vec3R& xyz, openvdb::Real& rad) const {
    xyz = positions[n];
    rad = radius;
  }
};

// Identical to particles_bench's jittered_block(80, 0.25, 1).
std::vector<openvdb::Vec3R> jittered_block(int n, double jitter, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-jitter, jitter);
  std::vector<openvdb::Vec3R> p;
  p.reserve(static_cast<size_t>(n) * n * n);
  for (int k = 0; k < n; ++k) {
    for (int j = 0; j < n; ++j) {
      for (int i = 0; i < n; ++i) {
        const double x = i + u(rng);
        const double y = j + u(rng);
        const double z = k + u(rng);
        p.emplace_back(x, y, z);
      }
    }
  }
  return p;
}

double now() { return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count(); }

struct Run {
  double rasterize = 0, filter = 0, mesh = 0;
  size_t vertices = 0, triangles = 0;
};

Run run(const Particles& particles, double voxel, int gaussian_passes) {
  Run r;
  double t = now();
  openvdb::FloatGrid::Ptr grid = openvdb::createLevelSet<openvdb::FloatGrid>(voxel, 3.0);
  openvdb::tools::ParticlesToLevelSet<openvdb::FloatGrid> raster(*grid);
  raster.rasterizeSpheres(particles, particles.radius);
  raster.finalize(true);
  r.rasterize = now() - t;
  t = now();
  if (gaussian_passes > 0) {
    openvdb::tools::LevelSetFilter<openvdb::FloatGrid> filter(*grid);
    for (int k = 0; k < gaussian_passes; ++k) filter.gaussian(1);
  }
  r.filter = now() - t;
  t = now();
  std::vector<openvdb::Vec3s> points;
  std::vector<openvdb::Vec3I> triangles;
  std::vector<openvdb::Vec4I> quads;
  openvdb::tools::volumeToMesh(*grid, points, triangles, quads, 0.0, 0.0);
  r.mesh = now() - t;
  r.vertices = points.size();
  r.triangles = triangles.size() + 2 * quads.size();
  return r;
}

}  // namespace

int main(int argc, char** argv) {
  double radius = 0, spacing = 0, ours = 0, ours_cpu = 0;
  int repeat = 1;
  for (int a = 1; a + 1 < argc; a += 2) {
    const std::string arg = argv[a];
    const double v = std::atof(argv[a + 1]);
    if (arg == "--radius")
      radius = v;
    else if (arg == "--spacing")
      spacing = v;
    else if (arg == "--repeat")
      repeat = std::max(1, static_cast<int>(v));
    else if (arg == "--ours")
      ours = v;
    else if (arg == "--ours-cpu")
      ours_cpu = v;
  }
  if (!(radius > 0) || !(spacing > 0)) {
    std::fprintf(stderr, "usage: openvdb_particles --radius R --spacing H [--repeat N] [--ours S] [--ours-cpu S]\n");
    return 2;
  }
  openvdb::initialize();
  Particles particles;
  particles.positions = jittered_block(80, 0.25, 1);
  particles.radius = radius;
  std::printf("OpenVDB %s, %zu particles, sphere radius %.4g\n", openvdb::getLibraryVersionString(), particles.size(),
              radius);
  for (const double voxel : {spacing, 0.5 * spacing}) {
    for (const int passes : {0, 4}) {
      Run best;
      double best_total = 1e300;
      rusage before{}, after{};
      getrusage(RUSAGE_SELF, &before);
      for (int k = 0; k < repeat; ++k) {
        const Run r = run(particles, voxel, passes);
        const double total = r.rasterize + r.filter + r.mesh;
        if (total < best_total) {
          best_total = total;
          best = r;
        }
      }
      getrusage(RUSAGE_SELF, &after);
      const double cpu =
          (after.ru_utime.tv_sec - before.ru_utime.tv_sec) + (after.ru_stime.tv_sec - before.ru_stime.tv_sec) +
          1e-6 *
              ((after.ru_utime.tv_usec - before.ru_utime.tv_usec) + (after.ru_stime.tv_usec - before.ru_stime.tv_usec));
      std::printf(
          "  voxel %.4g, %d Gaussian passes: rasterize %.3f  filter %.3f  mesh %.3f  total %.3f s (cpu %.3f s "
          "per run), %zu vertices, %zu triangles",
          voxel, passes, best.rasterize, best.filter, best.mesh, best_total, cpu / repeat, best.vertices,
          best.triangles);
      if (ours > 0) std::printf("  -> ours/theirs wall %.2f", ours / best_total);
      if (ours_cpu > 0) std::printf(", cpu %.2f", ours_cpu / (cpu / repeat));
      std::printf("\n");
      std::fflush(stdout);
    }
  }
  return 0;
}
