// The polygonizing step shared by job types: resolves bounds and resolution from a request, checks limits, and
// runs Marching Cubes or Marching Tiles.
#pragma once

#include <array>
#include <optional>
#include <string>
#include <vector>

#include "core/util/run_control.h"
#include "core/scene/scene.h"
#include "server/server.h"
#include "surfacer/v1/surfacer.pb.h"

namespace surfacer::server {

struct PolygonizeSettings {
  v1::Polygonizer method = v1::POLYGONIZER_TILES;
  Aabb bounds;                      // whole cubic cells of edge h
  double h = 0.0;                   // cell edge (cubes) / mean sample spacing (tiles)
  std::array<int, 3> cells{1, 1, 1};
  bool normals = false;
};

// Resolution as requested: cells along the longest axis, or a cell size; nullopt = default_cells.
struct Resolution {
  std::optional<int> cells;
  std::optional<double> cell_size;
};

// `bounds`: the request's bounds, or null to use the union of the fields' own bounds padded by two cells.
// `path` names the request message for errors ("spec.isosurface"). Throws InvalidInput / ResourceLimit.
PolygonizeSettings resolve_polygonize(const std::vector<FieldPtr>& fields, const v1::Bounds* bounds,
                                      const Resolution& resolution, int default_cells, v1::Polygonizer method,
                                      bool normals, const Limits& limits, const std::string& path);

Mesh polygonize(const Field& field, const PolygonizeSettings& settings, int threads, const RunControl& control);

}  // namespace surfacer::server
