// A job's position quantization grid (docs/ALGORITHMS.md §5 "Frames"): Draco's explicit quantization reproduced bit
// for bit, so that standard Draco frames, Draco pieces and meshopt pieces put every vertex on the same lattice.
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>

#include "core/util/geometry.h"

namespace surfacer {

// Draco quantizes a float32 coordinate x on (origin, range, bits) as floor((x - origin) * ((2^bits - 1) / range) +
// 0.5), every operation in float32 (draco/core/quantization_utils.h), and dequantizes q as q * (range / (2^bits - 1))
// + origin, again in float32. One range (the box's longest side) serves all three axes.
struct QuantizationGrid {
  std::array<float, 3> origin{};
  float range = 1.0f;
  int bits = 14;  // 1..30
  // The box positions are clamped into before quantizing (as Draco frames are written); unknown to a decoder.
  Aabb box{Vec3::Constant(-1e300), Vec3::Constant(1e300)};

  // The grid of `box` (valid) with `bits` bits, as Draco's SetAttributeExplicitQuantization gets it.
  static QuantizationGrid of(const Aabb& box, int bits) {
    QuantizationGrid g;
    g.box = box;
    for (int c = 0; c < 3; ++c) g.origin[c] = static_cast<float>(box.min[c]);
    g.range = static_cast<float>(box.size().maxCoeff());
    g.bits = bits;
    return g;
  }

  std::uint32_t max_value() const { return (std::uint32_t{1} << bits) - 1u; }
  // The distance between neighbouring grid points along an axis, in scene units.
  double step() const { return static_cast<double>(range) / static_cast<double>(max_value()); }

  // Grid coordinates of p clamped into `box` (and to 0..max_value(), against float rounding at the far faces), as
  // Draco rounds them.
  std::array<std::uint32_t, 3> quantize(const Vec3& p) const {
    const float inverse_delta = static_cast<float>(max_value()) / range;
    std::array<std::uint32_t, 3> q{};
    for (int c = 0; c < 3; ++c) {
      const double clamped = std::clamp(p[c], box.min[c], box.max[c]);
      const float value = (static_cast<float>(clamped) - origin[c]) * inverse_delta;
      const float rounded = std::floor(value + 0.5f);
      q[c] = rounded <= 0.0f ? 0u : std::min(max_value(), static_cast<std::uint32_t>(rounded));
    }
    return q;
  }

  // The grid point a frame puts p on (snapped positions, docs/ALGORITHMS.md §5 "Clean on the grid"): quantize(p),
  // one step back where that point lies beyond the box's far face by more than float rounding. On an axis shorter
  // than `range` the far face need not be a grid point, and the nearest one may lie up to half a step outside;
  // snapped positions stay in the box (the encoder refuses others), and Draco, quantizing them again, finds them.
  std::array<std::uint32_t, 3> frame_point(const Vec3& p) const {
    std::array<std::uint32_t, 3> q = quantize(p);
    for (int c = 0; c < 3; ++c) {
      if (q[c] > 0u && coordinate(c, q[c]) > box.max[c] + float_slack()) --q[c];
    }
    return q;
  }

  // How far float32 rounding may put a grid point outside `box`: a few float ulps of the box's largest coordinate.
  double float_slack() const {
    const double magnitude = std::max(box.min.cwiseAbs().maxCoeff(), box.max.cwiseAbs().maxCoeff());
    return 4.0 * static_cast<double>(std::numeric_limits<float>::epsilon()) * magnitude;
  }

  // Coordinate c of grid point q as Draco's decoder gives it (float32).
  double coordinate(int c, std::uint32_t q) const {
    const float delta = range / static_cast<float>(max_value());
    return static_cast<float>(static_cast<float>(q) * delta + origin[c]);
  }

  // The position Draco's decoder gives grid point q (float32 values).
  Vec3 dequantize(const std::array<std::uint32_t, 3>& q) const {
    return Vec3(coordinate(0, q[0]), coordinate(1, q[1]), coordinate(2, q[2]));
  }
};

// Whether grid points a, b, c are collinear (or repeat a point), exactly: coordinates below 2^30, so the cross product
// fits in 64 bits. Such a triangle has zero area once decoded.
inline bool collinear_on_grid(const std::array<std::uint32_t, 3>& a, const std::array<std::uint32_t, 3>& b,
                              const std::array<std::uint32_t, 3>& c) {
  std::array<std::int64_t, 3> u, v;
  for (int k = 0; k < 3; ++k) {
    u[k] = static_cast<std::int64_t>(b[k]) - static_cast<std::int64_t>(a[k]);
    v[k] = static_cast<std::int64_t>(c[k]) - static_cast<std::int64_t>(a[k]);
  }
  return u[1] * v[2] == u[2] * v[1] && u[2] * v[0] == u[0] * v[2] && u[0] * v[1] == u[1] * v[0];
}

}  // namespace surfacer
