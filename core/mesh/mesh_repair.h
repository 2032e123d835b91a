// Sliver repair: edge flips and edge collapses that remove triangles with a tiny angle, and triangles that become
// degenerate once their vertices are snapped to an output quantization grid, while the mesh stays closed, manifold
// and oriented and no vertex's valence drops below a floor it was at or above.
#pragma once

#include <cstdint>
#include <functional>
#include <optional>

#include "core/mesh/mesh.h"
#include "core/mesh/quantization.h"
#include "core/util/run_control.h"

namespace surfacer {

struct SliverOptions {
  double min_angle_degrees = 1.0;  // a triangle with a smaller angle is repaired; in [0, 30]
  // When set, angles are those of the triangles' corners quantized on the grid, as a decoder of the frame gives them
  // (quantization moves each corner by up to half a step, which turns a triangle a few steps across), and a triangle
  // whose corners there are collinear (or repeat a point) is repaired too: the decoder would give it zero area.
  std::optional<QuantizationGrid> grid{};
  // A repair may not take a vertex whose valence is at least this below it (Marching Tiles meshes start at 5).
  int min_valence = 5;
  int max_passes = 8;
  int threads = 0;  // for the first scan; 0: hardware threads
  // When set, a bad triangle that no flip or collapse repairs may be repaired by moving one of its vertices: the
  // proposal is the centroid of the vertex's neighbours in its tangent plane, and place(v, p, n) moves p to where
  // vertex v may lie (its data's constraints; n: v's unit area-weighted normal), or returns false to refuse. Unset:
  // positions never move.
  std::function<bool(std::uint32_t vertex, Vec3& position, const Vec3& normal)> place{};
};

struct SliverReport {
  std::int64_t candidates = 0;  // bad triangles found by the first pass
  std::int64_t flips = 0;
  std::int64_t collapses = 0;
  std::int64_t moves = 0;      // vertices moved (SliverOptions::place)
  std::int64_t remaining = 0;  // bad triangles no allowed repair removed
};

// Passes over the bad triangles, worst first, until none is left or a pass repairs nothing (at most max_passes). For a
// bad triangle, every move is weighed: the flip of each of its edges (with the triangle across it), and the collapse of
// each edge onto either end. A move is valid when the mesh stays manifold (a flip's new edge does not exist yet; a
// collapse's two ends share exactly the two opposite vertices, the link condition), no triangle turns over (a flip's
// quad is convex seen along its normal), and the valence floor holds; it is taken when the worst of the triangles it
// makes is better than the worst of those it replaces (a triangle degenerate on the grid counts worst of all). The
// moves that leave no bad triangle come first, flips before collapses, then the others by quality. A move blocked
// only by the valence floor is tried after a flip elsewhere gives the blocking vertex a neighbour more (two levels
// deep; those flips are undone when the move still cannot be made). When no flip or collapse is left and `place` is
// set, a vertex of the triangle moves instead (in a valence-5 cluster, where every flip and collapse would take a
// vertex below the floor): toward the centroid of its neighbours in its tangent plane, through place(), taken when
// none of its triangles turns over and the worst of them gets better; the best of its three vertices moves. Without
// `place` positions never move, so a vertex faithful to its data stays so; collapsed vertices are removed (the
// others keep their order) and normals, when present, follow their vertices (a moved vertex keeps its normal). Only
// edges with exactly two triangles are touched, and no vertex at a non-manifold edge. The flips and collapses go
// through MeshEditor (core/mesh/mesh_edit.h). Cost: one parallel scan of the triangles when nothing is bad; the
// adjacency is built at the first bad triangle. control.check() once per pass.
SliverReport repair_slivers(Mesh& mesh, const SliverOptions& options, const RunControl& control = {});

// The smallest angle of triangle (a, b, c) in degrees (0 for a degenerate one).
double min_angle_degrees(const Vec3& a, const Vec3& b, const Vec3& c);

}  // namespace surfacer
