// OpenVDB as the reference particle surfacer of particles_bench: the particles rasterized as spheres of one radius
// into a narrow-band level set (tools::ParticlesToLevelSet, half width 3 voxels), optionally smoothed by Gaussian
// passes (tools::LevelSetFilter), meshed at isovalue 0 without adaptivity (tools::volumeToMesh). Kept in its own
// translation unit so OpenVDB's headers are compiled once; built without OpenVDB (bench/CMakeLists.txt), the same
// functions say it is missing.
#pragma once

#include <cstddef>
#include <optional>
#include <span>
#include <string>

#include "core/util/geometry.h"

namespace surfacer::bench {

// What to print instead of the comparison when particles_bench was built without OpenVDB.
inline constexpr const char* kOpenVdbMissing = "OpenVDB not available (apt-get install libopenvdb-dev)";

// OpenVDB's library version ("10.0.1"), or nullopt when built without it.
std::optional<std::string> openvdb_version();

struct OpenVdbMesh {
  std::size_t vertices = 0;
  std::size_t triangles = 0;            // volumeToMesh's quads count as 2 triangles each
  std::size_t particles_too_small = 0;  // skipped by ParticlesToLevelSet: radius below its minimum of 1.5 voxels
  double seconds_rasterize = 0.0, seconds_filter = 0.0, seconds_mesh = 0.0;
};

// Surfaces `particles` as the union of spheres of `radius` on a grid of `voxel` (scene units, both > 0), after
// `gaussian_passes` LevelSetFilter::gaussian(width 1) passes (0: none), with TBB limited to `threads` (>= 1).
// Throws std::logic_error when built without OpenVDB (check openvdb_version() first).
OpenVdbMesh openvdb_surface(std::span<const Vec3> particles, double radius, double voxel, int gaussian_passes,
                            int threads);

}  // namespace surfacer::bench
