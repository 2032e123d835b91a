#include "core/particles/spatial_hash.h"

#include <algorithm>
#include <bit>
#include <numeric>
#include <string>
#include <unordered_map>

#include "core/util/errors.h"

namespace surfacer {

void SpatialHash::build(std::span<const Vec3> points, double cell_size) {
  if (!(cell_size > 0.0) || !std::isfinite(cell_size)) {
    throw InvalidInput("cell_size", "cell_size (" + std::to_string(cell_size) + ") must be finite and > 0");
  }
  if (points.size() >= kEmpty) {
    throw InvalidInput("points", "at most 2^32 - 2 points are supported, got " + std::to_string(points.size()));
  }
  points_.clear();
  order_.clear();
  group_start_.clear();
  cell_offset_.clear();
  wide_start_.clear();
  cells_.clear();
  table_.clear();
  occupied_cells_ = 0;
  dense_ = true;
  cell_ = cell_size;
  inv_cell_ = 1.0 / cell_size;
  dims_[0] = dims_[1] = dims_[2] = 0;
  origin_ = Vec3::Zero();
  if (points.empty()) return;

  Eigen::Array3d lo = points[0].array(), hi = points[0].array();
  for (std::size_t i = 0; i < points.size(); ++i) {
    const Vec3& p = points[i];
    if (!p.allFinite()) {
      throw InvalidInput("points", "point " + std::to_string(i) + " has a non-finite coordinate; remove it");
    }
    lo = lo.min(p.array());
    hi = hi.max(p.array());
  }
  origin_ = lo.matrix();
  double total = 1.0;
  for (int a = 0; a < 3; ++a) {
    const double cells = std::floor((hi[a] - lo[a]) * inv_cell_) + 1.0;
    if (cells > static_cast<double>(1 << 30)) {
      throw ResourceLimit("cell_size", "the points span " + std::to_string(cells) + " cells of size " +
                                           std::to_string(cell_size) + " along one axis (max 2^30); use larger cells");
    }
    dims_[a] = static_cast<int>(cells);
    total *= cells;
  }
  auto cell_of = [&](const Vec3& p, int c[3]) {
    for (int a = 0; a < 3; ++a) c[a] = cell_coordinate(p[a], a);
  };

  const std::size_t n = points.size();
  points_.resize(n);
  order_.resize(n);
  dense_ = total <= 8.0 * static_cast<double>(n) + 4096.0;
  if (dense_) {
    // Counting sort by linear cell index (x fastest), stable in input order.
    const std::size_t cells = static_cast<std::size_t>(total);
    std::vector<std::uint32_t> cell_of_point(n);
    std::vector<std::uint32_t> cell_start(cells + 1, 0);
    for (std::size_t i = 0; i < n; ++i) {
      int c[3];
      cell_of(points[i], c);
      const std::size_t id = (static_cast<std::size_t>(c[2]) * dims_[1] + c[1]) * dims_[0] + c[0];
      cell_of_point[i] = static_cast<std::uint32_t>(id);
      ++cell_start[id + 1];
    }
    for (std::size_t c = 0; c < cells; ++c) {
      occupied_cells_ += cell_start[c + 1] != 0;
      cell_start[c + 1] += cell_start[c];
    }
    {
      std::vector<std::uint32_t> fill(cell_start.begin(), cell_start.end() - 1);
      for (std::size_t i = 0; i < n; ++i) {
        const std::uint32_t s = fill[cell_of_point[i]]++;
        points_[s] = points[i];
        order_[s] = static_cast<std::uint32_t>(i);
      }
    }
    // The compact offsets when every group's points fit a byte.
    const std::size_t groups = (cells >> kGroupBits) + 1;  // the end offset (index `cells`) has a group too
    bool narrow = true;
    for (std::size_t g = 0; g < groups && narrow; ++g) {
      const std::size_t last = std::min(cells, ((g + 1) << kGroupBits) - 1);
      narrow = cell_start[last] - cell_start[g << kGroupBits] <= 0xFFu;
    }
    if (!narrow) {
      wide_start_ = std::move(cell_start);
      return;
    }
    group_start_.resize(groups);
    cell_offset_.resize(cells + 1);
    for (std::size_t g = 0; g < groups; ++g) group_start_[g] = cell_start[g << kGroupBits];
    for (std::size_t c = 0; c <= cells; ++c) {
      cell_offset_[c] = static_cast<std::uint8_t>(cell_start[c] - group_start_[c >> kGroupBits]);
    }
    return;
  }

  // Sparse: sort by (k, j, i, input index), then one Cell per run and a hash table over the runs.
  struct Keyed {
    std::int32_t k, j, i;
    std::uint32_t index;
  };
  std::vector<Keyed> keyed(n);
  for (std::size_t i = 0; i < n; ++i) {
    int c[3];
    cell_of(points[i], c);
    keyed[i] = {c[2], c[1], c[0], static_cast<std::uint32_t>(i)};
  }
  std::sort(keyed.begin(), keyed.end(), [](const Keyed& a, const Keyed& b) {
    if (a.k != b.k) return a.k < b.k;
    if (a.j != b.j) return a.j < b.j;
    if (a.i != b.i) return a.i < b.i;
    return a.index < b.index;
  });
  for (std::size_t s = 0; s < n; ++s) {
    const Keyed& e = keyed[s];
    points_[s] = points[e.index];
    order_[s] = e.index;
    if (s == 0 || e.i != keyed[s - 1].i || e.j != keyed[s - 1].j || e.k != keyed[s - 1].k) {
      cells_.push_back({e.i, e.j, e.k, static_cast<std::uint32_t>(s), static_cast<std::uint32_t>(s)});
    }
    cells_.back().end = static_cast<std::uint32_t>(s + 1);
  }
  occupied_cells_ = cells_.size();
  const std::size_t capacity = std::bit_ceil(std::max<std::size_t>(16, 2 * cells_.size()));
  table_.assign(capacity, kEmpty);
  mask_ = capacity - 1;
  for (std::size_t c = 0; c < cells_.size(); ++c) {
    std::uint64_t s = hash(cells_[c].i, cells_[c].j, cells_[c].k) & mask_;
    while (table_[s] != kEmpty) s = (s + 1) & mask_;
    table_[s] = static_cast<std::uint32_t>(c);
  }
}

std::size_t SpatialHash::memory_bytes() const {
  return points_.capacity() * sizeof(Vec3) + order_.capacity() * sizeof(std::uint32_t) +
         group_start_.capacity() * sizeof(std::uint32_t) + cell_offset_.capacity() +
         wide_start_.capacity() * sizeof(std::uint32_t) + cells_.capacity() * sizeof(Cell) +
         table_.capacity() * sizeof(std::uint32_t);
}

std::optional<SpatialHash::Neighbor> SpatialHash::nearest(const Vec3& q, double max_distance,
                                                          double first_radius) const {
  if (points_.empty() || !(max_distance >= 0.0)) return std::nullopt;
  // Radius beyond which every point is inside the search box: the distance to the farthest corner of the grid.
  const Eigen::Array3d far =
      (q.array() - origin_.array())
          .abs()
          .max((q.array() - origin_.array() - Eigen::Array3d(dims_[0], dims_[1], dims_[2]) * cell_).abs());
  const double all = far.matrix().norm() * (1.0 + 1e-12) + cell_;
  double r = std::min({max_distance, first_radius > 0.0 ? first_radius : cell_, all});
  while (true) {
    double best2 = r * r;
    std::uint32_t best = kEmpty;
    for_each_range(q.array() - r, q.array() + r, [&](std::uint32_t begin, std::uint32_t end) {
      for (std::uint32_t s = begin; s < end; ++s) {
        const double d2 = (points_[s] - q).squaredNorm();
        if (d2 < best2 || (d2 == best2 && best == kEmpty)) {
          best2 = d2;
          best = s;
        }
      }
    });
    if (best != kEmpty) return Neighbor{order_[best], std::sqrt(best2)};
    if (r >= max_distance || r >= all) return std::nullopt;
    r = std::min({2.0 * r, max_distance, all});
  }
}

double SpatialHash::bounded_distance(const Vec3& q, double max_distance, double stop_below) const {
  double best2 = max_distance * max_distance;
  bool found = false;
  const double stop2 = stop_below * stop_below;
  const double qx = q.x(), qy = q.y(), qz = q.z();
  auto scan = [&](std::uint32_t begin, std::uint32_t end) {
    double b2 = best2;  // locals, so the loop keeps them in registers
    bool hit = false;
    for (std::uint32_t s = begin; s < end; ++s) {
      const double dx = points_[s].x() - qx, dy = points_[s].y() - qy, dz = points_[s].z() - qz;
      const double d2 = dx * dx + dy * dy + dz * dz;
      if (d2 <= b2) {
        b2 = d2;
        hit = true;
      }
    }
    best2 = b2;
    found = found || hit;
    return !(found && best2 < stop2);
  };
  // First the cell holding q, then the box of the stop ball: if any point is closer than stop_below it is in there,
  // and inside a dense cloud one cell or that small box usually decides. Otherwise the whole box (the smaller ones
  // are scanned again).
  if (stop_below > 0.0 && stop_below < max_distance) {
    if (!for_each_range(q.array(), q.array(), scan)) return std::sqrt(best2);
    if (!for_each_range(q.array() - stop_below, q.array() + stop_below, scan)) return std::sqrt(best2);
  }
  for_each_range(q.array() - max_distance, q.array() + max_distance, scan);
  return found ? std::sqrt(best2) : std::numeric_limits<double>::infinity();
}

bool SpatialHash::any_within(const Vec3& q, double radius) const {
  const double r2 = radius * radius;
  const double qx = q.x(), qy = q.y(), qz = q.z();
  auto scan = [&](std::uint32_t begin, std::uint32_t end) {
    for (std::uint32_t s = begin; s < end; ++s) {
      const double dx = points_[s].x() - qx, dy = points_[s].y() - qy, dz = points_[s].z() - qz;
      if (dx * dx + dy * dy + dz * dz < r2) return false;  // found: stop the walk
    }
    return true;
  };
  return !for_each_range(q.array(), q.array(), scan) || !for_each_range(q.array() - radius, q.array() + radius, scan);
}

void SpatialHash::within(const Vec3& q, double radius, std::vector<std::uint32_t>& out) const {
  for_each_within(q, radius, [&](std::uint32_t index, const Vec3&, double) { out.push_back(index); });
}

bool SpatialHash::any_pair_within(double distance, const RunControl& control) const {
  const double d2 = distance * distance;
  for (std::uint32_t s = 0; s < points_.size(); ++s) {
    if ((s & 63) == 0) control.check();
    const Vec3& p = points_[s];
    const bool none = for_each_range(p.array() - distance, p.array() + distance, [&](std::uint32_t b, std::uint32_t e) {
      for (std::uint32_t t = std::max(b, s + 1); t < e; ++t) {
        if ((points_[t] - p).squaredNorm() <= d2) return false;
      }
      return true;
    });
    if (!none) return true;
  }
  return false;
}

CoincidentGroups group_coincident(std::span<const Vec3> points, double tolerance, const RunControl& control) {
  CoincidentGroups out;
  out.group.resize(points.size());
  if (points.empty()) return out;
  // Cells of edge `tolerance`, at least 2^-40 of the largest coordinate so that cell indices stay far inside int64.
  double scale = 0.0;
  for (const Vec3& p : points) scale = std::max(scale, p.cwiseAbs().maxCoeff());
  double cell = std::max(tolerance, std::ldexp(scale, -40));
  if (!(cell > 0.0)) cell = 1.0;  // every point at the origin
  const double inv = 1.0 / cell;
  const auto key = [](std::int64_t i, std::int64_t j, std::int64_t k) {
    std::uint64_t h = static_cast<std::uint64_t>(i) * 0x9E3779B97F4A7C15ull;
    h ^= static_cast<std::uint64_t>(j) * 0xC2B2AE3D27D4EB4Full + (h << 6) + (h >> 2);
    h ^= static_cast<std::uint64_t>(k) * 0x165667B19E3779F9ull + (h << 6) + (h >> 2);
    return h;
  };
  // Per cell key, the last kept point in it (a position in out.kept); earlier ones through `previous`.
  constexpr std::uint32_t kNone = std::numeric_limits<std::uint32_t>::max();
  std::unordered_map<std::uint64_t, std::uint32_t> last_in_cell;
  last_in_cell.reserve(points.size());
  std::vector<std::uint32_t> previous;
  const double tolerance2 = tolerance * tolerance;
  for (std::size_t i = 0; i < points.size(); ++i) {
    if ((i & 4095) == 0) control.check();
    const Vec3& p = points[i];
    std::int64_t c[3];
    for (int a = 0; a < 3; ++a) c[a] = static_cast<std::int64_t>(std::floor(p[a] * inv));
    std::uint32_t joined = kNone;
    for (std::int64_t dk = -1; dk <= 1; ++dk) {
      for (std::int64_t dj = -1; dj <= 1; ++dj) {
        for (std::int64_t di = -1; di <= 1; ++di) {
          const auto it = last_in_cell.find(key(c[0] + di, c[1] + dj, c[2] + dk));
          if (it == last_in_cell.end()) continue;
          for (std::uint32_t k = it->second; k != kNone; k = previous[k]) {
            if (k < joined && (points[out.kept[k]] - p).squaredNorm() <= tolerance2) joined = k;
          }
        }
      }
    }
    if (joined == kNone) {
      joined = static_cast<std::uint32_t>(out.kept.size());
      out.kept.push_back(static_cast<std::uint32_t>(i));
      const auto [it, fresh] = last_in_cell.try_emplace(key(c[0], c[1], c[2]), joined);
      previous.push_back(fresh ? kNone : it->second);
      it->second = joined;
    }
    out.group[i] = joined;
  }
  return out;
}

}  // namespace surfacer
