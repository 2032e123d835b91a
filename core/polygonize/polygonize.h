// The choice of polygonizer, in one place: Marching Tiles (the default; every vertex valence >= 5) or Marching Cubes,
// the grid they run on (a region and a resolution, resolved from what a request gives), and one call that runs either.
// Used by the isosurface job, the optimize job's start mesh and the active surface.
#pragma once

#include <array>
#include <cstdint>
#include <optional>
#include <span>
#include <string_view>

#include "core/mesh/mesh.h"
#include "core/scene/scene.h"
#include "core/util/run_control.h"

namespace surfacer {

enum class Polygonizer {
  kTiles,  // Marching Tiles over the acute A15 tiling (core/polygonize/marching_tiles.h): valence >= 5
  kCubes,  // Marching Cubes (core/polygonize/marching_cubes.h): the baseline, valence-4 vertices
};

// "tiles" / "cubes".
std::string_view polygonizer_name(Polygonizer polygonizer);
// The polygonizer named `name` ("tiles" or "cubes"), or nullopt.
std::optional<Polygonizer> polygonizer_from_name(std::string_view name);

// A polygonization as requested. The defaults are the isosurface job's.
struct PolygonizeOptions {
  Polygonizer method = Polygonizer::kTiles;
  // Region to polygonize (valid box). Default: the union of the fields' own bounds, grown by kPadCells cells on
  // every side so that closed surfaces stay inside.
  std::optional<Aabb> bounds;
  // Cubic cells along the longest axis of the region (>= 1), used when cell_size is unset.
  int cells = 128;
  // The cell edge (cubes) or mean sample spacing (tiles) in scene units (> 0); overrides `cells`.
  std::optional<double> cell_size;
  bool normals = false;  // per-vertex unit normals from the field gradient
  int threads = 0;       // 0: hardware threads

  static constexpr double kPadCells = 2.0;
};

// Throws InvalidInput naming "method", "bounds", "cells", "cell_size" or "threads" (with a hint).
void validate(const PolygonizeOptions& options);

// The grid a polygonization runs on: whole cubic cells of edge h covering the region (stretched about its centre).
struct PolygonizeGrid {
  Polygonizer method = Polygonizer::kTiles;
  Aabb bounds;
  double h = 0.0;  // cell edge (cubes) / mean sample spacing (tiles)
  std::array<int, 3> cells{1, 1, 1};
  // Cells of the whole grid as requested (what a server's --max-grid-cells bounds); an axis of more than 10^9 cells
  // is clamped in `cells` but counted here in full.
  double cell_count = 1.0;
  bool normals = false;
  int threads = 0;
  // Each vertex at least this far (scene units, >= 0) from both ends of its edge, but never more than a quarter of
  // the edge: a frame runner sets a few quantization steps, so that vertices near a zero sample keep distinct grid
  // points and their triangles keep some area on the grid (docs/ALGORITHMS.md §5 "Clean on the grid"). 0: off.
  double vertex_margin = 0.0;
};

// Resolves `options` for `fields` (the union of their bounds is the default region). Validates the options first.
// Throws InvalidInput("bounds") when no bounds are given and a field is unbounded or the union is empty.
PolygonizeGrid resolve_grid(std::span<const FieldPtr> fields, const PolygonizeOptions& options);

// Mesh of {f = 0} on `grid` with the chosen polygonizer: welded, oriented outward, closed where the surface stays
// inside the grid, deterministic whatever grid.threads. Marching Cubes runs sparse (the same mesh as dense, skipping
// samples the field's Lipschitz bound rules out). Throws what the polygonizer throws (Cancelled when control fires).
// Obeys control.triangles as the triangles are produced (core/util/triangle_limit.h; the polygonizers' headers give
// their memory per triangle).
Mesh polygonize(const Field& field, const PolygonizeGrid& grid, const RunControl& control = {});

// The working memory polygonize(field, grid) holds besides its triangles, in bytes, known before the work
// (marching_cubes_fixed_bytes / marching_tiles_fixed_bytes).
std::int64_t polygonize_fixed_bytes(const PolygonizeGrid& grid);

}  // namespace surfacer
