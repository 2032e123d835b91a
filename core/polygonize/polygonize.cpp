#include "core/polygonize/polygonize.h"

#include <algorithm>
#include <cmath>

#include "core/polygonize/marching_cubes.h"
#include "core/polygonize/marching_tiles.h"
#include "core/util/checks.h"

namespace surfacer {

std::string_view polygonizer_name(Polygonizer polygonizer) {
  return polygonizer == Polygonizer::kCubes ? "cubes" : "tiles";
}

std::optional<Polygonizer> polygonizer_from_name(std::string_view name) {
  if (name == "tiles") return Polygonizer::kTiles;
  if (name == "cubes") return Polygonizer::kCubes;
  return std::nullopt;
}

void validate(const PolygonizeOptions& o) {
  if (o.method != Polygonizer::kTiles && o.method != Polygonizer::kCubes) {
    throw InvalidInput("method", "method (" + std::to_string(static_cast<int>(o.method)) +
                                     ") is not a polygonizer; use tiles or cubes");
  }
  if (o.bounds) require_box("bounds", *o.bounds);
  if (o.cell_size) {
    require_length("cell_size", *o.cell_size, "the cell edge (cubes) or sample spacing (tiles) in scene units");
  } else if (o.cells < 1) {
    throw InvalidInput("cells", "cells (" + std::to_string(o.cells) +
                                    ") must be >= 1 (cells along the longest axis; "
                                    "the default is " +
                                    std::to_string(PolygonizeOptions{}.cells) + ")");
  }
  if (o.threads < 0) {
    throw InvalidInput("threads",
                       "threads (" + std::to_string(o.threads) + ") must be >= 0 (0: every hardware thread)");
  }
}

PolygonizeGrid resolve_grid(std::span<const FieldPtr> fields, const PolygonizeOptions& options) {
  validate(options);
  PolygonizeGrid grid;
  grid.method = options.method;
  grid.normals = options.normals;
  grid.threads = options.threads;
  Aabb bounds;
  if (options.bounds) {
    bounds = *options.bounds;
  } else {
    for (std::size_t i = 0; i < fields.size(); ++i) {
      const auto b = fields[i]->bounds();
      if (!b) {
        throw InvalidInput(
            "bounds", "bounds are needed: scene " + std::to_string(i) +
                          " is unbounded (a plane or gyroid not intersected with a bounded solid, or a smooth union "
                          "whose blend reaches below a child arbitrarily far away)");
      }
      bounds = i == 0 ? *b : merged(bounds, *b);
    }
    if (fields.empty() || !bounds.finite() || !bounds.valid()) {
      throw InvalidInput("bounds", "bounds are needed: the scene is empty (its own bounds are empty or not finite)");
    }
  }
  grid.h = options.cell_size ? *options.cell_size : bounds.size().maxCoeff() / options.cells;
  if (!options.bounds) bounds = bounds.padded(PolygonizeOptions::kPadCells * grid.h);
  grid.cell_count = 1.0;
  for (int a = 0; a < 3; ++a) {
    const double n = std::max(1.0, std::ceil(bounds.size()[a] / grid.h - 1e-9));
    grid.cell_count *= n;
    grid.cells[a] = static_cast<int>(std::min(n, 1e9));
  }
  // Stretch the region to a whole number of cubic cells, keeping its centre.
  grid.bounds = bounds;
  for (int a = 0; a < 3; ++a) {
    const double extra = grid.cells[a] * grid.h - bounds.size()[a];
    grid.bounds.min[a] -= extra / 2;
    grid.bounds.max[a] += extra / 2;
  }
  return grid;
}

namespace {

MarchingCubesOptions cubes_options(const PolygonizeGrid& grid) {
  MarchingCubesOptions options;
  options.bounds = grid.bounds;
  options.cells = grid.cells;
  options.normals = grid.normals;
  options.threads = grid.threads;
  options.sparse = true;  // the same mesh as dense; skips samples the field's Lipschitz bound rules out
  options.vertex_margin = grid.vertex_margin;
  return options;
}

MarchingTilesOptions tiles_options(const PolygonizeGrid& grid) {
  MarchingTilesOptions options;
  options.bounds = grid.bounds;
  options.spacing = grid.h;
  options.normals = grid.normals;
  options.threads = grid.threads;
  options.vertex_margin = grid.vertex_margin;
  return options;
}

}  // namespace

Mesh polygonize(const Field& field, const PolygonizeGrid& grid, const RunControl& control) {
  if (grid.method == Polygonizer::kCubes) return marching_cubes(field, cubes_options(grid), control);
  return marching_tiles(field, tiles_options(grid), control);
}

std::int64_t polygonize_fixed_bytes(const PolygonizeGrid& grid) {
  if (grid.method == Polygonizer::kCubes) return marching_cubes_fixed_bytes(cubes_options(grid));
  return marching_tiles_fixed_bytes(tiles_options(grid));
}

}  // namespace surfacer
