// Where the active surface's potential grid lies (core/active/active_surface.h): its spacing h, the position of
// node (0, 0, 0), the half-width of the potential's ramp, and the optional domain box with its wall. Internal to
// core/active; fixed once the run's options are validated.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <optional>

#include "core/active/sparse_grid.h"
#include "core/util/geometry.h"

namespace surfacer::active_detail {

class GridFrame {
 public:
  GridFrame() = default;
  // Spacing h > 0 and ramp half-width `band_width` (units of h), both validated by the caller. With a domain, node
  // (0, 0, 0) is at domain->min and the last node per axis is the last one inside domain->max; without one the grid
  // is unbounded and node (0, 0, 0) is at the coordinate origin.
  GridFrame(double h, double band_width, const std::optional<Aabb>& domain);

  double spacing() const { return spacing_; }
  double inv_spacing() const { return inv_spacing_; }
  // The ramp's half-width w (units of h): f = clamp(-d / (w h), -1, 1).
  double band_width() const { return ramp_; }
  const Vec3& origin() const { return origin_; }
  bool has_domain() const { return has_domain_; }
  // Index of the last node inside the domain along `axis` (the first is 0); 0 without a domain.
  std::int64_t last_node(int axis) const { return last_node_[axis]; }

  Vec3 node_position(const sparse::BlockCoord& b, int x, int y, int z) const {
    return origin_ + spacing_ * Vec3(double(sparse::kBlockSize) * b[0] + x, double(sparse::kBlockSize) * b[1] + y,
                                     double(sparse::kBlockSize) * b[2] + z);
  }
  bool node_in_domain(const sparse::BlockCoord& b, int x, int y, int z) const {
    if (!has_domain_) return true;
    const std::int64_t g[3] = {std::int64_t{sparse::kBlockSize} * b[0] + x, std::int64_t{sparse::kBlockSize} * b[1] + y,
                               std::int64_t{sparse::kBlockSize} * b[2] + z};
    for (int a = 0; a < 3; ++a) {
      if (g[a] < 0 || g[a] > last_node_[a]) return false;
    }
    return true;
  }

  // Blocks beyond the domain's last node holding the wall's outer ramp.
  int wall_blocks() const { return static_cast<int>(std::ceil((ramp_ + 1.0) / sparse::kBlockSize)); }
  // Whether block n lies within the domain's blocks and its wall blocks; always true without a domain.
  bool block_in_reach(const sparse::BlockCoord& n) const {
    if (!has_domain_) return true;
    for (int a = 0; a < 3; ++a) {
      if (n[a] < -wall_blocks() || n[a] > last_node_[a] / sparse::kBlockSize + wall_blocks()) return false;
    }
    return true;
  }
  // The domain wall as a potential: clamp(-d_wall / (ramp h)) with d_wall the signed distance (grid units) to the box
  // of nodes inside the domain grown by half a cell; +1 without a domain. The potential is min(f, wall) everywhere,
  // so the solid is cut off at the box with a regular ramp (not a jump, which reinitialization would erode).
  float wall_potential(const sparse::BlockCoord& b, int x, int y, int z) const {
    if (!has_domain_) return 1.0f;
    const std::int64_t g[3] = {std::int64_t{sparse::kBlockSize} * b[0] + x, std::int64_t{sparse::kBlockSize} * b[1] + y,
                               std::int64_t{sparse::kBlockSize} * b[2] + z};
    double out2 = 0.0, inside = -1e300;
    for (int a = 0; a < 3; ++a) {
      const double q = std::max(-0.5 - static_cast<double>(g[a]), static_cast<double>(g[a] - last_node_[a]) - 0.5);
      if (q > 0.0) out2 += q * q;
      inside = std::max(inside, q);
    }
    const double d = out2 > 0.0 ? std::sqrt(out2) : inside;
    return static_cast<float>(std::clamp(-d / ramp_, -1.0, 1.0));
  }
  // Whether block b holds nodes whose wall potential is below 1.
  bool near_wall(const sparse::BlockCoord& b) const {
    if (!has_domain_) return false;
    const double reach = ramp_ + 1.0;
    for (int a = 0; a < 3; ++a) {
      const double first = double(sparse::kBlockSize) * b[a], last = first + sparse::kBlockMask;
      if (first - reach < 0.0 || last + reach > static_cast<double>(last_node_[a])) return true;
    }
    return false;
  }

 private:
  double spacing_ = 0.0, inv_spacing_ = 0.0;
  double ramp_ = 3.0;
  Vec3 origin_ = Vec3::Zero();
  bool has_domain_ = false;
  std::int64_t last_node_[3] = {0, 0, 0};
};

inline GridFrame::GridFrame(double h, double band_width, const std::optional<Aabb>& domain)
    : spacing_(h), inv_spacing_(1.0 / h), ramp_(band_width), has_domain_(domain.has_value()) {
  if (!domain) return;
  origin_ = domain->min;
  for (int a = 0; a < 3; ++a) {
    last_node_[a] = static_cast<std::int64_t>(std::floor((domain->max[a] - domain->min[a]) / h + 1e-9));
  }
}

}  // namespace surfacer::active_detail
