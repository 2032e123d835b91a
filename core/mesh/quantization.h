// A job's position quantization grid (docs/ALGORITHMS.md §5 "Frames"): Draco's explicit quantization reproduced bit
// for bit, so that standard Draco frames, Draco pieces and meshopt pieces put every vertex on the same lattice.
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>

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

  // Grid coordinates of p clamped into `box` (and to 0..max_value(), against float rounding at the far faces).
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

  // The position Draco's decoder gives grid point q (float32 values).
  Vec3 dequantize(const std::array<std::uint32_t, 3>& q) const {
    const float delta = range / static_cast<float>(max_value());
    Vec3 p;
    for (int c = 0; c < 3; ++c) p[c] = static_cast<float>(static_cast<float>(q[c]) * delta + origin[c]);
    return p;
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
