#include "bench/openvdb_reference.h"

#ifdef SURFACER_HAVE_OPENVDB

#include <openvdb/openvdb.h>
#include <openvdb/tools/LevelSetFilter.h>
#include <openvdb/tools/ParticlesToLevelSet.h>
#include <openvdb/tools/VolumeToMesh.h>
#include <tbb/global_control.h>

#include <chrono>
#include <vector>

namespace surfacer::bench {
namespace {

// The particle list ParticlesToLevelSet reads (rasterizeSpheres with one radius needs only size and getPos).
class ParticleList {
 public:
  using PosType = openvdb::Vec3R;
  explicit ParticleList(std::span<const Vec3> particles) : particles_(particles) {}
  std::size_t size() const { return particles_.size(); }
  void getPos(std::size_t n, openvdb::Vec3R& xyz) const {
    const Vec3& p = particles_[n];
    xyz = openvdb::Vec3R(p.x(), p.y(), p.z());
  }

 private:
  std::span<const Vec3> particles_;
};

double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

}  // namespace

std::optional<std::string> openvdb_version() { return std::string(openvdb::getLibraryVersionString()); }

OpenVdbMesh openvdb_surface(std::span<const Vec3> particles, double radius, double voxel, int gaussian_passes,
                            int threads) {
  openvdb::initialize();
  const tbb::global_control limit(tbb::global_control::max_allowed_parallelism, static_cast<std::size_t>(threads));
  OpenVdbMesh out;

  auto t0 = std::chrono::steady_clock::now();
  const openvdb::FloatGrid::Ptr grid = openvdb::createLevelSet<openvdb::FloatGrid>(voxel, 3.0);
  openvdb::tools::ParticlesToLevelSet<openvdb::FloatGrid> raster(*grid);
  raster.rasterizeSpheres(ParticleList(particles), radius);
  raster.finalize(true);
  out.particles_too_small = raster.getMinCount();
  out.seconds_rasterize = seconds_since(t0);

  t0 = std::chrono::steady_clock::now();
  if (gaussian_passes > 0) {
    openvdb::tools::LevelSetFilter<openvdb::FloatGrid> filter(*grid);
    for (int k = 0; k < gaussian_passes; ++k) filter.gaussian(1);
  }
  out.seconds_filter = seconds_since(t0);

  t0 = std::chrono::steady_clock::now();
  std::vector<openvdb::Vec3s> points;
  std::vector<openvdb::Vec3I> triangles;
  std::vector<openvdb::Vec4I> quads;
  openvdb::tools::volumeToMesh(*grid, points, triangles, quads, /*isovalue=*/0.0, /*adaptivity=*/0.0);
  out.seconds_mesh = seconds_since(t0);
  out.vertices = points.size();
  out.triangles = triangles.size() + 2 * quads.size();
  return out;
}

}  // namespace surfacer::bench

#else  // built without OpenVDB

#include <stdexcept>

namespace surfacer::bench {

std::optional<std::string> openvdb_version() { return std::nullopt; }

OpenVdbMesh openvdb_surface(std::span<const Vec3>, double, double, int, int) {
  throw std::logic_error(kOpenVdbMissing);
}

}  // namespace surfacer::bench

#endif
