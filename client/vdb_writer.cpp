#include "client/vdb_writer.h"

#include <openvdb/io/Stream.h>
#include <openvdb/openvdb.h>
#include <openvdb/tools/MeshToVolume.h>

#include <Eigen/Geometry>
#include <cmath>
#include <mutex>
#include <sstream>
#include <vector>

#include "client/exit_codes.h"
#include "core/util/format.h"

namespace surfacer::client {
namespace {

constexpr float kHalfWidth = 3.0f;  // voxels each side of the surface: OpenVDB's LEVEL_SET_HALF_WIDTH

double surface_area(const Mesh& mesh) {
  double area = 0.0;
  for (const Triangle& t : mesh.triangles) {
    area += 0.5 * (mesh.vertices[t[1]] - mesh.vertices[t[0]]).cross(mesh.vertices[t[2]] - mesh.vertices[t[0]]).norm();
  }
  return area;
}

}  // namespace

double default_vdb_voxel_size(const Mesh& mesh) {
  double total = 0.0;
  for (const Triangle& t : mesh.triangles) {
    for (int k = 0; k < 3; ++k) total += (mesh.vertices[t[(k + 1) % 3]] - mesh.vertices[t[k]]).norm();
  }
  return mesh.triangles.empty() ? 0.0 : total / (3.0 * static_cast<double>(mesh.triangles.size()));
}

std::string write_vdb(const Mesh& mesh, double voxel_size) {
  static std::once_flag initialized;
  std::call_once(initialized, [] { openvdb::initialize(); });
  if (voxel_size == 0.0) voxel_size = default_vdb_voxel_size(mesh);
  if (mesh.triangles.empty()) voxel_size = voxel_size > 0.0 ? voxel_size : 1.0;
  if (!std::isfinite(voxel_size) || voxel_size <= 0.0) {
    throw CliError(ExitCode::kUsage, "--vdb-voxel-size " + format_number(voxel_size) + ": give a length > 0");
  }
  // The band holds about (area / h^2) x (2 x half width) voxels.
  const double voxels = surface_area(mesh) / (voxel_size * voxel_size) * 2.0 * kHalfWidth;
  if (voxels > kMaxVdbVoxels) {
    throw CliError(ExitCode::kUsage,
                   "--vdb-voxel-size " + format_number(voxel_size) + ": the surface's band would hold about " +
                       format_number(voxels) + " voxels, over the " + format_number(kMaxVdbVoxels) +
                       " a .vdb may; use a voxel size of at least " +
                       format_number(voxel_size * std::sqrt(voxels / kMaxVdbVoxels)));
  }
  std::vector<openvdb::Vec3s> points;
  points.reserve(mesh.vertices.size());
  for (const Vec3& p : mesh.vertices) points.emplace_back(float(p.x()), float(p.y()), float(p.z()));
  std::vector<openvdb::Vec3I> triangles;
  triangles.reserve(mesh.triangles.size());
  for (const Triangle& t : mesh.triangles) triangles.emplace_back(t[0], t[1], t[2]);
  const openvdb::math::Transform::Ptr transform = openvdb::math::Transform::createLinearTransform(voxel_size);
  openvdb::FloatGrid::Ptr grid;
  if (mesh.triangles.empty()) {
    grid = openvdb::FloatGrid::create(static_cast<float>(kHalfWidth * voxel_size));
    grid->setTransform(transform);
    grid->setGridClass(openvdb::GRID_LEVEL_SET);
  } else {
    // meshToLevelSet takes points in world space and samples them through the transform.
    grid = openvdb::tools::meshToLevelSet<openvdb::FloatGrid>(*transform, points, triangles, kHalfWidth);
  }
  grid->setName("surface");
  grid->insertMeta("creator", openvdb::StringMetadata("surfacer"));
  std::ostringstream out(std::ios_base::binary);
  openvdb::io::Stream(out).write({grid});
  return std::move(out).str();
}

}  // namespace surfacer::client
