// Connectivity repair for the mesh optimizer (core/optimize/mesh_optimizer.h, option `repair_connectivity`): cap flips,
// normal-improving flips and needle collapses. Internal to core.
#pragma once

#include <cstdint>
#include <vector>

#include "core/mesh/mesh.h"
#include "core/mesh/mesh_edit.h"
#include "core/optimize/refine.h"
#include "core/util/run_control.h"

namespace surfacer {
class Field;
}

namespace surfacer::optimizer_detail {

struct CleanupOptions {
  double cap_angle_degrees = 170.0;  // a triangle whose largest angle exceeds this is a cap
  double needle_ratio = 0.02;        // an edge shorter than this times both other edges of its triangle: a needle
  double flip_deviation = 0.1;       // |n - m|² above this (about 18 degrees): try a normal-improving flip
  double min_cos = 0.02;             // changed triangles need n·m(C) >= min(min_cos, their score before)
  double degenerate_cross = 0.0;     // |(b-a)x(c-a)| at or below this: degenerate (never produced)
  int max_passes = 8;
};

struct CleanupCounts {
  std::int64_t flips = 0;
  std::int64_t collapses = 0;
};

// Passes over the candidate triangles (caps, needles, deviating triangles; in index order) and those changed by the
// previous pass, until a pass changes nothing (at most max_passes):
// * Cap (u, v, x) with its largest angle at x: flip (u, v) with the triangle (v, u, y) across it into (u, y, x),
//   (y, v, x) when x != y, the edge (x, y) does not exist and has no registered midpoint, both new triangles are
//   non-degenerate and face along the field (n·m(C) >= min_cos), and the pair's largest angle drops.
// * Triangle T with |n_T - m(C_T)|² > flip_deviation: flip the edge of T that lowers A|n - m|² summed over the
//   pair the most, by at least 1 %, when the new edge does not exist and has no midpoint record and the new
//   triangles face along the field and are no caps (connectivity the vertex flows cannot fix: near corners a
//   triangle can span two faces whatever its vertices do).
// * Needle (a, b, c) with |ab| < needle_ratio · min(|ac|, |bc|): collapse (a, b) into a, placed at the midpoint or
//   else at a or b (the first that works), when (a, b) has two triangles, a and b share exactly the two opposite
//   vertices (link condition: the mesh stays manifold), every changed triangle stays non-degenerate and its score
//   n·m(C) does not fall below min(min_cos, its score before), no new edge has a registered midpoint, and a and b
//   are not both on the boundary. The collapsed vertex b stays in `positions`, unreferenced; midpoint records that
//   name it are dropped.
// Only edges with at most two triangles are touched. A green pair with a changed child is dissolved (its children
// become plain triangles). Orientation, closedness and manifoldness are kept.
// `field_normals` holds m(C_T) for every triangle on entry and is kept in step (same order, recomputed where changed).
// `adjacency`: the vertex -> triangle adjacency of `triangles` on entry (over positions.size() vertices). The edits go
// through MeshEditor (core/mesh/mesh_edit.h): a vertex at a non-manifold edge is left alone. Calls control.check() once
// per pass.
CleanupCounts repair_connectivity(std::vector<Vec3>& positions, std::vector<Triangle>& triangles,
                                  RedGreenHierarchy& hierarchy, std::vector<Vec3>& field_normals,
                                  const VertexTriangles& adjacency, const Field& field, const CleanupOptions& options,
                                  const RunControl& control);

}  // namespace surfacer::optimizer_detail
