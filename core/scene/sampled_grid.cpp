// Sampled grids (core/scene/scene.h): trilinear interpolation of x-fastest samples, normalized to negative inside.
//
// Inside the grid box the value is the trilinear interpolant and the gradient its exact derivative (one-sided on
// cell faces: the cell above is used). Outside, with q the nearest point of the grid box, the value is
// interp(q) + |p - q|; its gradient is the interpolant's derivative along the axes where p is not clamped plus
// (p - q)/|p - q|.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <string>
#include <vector>

#include "core/scene/scene.h"
#include "core/util/checks.h"
#include "core/util/errors.h"

namespace surfacer {
namespace {

class SampledGrid final : public SceneField {
 public:
  SampledGrid(const SampledGridDesc& desc, std::span<const float> values)
      : origin_(desc.origin),
        spacing_(desc.spacing),
        inv_spacing_(desc.spacing.cwiseInverse()),
        dims_{desc.nx, desc.ny, desc.nz},
        sign_(desc.potential ? -1.0 : 1.0),
        iso_(desc.iso),
        values_(values.begin(), values.end()) {
    for (int i = 0; i < 3; ++i) max_corner_[i] = origin_[i] + spacing_[i] * (dims_[i] - 1);
    compute_slice_minima();
    compute_lipschitz();
  }

  double value(const Vec3& p) const override { return eval<false>(p, nullptr); }
  double value_and_gradient(const Vec3& p, Vec3& gradient) const override { return eval<true>(p, &gradient); }
  // Inside the grid each partial derivative of the trilinear interpolant is a weighted mean of its cell's edge
  // difference quotients, so |grad| <= sqrt(Dx^2 + Dy^2 + Dz^2) with D_a the largest |difference| / spacing along
  // axis a. Outside, the clamped axes contribute the unit vector (p - q)/|p - q| instead: at most sqrt(D^2 + 1).
  std::optional<double> lipschitz_bound() const override { return lipschitz_; }

 private:
  double normalized(std::int64_t index) const { return sign_ * (static_cast<double>(values_[index]) - iso_); }

  template <bool kGradient>
  double eval(const Vec3& p, Vec3* gradient) const {
    const Vec3 q = p.cwiseMax(origin_).cwiseMin(max_corner_);
    std::int64_t cell[3];
    double f[3];
    for (int i = 0; i < 3; ++i) {
      const double u = (q[i] - origin_[i]) * inv_spacing_[i];
      const std::int64_t c = std::clamp<std::int64_t>(static_cast<std::int64_t>(std::floor(u)), 0, dims_[i] - 2);
      cell[i] = c;
      // In [0, 1] also when rounding puts u a hair past the last sample: a weight of 1 + 1e-16 on a sample of 1e30
      // would move the value by 1e14.
      f[i] = std::clamp(u - static_cast<double>(c), 0.0, 1.0);
    }
    const std::int64_t sx = 1, sy = dims_[0], sz = std::int64_t{dims_[0]} * dims_[1];
    const std::int64_t base = cell[0] + sy * cell[1] + sz * cell[2];
    const double c000 = values_[base], c100 = values_[base + sx];
    const double c010 = values_[base + sy], c110 = values_[base + sx + sy];
    const double c001 = values_[base + sz], c101 = values_[base + sx + sz];
    const double c011 = values_[base + sy + sz], c111 = values_[base + sx + sy + sz];
    const double c00 = c000 + f[0] * (c100 - c000), c10 = c010 + f[0] * (c110 - c010);
    const double c01 = c001 + f[0] * (c101 - c001), c11 = c011 + f[0] * (c111 - c011);
    const double c0 = c00 + f[1] * (c10 - c00), c1 = c01 + f[1] * (c11 - c01);
    const double v = c0 + f[2] * (c1 - c0);

    const Vec3 outward = p - q;
    const double dist = outward.norm();
    if constexpr (kGradient) {
      const double gy0 = c10 - c00, gy1 = c11 - c01;
      const double dx = (1.0 - f[2]) * ((1.0 - f[1]) * (c100 - c000) + f[1] * (c110 - c010)) +
                        f[2] * ((1.0 - f[1]) * (c101 - c001) + f[1] * (c111 - c011));
      const double dy = (1.0 - f[2]) * gy0 + f[2] * gy1;
      const double dz = c1 - c0;
      Vec3 g(dx * inv_spacing_.x(), dy * inv_spacing_.y(), dz * inv_spacing_.z());
      g *= sign_;
      for (int i = 0; i < 3; ++i) {
        if (p[i] != q[i]) g[i] = 0.0;  // clamped axis: q does not move with p
      }
      if (dist > 0.0) g += outward / dist;
      *gradient = g;
    }
    return sign_ * (v - iso_) + dist;
  }

  // The smallest normalized value in each slice of samples across each axis, and on the grid's boundary.
  void compute_slice_minima() {
    const double inf = std::numeric_limits<double>::infinity();
    for (int a = 0; a < 3; ++a) slice_min_[a].assign(static_cast<std::size_t>(dims_[a]), inf);
    std::int64_t index = 0;
    for (std::int64_t k = 0; k < dims_[2]; ++k) {
      for (std::int64_t j = 0; j < dims_[1]; ++j) {
        for (std::int64_t i = 0; i < dims_[0]; ++i, ++index) {
          const double v = normalized(index);
          const std::int64_t ijk[3] = {i, j, k};
          for (int a = 0; a < 3; ++a) {
            double& m = slice_min_[a][static_cast<std::size_t>(ijk[a])];
            m = std::min(m, v);
          }
        }
      }
    }
    boundary_min_ = inf;
    for (int a = 0; a < 3; ++a) boundary_min_ = std::min({boundary_min_, slice_min_[a].front(), slice_min_[a].back()});
  }

  // Trilinear values lie between their cell's corner values, so inside the grid {value <= level} lies in cells that
  // have a corner at or below level: the box of those samples padded by one cell. Outside the grid the value is
  // interp(q) + |p - q|, so the set reaches at most level - (the smallest boundary value) beyond the boundary, near
  // boundary points whose cell holds such a sample: pad that box by as much (no clamping to the grid box then).
  // If no sample is at or below level the set is empty; the grid box stands for it. So every level has a box.
  std::optional<Aabb> sublevel_bounds(double level) const override {
    Aabb box{origin_, max_corner_};
    for (int a = 0; a < 3; ++a) {
      const std::vector<double>& m = slice_min_[a];
      const auto at_or_below = [level](double v) { return v <= level; };
      const auto first = std::find_if(m.begin(), m.end(), at_or_below);
      if (first == m.end()) return box;
      const auto last = std::find_if(m.rbegin(), m.rend(), at_or_below);
      const std::int64_t lo = first - m.begin(), hi = (m.rend() - last) - 1;
      box.min[a] = origin_[a] + spacing_[a] * static_cast<double>(std::max<std::int64_t>(lo - 1, 0));
      box.max[a] = origin_[a] + spacing_[a] * static_cast<double>(std::min<std::int64_t>(hi + 1, dims_[a] - 1));
    }
    return box.padded(std::max(0.0, level - boundary_min_));
  }
  double sublevel_limit() const override { return std::numeric_limits<double>::infinity(); }

  void compute_lipschitz() {
    const std::int64_t stride[3] = {1, dims_[0], std::int64_t{dims_[0]} * dims_[1]};
    double sum2 = 1.0;
    for (int a = 0; a < 3; ++a) {
      double worst = 0.0;
      std::int64_t index = 0;
      for (std::int64_t k = 0; k < dims_[2]; ++k) {
        for (std::int64_t j = 0; j < dims_[1]; ++j) {
          for (std::int64_t i = 0; i < dims_[0]; ++i, ++index) {
            const std::int64_t ijk[3] = {i, j, k};
            if (ijk[a] + 1 >= dims_[a]) continue;
            const double d = static_cast<double>(values_[index + stride[a]]) - static_cast<double>(values_[index]);
            worst = std::max(worst, std::abs(d));
          }
        }
      }
      const double d = worst * inv_spacing_[a];
      sum2 += d * d;
    }
    lipschitz_ = std::sqrt(sum2) * (1.0 + 1e-12);
  }

  Vec3 origin_, spacing_, inv_spacing_, max_corner_;
  std::int64_t dims_[3];
  double sign_;  // +1: signed distance (inside below iso); -1: potential (inside above iso)
  double iso_;
  std::vector<float> values_;
  std::vector<double> slice_min_[3];
  double boundary_min_ = 0.0;
  double lipschitz_ = 1.0;
};

}  // namespace

FieldPtr make_sampled_grid(const SampledGridDesc& desc, std::span<const float> values) {
  require_coordinate("origin", desc.origin);
  require_length("spacing", desc.spacing, "give the distance between samples along each axis");
  // Evaluation multiplies by 1/spacing: below ~5.6e-309 that is infinite (and 0 * inf a NaN cell index).
  constexpr double kMinSpacing = 1e-300;
  static const char* const kSpacingAxes[3] = {"spacing.x", "spacing.y", "spacing.z"};
  for (int i = 0; i < 3; ++i) {
    if (desc.spacing[i] < kMinSpacing) {
      throw InvalidInput(kSpacingAxes[i], std::string(kSpacingAxes[i]) + " (" + format_number(desc.spacing[i]) +
                                              ") is too small; give a spacing of at least 1e-300");
    }
  }
  require_coordinate("iso", desc.iso);
  const int n[3] = {desc.nx, desc.ny, desc.nz};
  const char* const names[3] = {"nx", "ny", "nz"};
  for (int i = 0; i < 3; ++i) {
    if (n[i] < 2) {
      throw InvalidInput(names[i], std::string(names[i]) + " (" + std::to_string(n[i]) +
                                       ") must be >= 2; a grid needs at least two samples per axis");
    }
  }
  // nx * ny < 2^62 fits; the third factor can wrap around 2^64 (e.g. 2^30 * 16 * 2^30 == 0), which would let a grid
  // with no values through the count check below.
  const std::uint64_t nxy = static_cast<std::uint64_t>(n[0]) * static_cast<std::uint64_t>(n[1]);
  if (nxy > std::numeric_limits<std::uint64_t>::max() / static_cast<std::uint64_t>(n[2])) {
    throw InvalidInput("nx", "nx * ny * nz (" + std::to_string(n[0]) + " * " + std::to_string(n[1]) + " * " +
                                 std::to_string(n[2]) +
                                 ") exceeds 2^64 samples; give the grid's real dimensions, "
                                 "one value per grid point");
  }
  const std::uint64_t expected = nxy * static_cast<std::uint64_t>(n[2]);
  if (values.size() != expected) {
    throw InvalidInput("values", "values has " + std::to_string(values.size()) + " numbers but nx*ny*nz = " +
                                     std::to_string(expected) + "; give one value per grid point, x fastest");
  }
  for (std::size_t i = 0; i < values.size(); ++i) {
    if (!std::isfinite(values[i])) {
      const std::string f = "values[" + std::to_string(i) + "]";
      throw InvalidInput("values", f + " is " + (std::isnan(values[i]) ? "NaN" : "infinite") +
                                       "; every grid value must be a finite number");
    }
  }
  return std::make_shared<SampledGrid>(desc, values);
}

}  // namespace surfacer
