// Sliver repair: edge flips and edge collapses that remove triangles with a tiny angle, and triangles that become
// degenerate once their vertices are snapped to an output quantization grid, while the mesh stays closed, manifold
// and oriented and no vertex's valence drops below a floor it was at or above.
#pragma once

#include <cstdint>
#include <optional>

#include "core/mesh/mesh.h"
#include "core/mesh/quantization.h"
#include "core/util/run_control.h"

namespace surfacer {

struct SliverOptions {
  double min_angle_degrees = 1.0;  // a triangle with a smaller angle is repaired; in [0, 30)
  // When set, a triangle whose corners, quantized on the grid, are collinear (or repeat a point) is repaired too: the
  // decoder would give it zero area.
  std::optional<QuantizationGrid> grid;
  // A repair may not take a vertex whose valence is at least this below it (Marching Tiles meshes start at 5).
  int min_valence = 5;
  int max_passes = 8;
  int threads = 0;  // for the first scan; 0: hardware threads
};

struct SliverReport {
  std::int64_t candidates = 0;  // bad triangles found by the first pass
  std::int64_t flips = 0;
  std::int64_t collapses = 0;
  std::int64_t remaining = 0;  // bad triangles no allowed repair removed
};

// Passes over the bad triangles until none is left or a pass repairs nothing (at most max_passes):
// * a triangle whose largest angle is at least 90 degrees (a cap: a vertex near the opposite edge) has that edge
//   flipped with the triangle across it, when the new edge does not exist yet, the two new triangles are better (their
//   smallest angle exceeds the old pair's, neither is degenerate on the grid) and turn the same way as the old pair;
// * otherwise (a needle: a very short edge) the shortest edge is collapsed onto one of its ends (positions never
//   move, so a vertex that was faithful to its data stays so), when the two ends share exactly the two opposite
//   vertices (the link condition: the mesh stays manifold), no triangle around them turns over or gets worse than the
//   needle, and the valence floor holds.
// Collapsed vertices are removed (the others keep their order); normals, when present, follow their vertices.
// Only edges with exactly two triangles are touched. Cost: one parallel-free scan of the triangles when nothing is
// bad; adjacency is built only when something is. control.check() once per pass.
SliverReport repair_slivers(Mesh& mesh, const SliverOptions& options, const RunControl& control = {});

// The smallest angle of triangle (a, b, c) in degrees (0 for a degenerate one).
double min_angle_degrees(const Vec3& a, const Vec3& b, const Vec3& c);

}  // namespace surfacer
