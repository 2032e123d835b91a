// Uniform grid over a static point set for nearest-point and radius queries (Williams 2008 §3.4.1 uses "a simple
// sparse spatial hash on particle locations"; docs/ALGORITHMS.md §1).
//
// Points are copied in cell order (counting sort by cell, stable by input index), so points that are near in space are
// near in memory and a query touches a few short contiguous ranges. Cells are addressed either
//   * densely: a start offset per cell of the points' bounding box, used while the box holds at most 8 cells per point
//     (+ 4096), so a row of cells along x is one contiguous range. The offsets are stored compactly: one uint32 per
//     group of 32 cells and one byte per cell counting from it (about 1.1 bytes per cell), or one uint32 per cell
//     when some group holds more than 255 points; or
//   * sparsely: an open-addressing hash table of occupied cells only, for scattered data (spray, a few points far from
//     the rest) where a dense box would waste memory. Memory is then O(points), whatever the extent.
// Queries are const and thread-safe. Coordinates must be finite.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <optional>
#include <span>
#include <type_traits>
#include <vector>

#include "core/mesh/mesh.h"
#include "core/util/run_control.h"

namespace surfacer {

class SpatialHash {
 public:
  struct Neighbor {
    std::uint32_t index = 0;  // index into the span given to build()
    double distance = 0.0;
  };

  SpatialHash() = default;
  // See build().
  SpatialHash(std::span<const Vec3> points, double cell_size) { build(points, cell_size); }

  // (Re)builds over `points` (copied; the span need not outlive the hash) with cubic cells of edge `cell_size`.
  // A cell size near the typical query radius is best. O(points) time (plus O(cells) in dense mode).
  // Throws InvalidInput("cell_size") unless cell_size is finite and > 0, InvalidInput("points") for a non-finite
  // coordinate or more than 2^32 - 1 points, ResourceLimit("cell_size") when the extent exceeds 2^30 cells per axis.
  void build(std::span<const Vec3> points, double cell_size);

  std::size_t size() const { return points_.size(); }
  bool empty() const { return points_.empty(); }
  double cell_size() const { return cell_; }
  bool dense() const { return dense_; }
  std::size_t occupied_cells() const { return occupied_cells_; }
  // Bytes held by the structure (points, order, cell directory).
  std::size_t memory_bytes() const;

  // The nearest point with distance <= max_distance (exact; ties go to the first in cell order), or nullopt. The
  // search first looks within `first_radius` (0: one cell), then doubles its radius up to max_distance: a caller that
  // knows about how far its nearest point lies skips the rounds below that. With max_distance = infinity the search
  // widens until it is exact.
  std::optional<Neighbor> nearest(const Vec3& q, double max_distance = std::numeric_limits<double>::infinity(),
                                  double first_radius = 0.0) const;

  // Distance to the nearest point, bounded for speed: exact when it lies in [stop_below, max_distance]; when some
  // point is closer than stop_below the search may stop there and return that (larger-than-exact but < stop_below)
  // distance; when no point lies within max_distance returns +infinity.
  double bounded_distance(const Vec3& q, double max_distance, double stop_below) const;

  // Whether some point lies strictly closer than `radius` to q (stops at the first one found: the cell holding q
  // first, then the box of the ball).
  bool any_within(const Vec3& q, double radius) const;

  // Whether two of the points lie within `distance` (>= 0) of each other; stops at the first such pair. About one
  // cell's points per point when `distance` is below the cell size. control.check() every 64 points.
  bool any_pair_within(double distance, const RunControl& control = {}) const;

  // Appends the input indices of all points with |p - q| <= radius (in cell order) to `out`.
  void within(const Vec3& q, double radius, std::vector<std::uint32_t>& out) const;

  // Calls fn(index, point, distance_squared) for every point with |p - q| <= radius.
  template <class Fn>
  void for_each_within(const Vec3& q, double radius, Fn&& fn) const {
    const double r2 = radius * radius;
    for_each_range(q.array() - radius, q.array() + radius, [&](std::uint32_t begin, std::uint32_t end) {
      for (std::uint32_t s = begin; s < end; ++s) {
        const double d2 = (points_[s] - q).squaredNorm();
        if (d2 <= r2) fn(order_[s], points_[s], d2);
      }
    });
  }

  // Calls fn(begin, end) for ranges [begin, end) of cell-ordered slots that together hold every point of the cells
  // overlapping the box [lo, hi] (and possibly a few more). Slot s holds sorted_points()[s], input index order()[s].
  // When fn returns bool, returning false stops the walk (and for_each_range returns false).
  template <class Fn>
  bool for_each_range(const Eigen::Array3d& lo, const Eigen::Array3d& hi, Fn&& fn) const {
    auto call = [&](std::uint32_t begin, std::uint32_t end) -> bool {
      if constexpr (std::is_same_v<decltype(fn(begin, end)), bool>) {
        return fn(begin, end);
      } else {
        fn(begin, end);
        return true;
      }
    };
    const std::optional<CellBox> box = cell_box(lo, hi);
    if (!box) return true;
    const int* c0 = box->lo;
    const int* c1 = box->hi;
    if (dense_) {
      for (int k = c0[2]; k <= c1[2]; ++k) {
        for (int j = c0[1]; j <= c1[1]; ++j) {
          const std::size_t row = (static_cast<std::size_t>(k) * dims_[1] + j) * dims_[0];
          const std::uint32_t begin = cell_start(row + c0[0]);
          const std::uint32_t end = cell_start(row + c1[0] + 1);
          if (begin < end && !call(begin, end)) return false;
        }
      }
    } else if (static_cast<double>(c1[0] - c0[0] + 1) * (c1[1] - c0[1] + 1) * (c1[2] - c0[2] + 1) >
               static_cast<double>(cells_.size())) {
      // A box larger than the occupied set: walk the occupied cells instead of the box.
      for (const Cell& cell : cells_) {
        if (cell.i >= c0[0] && cell.i <= c1[0] && cell.j >= c0[1] && cell.j <= c1[1] && cell.k >= c0[2] &&
            cell.k <= c1[2]) {
          if (!call(cell.begin, cell.end)) return false;
        }
      }
    } else {
      for (int k = c0[2]; k <= c1[2]; ++k) {
        for (int j = c0[1]; j <= c1[1]; ++j) {
          for (int i = c0[0]; i <= c1[0]; ++i) {
            const Cell* cell = find(i, j, k);
            if (cell != nullptr && !call(cell->begin, cell->end)) return false;
          }
        }
      }
    }
    return true;
  }

  // The cells for_each_range(lo, hi) visits, as inclusive ranges of cell coordinates per axis; nullopt when the box
  // misses the grid (or is NaN).
  struct CellBox {
    int lo[3], hi[3];
  };
  // Inlined into every query (for_each_range is their inner loop).
  [[gnu::always_inline]] std::optional<CellBox> cell_box(const Eigen::Array3d& lo, const Eigen::Array3d& hi) const {
    if (points_.empty()) return std::nullopt;
    CellBox box;
    for (int a = 0; a < 3; ++a) {
      // In cells from the origin; the floor of l and h is taken by truncation where they are >= 0, the only place an
      // integer is taken of them (the comparisons with 0 and dims give the same answers for l, h and their floors).
      const double l = (lo[a] - origin_[a]) * inv_cell_;
      const double h = (hi[a] - origin_[a]) * inv_cell_;
      if (!(h >= 0.0) || !(l < static_cast<double>(dims_[a]))) return std::nullopt;  // also rejects NaN
      box.lo[a] = l < 0.0 ? 0 : static_cast<int>(l);
      box.hi[a] = h >= static_cast<double>(dims_[a]) ? dims_[a] - 1 : static_cast<int>(h);
    }
    return box;
  }
  // Whether sorted_points()[slot] lies in one of the cells of `box`: whether for_each_range over the box that made it
  // visits that slot.
  bool in_cells(const CellBox& box, std::uint32_t slot) const {
    for (int a = 0; a < 3; ++a) {
      const int c = cell_coordinate(points_[slot][a], a);
      if (c < box.lo[a] || c > box.hi[a]) return false;
    }
    return true;
  }
  // Whether for_each_range(lo, hi) visits a slot, for the slots of a wider walk: a point inside the box is visited;
  // one outside it only when its cell is one of the box's (where rounding puts it at the box's faces), the cells being
  // worked out at the first such point.
  class RangeVisits {
   public:
    RangeVisits(const SpatialHash& hash, const Eigen::Array3d& lo, const Eigen::Array3d& hi)
        : hash_(hash), lo_(lo), hi_(hi) {}
    bool operator()(std::uint32_t slot) {
      const Vec3& p = hash_.points_[slot];
      if ((p.array() >= lo_).all() && (p.array() <= hi_).all()) return true;
      if (cells_state_ == kUnknown) {
        const std::optional<CellBox> box = hash_.cell_box(lo_, hi_);
        cells_state_ = box ? kKnown : kNone;
        if (box) cells_ = *box;
      }
      return cells_state_ == kKnown && hash_.in_cells(cells_, slot);
    }

   private:
    const SpatialHash& hash_;
    Eigen::Array3d lo_, hi_;
    enum { kUnknown, kKnown, kNone } cells_state_ = kUnknown;  // kNone: the box misses the grid
    CellBox cells_{};
  };

  std::span<const Vec3> sorted_points() const { return points_; }
  std::span<const std::uint32_t> order() const { return order_; }

 private:
  struct Cell {
    std::int32_t i = 0, j = 0, k = 0;
    std::uint32_t begin = 0, end = 0;
  };
  static constexpr std::uint32_t kEmpty = 0xFFFFFFFFu;
  static constexpr int kGroupBits = 5;  // cells per group of the compact dense offsets: 32
  // Dense: the slot of the first point of linear cell c (c up to the cell count: the end).
  std::uint32_t cell_start(std::size_t c) const {
    return wide_start_.empty() ? group_start_[c >> kGroupBits] + cell_offset_[c] : wide_start_[c];
  }
  // The cell coordinate along `axis` of a point of the grid, clamped: the top face of the box rounds into the last
  // cell.
  int cell_coordinate(double v, int axis) const {
    return std::clamp(static_cast<int>((v - origin_[axis]) * inv_cell_), 0, dims_[axis] - 1);
  }
  static std::uint64_t hash(std::int32_t i, std::int32_t j, std::int32_t k) {
    std::uint64_t h = static_cast<std::uint32_t>(i) * 0x9E3779B185EBCA87ull;
    h ^= static_cast<std::uint32_t>(j) * 0xC2B2AE3D27D4EB4Full;
    h ^= static_cast<std::uint32_t>(k) * 0x165667B19E3779F9ull;
    return h ^ (h >> 29);
  }
  const Cell* find(int i, int j, int k) const {
    std::uint64_t s = hash(i, j, k) & mask_;
    while (true) {
      const std::uint32_t c = table_[s];
      if (c == kEmpty) return nullptr;
      const Cell& cell = cells_[c];
      if (cell.i == i && cell.j == j && cell.k == k) return &cell;
      s = (s + 1) & mask_;
    }
  }

  std::vector<Vec3> points_;          // cell order
  std::vector<std::uint32_t> order_;  // slot -> input index
  Vec3 origin_ = Vec3::Zero();
  double cell_ = 0.0, inv_cell_ = 0.0;
  int dims_[3] = {0, 0, 0};
  bool dense_ = true;
  std::size_t occupied_cells_ = 0;
  // Dense: per group of cells, its first slot, and per cell (dims product + 1) its first slot less its group's; or,
  // when a group holds more than 255 points, every cell's first slot in wide_start_ (the other two empty).
  std::vector<std::uint32_t> group_start_;
  std::vector<std::uint8_t> cell_offset_;
  std::vector<std::uint32_t> wide_start_;
  std::vector<Cell> cells_;           // sparse: occupied cells in cell order
  std::vector<std::uint32_t> table_;  // sparse: power-of-two open-addressing table of indices into cells_
  std::uint64_t mask_ = 0;
};

// Points closer than `tolerance` (>= 0, scene units) grouped greedily in input order: each point joins the first
// earlier kept point within `tolerance` of it (distance <= tolerance), or is kept itself. Kept points are pairwise
// farther apart than `tolerance`, so each lookup visits a bounded number of them: O(points) expected time whatever
// the points' multiplicity (a hash map of cells of edge `tolerance`, or coarser where coordinates are too large for
// such cells). control.check() every 4096 points. Coordinates must be finite.
struct CoincidentGroups {
  std::vector<std::uint32_t> kept;   // indices of the kept points, ascending
  std::vector<std::uint32_t> group;  // per point, the position in `kept` of the point it joined (its own when kept)
};
CoincidentGroups group_coincident(std::span<const Vec3> points, double tolerance, const RunControl& control = {});

}  // namespace surfacer
