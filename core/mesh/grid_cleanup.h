// A mesh made clean on the quantization grid it is delivered on (docs/ALGORITHMS.md §5 "Frames", "Clean on the
// grid"): no triangle degenerate once its corners are quantized (collinear or repeated grid points) and no two
// vertices on one grid point, so that what a decoder reads is as closed and manifold as the mesh was. Every job
// type's frames go through it (server/runners/frames.h); the particle surfacer repairs on the grid itself first.
#pragma once

#include <cstdint>
#include <vector>

#include "core/mesh/mesh.h"
#include "core/mesh/quantization.h"
#include "core/util/run_control.h"

namespace surfacer {

struct GridCleanupOptions {
  // A flip or collapse may not take a vertex below this valence when it was at or above it (Marching Tiles meshes
  // start at 5; Marching Cubes meshes have vertices of valence 3 and 4, which stay allowed to lose none); in [3, 6].
  int min_valence = 5;
  int max_rounds = 4;  // rounds of (repair, nudge) at most; >= 1
  int threads = 0;     // for the scans; 0: hardware threads
};

struct GridCleanupReport {
  std::int64_t degenerate_found = 0;   // triangles degenerate on the grid on entry
  std::int64_t coincident_found = 0;   // vertices sharing a grid point with another on entry
  std::int64_t flips = 0, collapses = 0;
  std::int64_t nudges = 0;             // vertices moved to a free neighbouring grid point
  // Left after the last round, counted afresh on the mesh as returned (0 and 0 on every mesh the tests know).
  std::int64_t degenerate_left = 0;
  std::int64_t coincident_left = 0;
};

// Cleans `mesh` on `grid`, in rounds: the sliver repair with the grid (core/mesh/mesh_repair.h: edge flips and
// collapses that keep the mesh closed, manifold and oriented, with the valence floor), then every vertex still on a
// degenerate triangle or on a shared grid point is nudged to the nearest of its 26 neighbouring grid points that is
// free and leaves none of its triangles degenerate or turned over (positions move by at most one grid step along each
// axis, to a grid point exactly). The report's counts left come from a fresh scan of the result, not from the
// repair's bookkeeping. Vertices outside grid.box are left where they are (the encoder refuses them). Normals follow
// their vertices. Cost: two parallel scans (triangles, then the vertices' grid points sorted) when the mesh is clean;
// adjacency only around what is found. Throws Cancelled (control, between rounds and every few thousand edits).
GridCleanupReport clean_on_grid(Mesh& mesh, const QuantizationGrid& grid, const GridCleanupOptions& options = {},
                                const RunControl& control = {});

// Replaces every position by the one a decoder of the grid gives it (dequantize(quantize(p))).
void snap_to_grid(std::vector<Vec3>& vertices, const QuantizationGrid& grid, int threads = 0);

}  // namespace surfacer
