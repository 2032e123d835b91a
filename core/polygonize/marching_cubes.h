// Marching Cubes (Lorensen & Cline 1987, with the standard 256-case table) over a regular grid of cells.
// The baseline polygonizer; Marching Tiles (core/polygonize/marching_tiles.h) is the default
// (core/polygonize/polygonize.h).
#pragma once

#include <array>
#include <cstdint>
#include <span>

#include "core/mesh/mesh.h"
#include "core/util/run_control.h"

namespace surfacer {

class Field;

struct MarchingCubesOptions {
  Aabb bounds;                           // region sampled; grid points lie on its corners
  std::array<int, 3> cells{64, 64, 64};  // cells per axis, >= 1 each
  bool normals = false;                  // per-vertex normals from the field gradient (normalized, outward)
  int threads = 0;                       // 0: hardware threads
  // marching_cubes(Field) only: skip evaluating the field where Field::lipschitz_bound() proves that no grid edge
  // can be crossed (per z-layer, a quadtree of point tiles: a tile, grown by one cell on every side and one layer
  // up and down, is skipped when |f(centre)| > L * half-diagonal; its points get f(centre), which has their sign).
  // The mesh is byte-identical to the dense one; evaluations drop to about surface area / cell size^2 times a small
  // factor plus a quadtree overhead. No effect without a bound or for pre-sampled input.
  bool sparse = false;
  // Each vertex at least this far (scene units, >= 0) from both ends of its edge, but never more than a quarter of
  // the edge: a frame runner sets a few quantization steps, so that vertices near a zero sample keep distinct grid
  // points and their triangles keep some area on the grid (docs/ALGORITHMS.md §5 "Clean on the grid"). 0: off.
  double vertex_margin = 0.0;
};

// Mesh of {f = 0} for a normalized field (negative inside). Output: welded (one vertex per crossed grid edge),
// triangles oriented outward (toward increasing f), no degenerate triangles when samples equal 0 exactly
// (a sample equal to 0 counts as outside). Closed wherever the surface does not leave `bounds`.
// Deterministic: the same input yields the same mesh whatever `threads`.
// Throws InvalidInput for bad options, Cancelled when control's token fires (checked at least once per slab).
//
// Details (core/polygonize/marching_cubes.cpp, core/polygonize/mc_tables.py):
// * Vertices are linear interpolations on crossed edges. Ambiguous cube faces are always resolved from the face's own
//   corners (the inside corners stay connected across the face), so the mesh is a closed, oriented 2-manifold
//   (edge- and vertex-manifold) for a surface inside `bounds`, and an oriented manifold with boundary where it leaves.
// * "No degenerate triangles" means no repeated vertex index. A zero sample puts vertices exactly on its grid point
//   (t = 0 or 1); where one cube holds several such vertices (the surface touches a grid point) a triangle can still
//   have zero area.
// * Work is split into z-slabs (up to two per thread); each keeps two z-layers of samples plus per-layer edge-vertex
//   id arrays, so a Field is never sampled as a whole grid. control.check() runs every z-layer (and every row while
//   sampling a Field); control.report("polygonize", fraction) after every z-layer, non-decreasing, serialized.
// * Field normals: normalized Field::value_and_gradient at the vertex. Sample normals: central differences (one-sided
//   on the border) at the edge's two grid points, interpolated with the vertex's t, normalized. A zero gradient
//   falls back to the edge direction from its inside to its outside end.
// * Errors: InvalidInput fields "bounds" (min < max, finite), "cells" (1..2^24 each), "threads" (>= 0), "samples"
//   (size); ResourceLimit "cells" when a z-layer exceeds 2^31 points or the mesh 2^31 vertices per slab.
// * Triangles: control.triangles (core/util/triangle_limit.h) is obeyed as they are produced (counted every cell
//   row of every slab): past its max_triangles the run stops with ResourceLimit naming it and the count reached, and
//   its hook reserves their memory before they are made.
// * Memory: fixed, marching_cubes_fixed_bytes() (per slab running at once -- one per thread -- two z-layers of
//   samples, inside bits, row ranges and x/y-edge vertex ids plus one layer of z-edge ids: 38 bytes per point of a
//   z-layer); per triangle, 12 bytes in its slab plus its share of the vertices (a closed mesh has about half as
//   many vertices as triangles: 12 bytes per triangle, 24 with normals), all copied once more into the mesh at the
//   end, so 48 bytes per triangle (72 with normals) at the peak.
Mesh marching_cubes(const Field& field, const MarchingCubesOptions& options, const RunControl& control = {});

// The fixed working memory of marching_cubes (above), in bytes, for valid options.
std::int64_t marching_cubes_fixed_bytes(const MarchingCubesOptions& options);

// The same over pre-sampled values (x fastest, (cells+1) per axis points), for dense-grid throughput.
Mesh marching_cubes_samples(std::span<const float> samples, const MarchingCubesOptions& options,
                            const RunControl& control = {});

}  // namespace surfacer
