// OpenVDB as the reference particle surfacer of particles_bench: the particles rasterized as spheres of one radius
// into a narrow-band level set (tools::ParticlesToLevelSet, half width 3 voxels) and meshed at isovalue 0 without
// adaptivity (tools::volumeToMesh), with no smoothing. Kept in its own translation unit so OpenVDB's headers are
// compiled once.
#pragma once

#include <cstddef>
#include <span>
#include <string>

#include "core/mesh/mesh.h"
#include "core/util/geometry.h"

namespace surfacer::bench {

// OpenVDB's library version ("10.0.1").
std::string openvdb_version();

struct OpenVdbSurface {
  Mesh mesh;                            // volumeToMesh's quads split into 2 triangles each
  std::size_t particles_too_small = 0;  // skipped by ParticlesToLevelSet: radius below its minimum of 1.5 voxels
  double seconds_rasterize = 0.0;       // ParticlesToLevelSet, including finalize (prune)
  double seconds_mesh = 0.0;            // volumeToMesh, without the copy into `mesh`
};

// Surfaces `particles` as the union of spheres of `radius` on a grid of `voxel` (scene units, both > 0), with TBB
// limited to `threads` (>= 1).
OpenVdbSurface openvdb_surface(std::span<const Vec3> particles, double radius, double voxel, int threads);

}  // namespace surfacer::bench
