// Marching Cubes (Lorensen & Cline 1987, with the standard 256-case table) over a regular grid of cells.
// The baseline polygonizer; Marching Tiles (core/marching_tiles.h, issue 3) is the default once it lands.
#pragma once

#include <array>
#include <cstdint>
#include <span>

#include "core/mesh.h"
#include "core/run_control.h"

namespace surfacer {

class Field;

struct MarchingCubesOptions {
  Aabb bounds;                        // region sampled; grid points lie on its corners
  std::array<int, 3> cells{64, 64, 64};  // cells per axis, >= 1 each
  bool normals = false;               // per-vertex normals from the field gradient (normalized, outward)
  int threads = 0;                    // 0: hardware threads
};

// Mesh of {f = 0} for a normalized field (negative inside). Output: welded (one vertex per crossed grid edge),
// triangles oriented outward (toward increasing f), no degenerate triangles when samples equal 0 exactly
// (a sample equal to 0 counts as outside). Closed wherever the surface does not leave `bounds`.
// Deterministic: the same input yields the same mesh whatever `threads`.
// Throws InvalidInput for bad options, Cancelled when control's token fires (checked at least once per slab).
Mesh marching_cubes(const Field& field, const MarchingCubesOptions& options, const RunControl& control = {});

// The same over pre-sampled values (x fastest, (cells+1) per axis points), for dense-grid throughput.
Mesh marching_cubes_samples(std::span<const float> samples, const MarchingCubesOptions& options,
                            const RunControl& control = {});

}  // namespace surfacer
