// OpenVDB (.vdb) files of frames: the narrow-band signed distance to the surface that Houdini, Blender and OpenVDB's
// own tools render, collide against and combine. Only client/vdb_writer.cpp includes OpenVDB (slow headers).
#pragma once

#include <string>

#include "core/mesh/mesh.h"

namespace surfacer::client {

// A .vdb holds at most this many active voxels (a narrow band of 3 voxels each side): about 40 bytes each to build.
inline constexpr double kMaxVdbVoxels = 2e8;

// The voxel edge used when none is given: the mesh's mean edge length (the surface's own resolution). 0 for a mesh
// without triangles.
double default_vdb_voxel_size(const Mesh& mesh);

// `mesh` as an OpenVDB file: one FloatGrid named "surface", of class level set, negative inside, with a narrow band
// of 3 voxels each side of the surface, voxels of edge `voxel_size` (0: default_vdb_voxel_size) in scene units; the
// mesh should be closed (OpenVDB's meshToLevelSet: open or self-intersecting parts are signed as well as they can
// be). A mesh without triangles gives an empty grid of that class. Throws CliError(kUsage) naming --vdb-voxel-size
// for a size that is not finite and > 0, or whose band would pass kMaxVdbVoxels (before any voxel is made).
std::string write_vdb(const Mesh& mesh, double voxel_size);

}  // namespace surfacer::client
