// Red–green refinement of a triangle mesh (Bank, Sherman, Weiser 1983), the subdivision step of the mesh optimizer
// (Ohtake–Belyaev–Pasko 2002 §3.2; core/optimize/mesh_optimizer.h). Internal to core: not part of the public API.
#pragma once

#include <cstdint>
#include <limits>
#include <unordered_map>
#include <vector>

#include "core/mesh/mesh.h"
#include "core/util/run_control.h"

namespace surfacer::optimizer_detail {

// Kept across refinement rounds so green (bisected) triangles are never refined again: a green pair that must be
// refined is merged back into its parent, which is split 1-to-4 instead.
struct RedGreenHierarchy {
  std::vector<std::int32_t> green_group;  // per triangle: index into green_parents, or -1 (not a green child)
  std::vector<Triangle> green_parents;    // the triangle each green pair was bisected from
  std::unordered_map<std::uint64_t, std::uint32_t> midpoints;  // edge (sorted vertex pair) -> its midpoint vertex

  void reset(std::size_t triangles) {
    green_group.assign(triangles, -1);
    green_parents.clear();
    midpoints.clear();
  }
  // Becomes a copy of `other`, calling control.check() every 2^16 midpoints: a plain copy of a map of millions of
  // entries takes seconds that a cancel could not interrupt. Throws Cancelled (this is then partly copied).
  void assign(const RedGreenHierarchy& other, const RunControl& control);
};

// Splits every triangle with requested[t] != 0 into four at its edge midpoints (red) and closes the neighbourhood:
// a triangle with >= 2 split edges is split red too, one with exactly one split edge is bisected (green); a green
// child that would be split makes its pair merge back into the parent, split red. Repeats until conforming (no
// triangle edge carries a midpoint used across it). New vertices (edge midpoints, at the midpoint of the current
// positions) are appended to `vertices`; a conforming closed manifold mesh stays closed, manifold and oriented.
// `requested` has one entry per triangle of `triangles`.
// Each pass knows its result's size before building it: when that exceeds `max_triangles` the refinement stops
// there and returns false (the arguments are then partly refined: callers refine a copy); before building it, it has
// control.triangles' hook cover that size (reserve_triangles; `reserved`, when given, keeps what is covered across
// calls). Returns true when the conforming result fits. control.check() runs every 2^16 items of every loop and every
// 2^20 comparisons of the edge sort, so a cancel is seen within milliseconds at any size. Throws Cancelled and what
// the hook throws.
bool refine_red_green(std::vector<Vec3>& vertices, std::vector<Triangle>& triangles, RedGreenHierarchy& hierarchy,
                      const std::vector<std::uint8_t>& requested, const RunControl& control,
                      std::int64_t max_triangles = std::numeric_limits<std::int64_t>::max(),
                      std::int64_t* reserved = nullptr);

}  // namespace surfacer::optimizer_detail
