// The interpolation margin of both polygonizers (the options' vertex_margin; docs/ALGORITHMS.md §5 "Clean on the
// grid").
#pragma once

#include <algorithm>
#include <cmath>

#include "core/util/errors.h"
#include "core/util/format.h"

namespace surfacer {

// The smallest interpolation parameter a vertex on an edge of `edge_length` may take for a margin (scene units,
// >= 0): margin / edge_length, at most a quarter; the parameter t is then clamped to [floor, 1 - floor].
inline double edge_parameter_floor(double margin, double edge_length) {
  constexpr double kMaxFraction = 0.25;
  return margin > 0.0 && edge_length > 0.0 ? std::min(kMaxFraction, margin / edge_length) : 0.0;
}

// Throws InvalidInput("vertex_margin") unless the margin is a finite length >= 0.
inline void check_vertex_margin(double margin) {
  if (!std::isfinite(margin) || margin < 0.0) {
    throw InvalidInput("vertex_margin",
                       "vertex_margin (" + format_number(margin) + ") must be a finite length >= 0; 0 turns it off");
  }
}

}  // namespace surfacer
