#include "server/polygonize.h"

#include <cmath>

#include "core/util/errors.h"
#include "core/polygonize/marching_cubes.h"
#include "core/polygonize/marching_tiles.h"
#include "server/scene_translate.h"

namespace surfacer::server {
namespace {

constexpr double kPadCells = 2.0;  // padding of derived bounds, so closed surfaces stay inside

}  // namespace

PolygonizeSettings resolve_polygonize(const std::vector<FieldPtr>& fields, const v1::Bounds* request_bounds,
                                      const Resolution& resolution, int default_cells, v1::Polygonizer method,
                                      bool normals, const Limits& limits, const std::string& path) {
  PolygonizeSettings s;
  s.normals = normals;
  switch (method) {
    case v1::POLYGONIZER_CUBES: s.method = v1::POLYGONIZER_CUBES; break;
    case v1::POLYGONIZER_UNSPECIFIED:
    case v1::POLYGONIZER_TILES: s.method = v1::POLYGONIZER_TILES; break;
    default:
      throw InvalidInput(path + ".method", path + ".method (" + std::to_string(static_cast<int>(method)) +
                                               ") is not a polygonizer; use POLYGONIZER_TILES or POLYGONIZER_CUBES");
  }
  // Bounds: given, or the union of the fields' own bounds padded by two cells.
  Aabb bounds;
  if (request_bounds != nullptr) {
    bounds = to_aabb(*request_bounds, path + ".bounds");
  } else {
    for (std::size_t i = 0; i < fields.size(); ++i) {
      const auto b = fields[i]->bounds();
      if (!b) {
        throw InvalidInput(path + ".bounds", path + ": scene " + std::to_string(i) +
                                                 " is unbounded (a plane or gyroid not intersected with a bounded "
                                                 "solid); give " + path + ".bounds");
      }
      if (i == 0) {
        bounds = *b;
      } else {
        bounds.min = bounds.min.cwiseMin(b->min);
        bounds.max = bounds.max.cwiseMax(b->max);
      }
    }
    if (!bounds.min.allFinite() || !bounds.max.allFinite() || !bounds.valid()) {
      throw InvalidInput(path + ".bounds", path + ": the scene is empty (its bounds are empty or not finite); give " +
                                               path + ".bounds or check the scene");
    }
  }
  const double longest = bounds.size().maxCoeff();
  if (resolution.cell_size) {
    s.h = *resolution.cell_size;
    if (!(s.h > 0.0) || !std::isfinite(s.h)) {
      throw InvalidInput(path + ".cell_size", path + ".cell_size (" + std::to_string(s.h) +
                                                  ") must be a finite number > 0");
    }
  } else {
    const int cells = resolution.cells.value_or(default_cells);
    if (cells < 1) {
      throw InvalidInput(path + ".cells", path + ".cells (" + std::to_string(cells) +
                                              ") must be >= 1 (cells along the longest axis; e.g. 128)");
    }
    s.h = longest / cells;
  }
  if (request_bounds == nullptr) {
    bounds.min.array() -= kPadCells * s.h;
    bounds.max.array() += kPadCells * s.h;
  }
  double total = 1.0;
  for (int a = 0; a < 3; ++a) {
    const double n = std::max(1.0, std::ceil(bounds.size()[a] / s.h - 1e-9));
    total *= n;
    s.cells[a] = static_cast<int>(std::min(n, 1e9));
  }
  if (total > static_cast<double>(limits.max_grid_cells)) {
    throw ResourceLimit("max_grid_cells", path + ": the grid has " + std::to_string(s.cells[0]) + " x " +
                                              std::to_string(s.cells[1]) + " x " + std::to_string(s.cells[2]) +
                                              " cells, over the server's limit of " +
                                              std::to_string(limits.max_grid_cells) +
                                              "; use fewer cells or start the server with a larger "
                                              "--max-grid-cells");
  }
  // Stretch the bounds to a whole number of cubic cells, keeping the centre.
  s.bounds = bounds;
  for (int a = 0; a < 3; ++a) {
    const double extra = s.cells[a] * s.h - bounds.size()[a];
    s.bounds.min[a] -= extra / 2;
    s.bounds.max[a] += extra / 2;
  }
  return s;
}

Mesh polygonize(const Field& field, const PolygonizeSettings& settings, int threads, const RunControl& control) {
  if (settings.method == v1::POLYGONIZER_CUBES) {
    MarchingCubesOptions options;
    options.bounds = settings.bounds;
    options.cells = settings.cells;
    options.normals = settings.normals;
    options.threads = threads;
    options.sparse = true;  // same mesh as dense; skips samples the field's Lipschitz bound rules out
    return marching_cubes(field, options, control);
  }
  MarchingTilesOptions options;
  options.bounds = settings.bounds;
  options.spacing = settings.h;
  options.normals = settings.normals;
  options.threads = threads;
  return marching_tiles(field, options, control);
}

}  // namespace surfacer::server
