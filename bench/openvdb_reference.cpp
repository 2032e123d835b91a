#include "bench/openvdb_reference.h"

#include <openvdb/openvdb.h>
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

std::string openvdb_version() { return openvdb::getLibraryVersionString(); }

OpenVdbSurface openvdb_surface(std::span<const Vec3> particles, double radius, double voxel, int threads) {
  openvdb::initialize();
  const tbb::global_control limit(tbb::global_control::max_allowed_parallelism, static_cast<std::size_t>(threads));
  OpenVdbSurface out;

  auto t0 = std::chrono::steady_clock::now();
  const openvdb::FloatGrid::Ptr grid = openvdb::createLevelSet<openvdb::FloatGrid>(voxel, 3.0);
  openvdb::tools::ParticlesToLevelSet<openvdb::FloatGrid> raster(*grid);
  raster.rasterizeSpheres(ParticleList(particles), radius);
  raster.finalize(true);
  out.particles_too_small = raster.getMinCount();
  out.seconds_rasterize = seconds_since(t0);

  t0 = std::chrono::steady_clock::now();
  std::vector<openvdb::Vec3s> points;
  std::vector<openvdb::Vec3I> triangles;
  std::vector<openvdb::Vec4I> quads;
  openvdb::tools::volumeToMesh(*grid, points, triangles, quads, /*isovalue=*/0.0, /*adaptivity=*/0.0);
  out.seconds_mesh = seconds_since(t0);

  // volumeToMesh winds its faces clockwise seen from outside a level set: reversed here so the mesh is outward.
  out.mesh.vertices.reserve(points.size());
  for (const openvdb::Vec3s& p : points) out.mesh.vertices.emplace_back(p.x(), p.y(), p.z());
  out.mesh.triangles.reserve(triangles.size() + 2 * quads.size());
  for (const openvdb::Vec3I& t : triangles) out.mesh.triangles.push_back({t[0], t[2], t[1]});
  for (const openvdb::Vec4I& q : quads) {
    out.mesh.triangles.push_back({q[0], q[2], q[1]});
    out.mesh.triangles.push_back({q[0], q[3], q[2]});
  }
  return out;
}

}  // namespace surfacer::bench
