// Skeletal blobs (core/scene/scene.h): summed point and segment kernels, normalized as iso - sum.
//
// Kernels of x = r^2 / R^2 (r = distance to the skeleton: its centre, or the nearest point of its segment):
//   Wyvill  s (1 - x)^3 for x < 1, else 0   (compact support R)
//   Blinn   s exp(-b (x - 1))               (Blinn 1982; equals s at r = R)
// Both depend on r^2 only, so no square root is taken and the gradient is analytic: d(r^2)/dp = 2 (p - q(p)),
// q(p) the nearest skeleton point (the derivative of the clamped projection drops out). Wyvill sums visit only
// the skeletons whose support box holds p: a linear scan up to kGridThreshold skeletons, a uniform grid beyond.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

#include "core/scene/scene.h"
#include "core/util/checks.h"
#include "core/util/errors.h"

namespace surfacer {
namespace {

constexpr std::size_t kGridThreshold = 64;
constexpr std::int64_t kMaxGridCells = std::int64_t{1} << 21;

struct Skeleton {
  Vec3 a;
  Vec3 ba;          // b - a (zero for a point)
  double inv_baba;  // 1 / |b - a|^2, or 0 for a point
  double inv_r2;    // 1 / R^2
  double strength;
  Aabb support;  // the skeleton's box padded by R
};

class Blobs final : public SceneField {
 public:
  Blobs(std::vector<Skeleton> skeletons, const BlobOptions& options)
      : skeletons_(std::move(skeletons)), options_(options) {
    if (options_.kernel == BlobKernel::kWyvill && skeletons_.size() > kGridThreshold) build_grid();
    compute_lipschitz();
  }

  double value(const Vec3& p) const override { return options_.iso - sum<false>(p, nullptr); }

  double value_and_gradient(const Vec3& p, Vec3& gradient) const override {
    Vec3 g = Vec3::Zero();
    const double s = sum<true>(p, &g);
    gradient = -g;
    return options_.iso - s;
  }

  // Per skeleton, with u = r / R: Wyvill |d/dr| = 6 |s| u (1 - u^2)^2 / R <= (96 / (25 sqrt 5)) |s| / R (maximum at
  // u = 1/sqrt 5); Blinn |d/dr| = 2 |s| b e^b u e^(-b u^2) / R <= |s| sqrt(2 b) e^(b - 1/2) / R (at u = 1/sqrt(2b)).
  // The distance to a point or segment is 1-Lipschitz, so these bound each kernel's gradient. Wyvill sums only see
  // the skeletons whose support holds p: with the grid, the largest per-cell sum; otherwise the largest sum over a
  // skeleton and those overlapping it. Blinn kernels have no compact support: the sum over all skeletons.
  std::optional<double> lipschitz_bound() const override { return lipschitz_; }

  double sublevel_limit() const override { return options_.iso; }

  // value <= level where the sum reaches iso' = iso - level. If iso' <= 0 that includes everywhere far from every
  // skeleton (the sum tends to 0): unbounded.
  std::optional<Aabb> sublevel_bounds(double level) const override {
    const double iso = options_.iso - std::max(level, 0.0);
    if (!(iso > 0.0)) return std::nullopt;
    if (options_.kernel == BlobKernel::kWyvill) {
      // Outside every support the sum is 0 < iso'.
      Aabb box = skeletons_[0].support;
      for (const Skeleton& s : skeletons_) box.merge(s.support);
      return box;
    }
    // Blinn: let S = sum of the positive strengths. Where every positive skeleton i has
    //   s_i exp(-b (r_i^2/R_i^2 - 1)) < s_i iso' / S,   i.e.   r_i > rho_i = R_i sqrt(1 + ln(S / iso') / b),
    // the sum is below iso' (negative strengths only lower it): the set lies within rho_i of some skeleton.
    // If 1 + ln(S / iso') / b <= 0 (S e^b <= iso') the sum never reaches iso' and the set is empty; the box then
    // uses rho_i = R_i so that it stays a valid box.
    double total = 0.0;
    for (const Skeleton& s : skeletons_) total += std::max(0.0, s.strength);
    const double q = total > 0.0 ? 1.0 + std::log(total / iso) / options_.blobbiness : 0.0;
    const double factor = q > 0.0 ? std::sqrt(q) : 1.0;
    std::optional<Aabb> box;
    for (const Skeleton& s : skeletons_) {
      const double rho = factor / std::sqrt(s.inv_r2);
      const Vec3 b = s.a + s.ba;
      const Aabb sb{s.a.cwiseMin(b).array() - rho, s.a.cwiseMax(b).array() + rho};
      box = box ? merged(*box, sb) : sb;
    }
    return box;
  }

 private:
  template <bool kGradient>
  double sum(const Vec3& p, Vec3* gradient) const {
    double total = 0.0;
    if (options_.kernel == BlobKernel::kBlinn) {
      for (const Skeleton& s : skeletons_) add<kGradient>(s, p, total, gradient);
      return total;
    }
    if (cell_start_.empty()) {
      for (const Skeleton& s : skeletons_) {
        if (s.support.contains(p)) add<kGradient>(s, p, total, gradient);
      }
      return total;
    }
    std::int64_t index = 0;
    for (int axis = 2; axis >= 0; --axis) {
      const double u = (p[axis] - grid_origin_[axis]) * inv_cell_;
      if (!(u >= 0.0) || u >= dims_[axis]) return 0.0;  // outside every support (also catches NaN)
      index = index * dims_[axis] + static_cast<std::int64_t>(u);
    }
    for (std::uint32_t k = cell_start_[index]; k < cell_start_[index + 1]; ++k) {
      add<kGradient>(skeletons_[cell_items_[k]], p, total, gradient);
    }
    return total;
  }

  template <bool kGradient>
  void add(const Skeleton& s, const Vec3& p, double& total, Vec3* gradient) const {
    const Vec3 w = p - s.a;
    const double t = s.inv_baba > 0.0 ? std::clamp(w.dot(s.ba) * s.inv_baba, 0.0, 1.0) : 0.0;
    const Vec3 d = w - t * s.ba;  // p - nearest skeleton point
    const double x = d.squaredNorm() * s.inv_r2;
    double k = 0.0, dk_dx = 0.0;
    if (options_.kernel == BlobKernel::kWyvill) {
      if (x >= 1.0) return;
      const double m = 1.0 - x;
      k = s.strength * m * m * m;
      dk_dx = -3.0 * s.strength * m * m;
    } else {
      k = s.strength * std::exp(-options_.blobbiness * (x - 1.0));
      dk_dx = -options_.blobbiness * k;
    }
    total += k;
    if constexpr (kGradient) *gradient += (2.0 * dk_dx * s.inv_r2) * d;
  }

  double kernel_slope(const Skeleton& s) const {
    const double inv_r = std::sqrt(s.inv_r2);
    if (options_.kernel == BlobKernel::kWyvill) return 96.0 / (25.0 * std::sqrt(5.0)) * std::abs(s.strength) * inv_r;
    const double b = options_.blobbiness;
    return std::abs(s.strength) * std::sqrt(2.0 * b) * std::exp(b - 0.5) * inv_r;
  }

  void compute_lipschitz() {
    double total = 0.0;
    for (const Skeleton& s : skeletons_) total += kernel_slope(s);
    if (options_.kernel == BlobKernel::kWyvill && cell_start_.empty()) {
      // The skeletons contributing at p all have p in their support boxes, so they all overlap the box of any one of
      // them: the largest (own slope + slopes of the skeletons whose boxes overlap its box) bounds the sum.
      double worst = 0.0;
      for (const Skeleton& a : skeletons_) {
        double sum = 0.0;
        for (const Skeleton& b : skeletons_) {
          const bool overlap = (a.support.min.array() <= b.support.max.array()).all() &&
                               (b.support.min.array() <= a.support.max.array()).all();
          if (overlap) sum += kernel_slope(b);
        }
        worst = std::max(worst, sum);
      }
      total = worst;
    }
    if (!cell_start_.empty()) {
      double worst = 0.0;
      for (std::size_t c = 0; c + 1 < cell_start_.size(); ++c) {
        double sum = 0.0;
        for (std::uint32_t k = cell_start_[c]; k < cell_start_[c + 1]; ++k) {
          sum += kernel_slope(skeletons_[cell_items_[k]]);
        }
        worst = std::max(worst, sum);
      }
      total = worst;
    }
    lipschitz_ = total;
  }

  // Uniform grid over the supports; cell size about the median kernel radius, enlarged to cap the cell count.
  void build_grid() {
    Aabb box = skeletons_[0].support;
    std::vector<double> radii;
    radii.reserve(skeletons_.size());
    for (const Skeleton& s : skeletons_) {
      box.merge(s.support);
      radii.push_back(1.0 / std::sqrt(s.inv_r2));
    }
    std::nth_element(radii.begin(), radii.begin() + radii.size() / 2, radii.end());
    double cell = radii[radii.size() / 2];
    const Vec3 extent = box.size();
    // In double: per-axis counts can exceed int64 (skeletons far apart) and their product overflow.
    auto count_cells = [&](double c) {
      double n = 1.0;
      for (int i = 0; i < 3; ++i) n *= std::floor(extent[i] / c) + 1.0;
      return n;
    };
    while (count_cells(cell) > static_cast<double>(kMaxGridCells)) cell *= 1.25;
    grid_origin_ = box.min;
    inv_cell_ = 1.0 / cell;
    for (int i = 0; i < 3; ++i) dims_[i] = static_cast<std::int64_t>(std::floor(extent[i] / cell)) + 1;

    auto cell_range = [&](const Aabb& b, std::int64_t lo[3], std::int64_t hi[3]) {
      for (int i = 0; i < 3; ++i) {
        lo[i] = std::clamp<std::int64_t>(static_cast<std::int64_t>((b.min[i] - grid_origin_[i]) * inv_cell_), 0,
                                         dims_[i] - 1);
        hi[i] = std::clamp<std::int64_t>(static_cast<std::int64_t>((b.max[i] - grid_origin_[i]) * inv_cell_), 0,
                                         dims_[i] - 1);
      }
    };
    const std::int64_t cells = dims_[0] * dims_[1] * dims_[2];
    std::vector<std::uint32_t> counts(cells + 1, 0);
    auto for_cells = [&](const Skeleton& s, auto&& fn) {
      std::int64_t lo[3], hi[3];
      cell_range(s.support, lo, hi);
      for (std::int64_t z = lo[2]; z <= hi[2]; ++z)
        for (std::int64_t y = lo[1]; y <= hi[1]; ++y)
          for (std::int64_t x = lo[0]; x <= hi[0]; ++x) fn((z * dims_[1] + y) * dims_[0] + x);
    };
    for (const Skeleton& s : skeletons_) for_cells(s, [&](std::int64_t c) { ++counts[c + 1]; });
    for (std::int64_t c = 0; c < cells; ++c) counts[c + 1] += counts[c];
    cell_start_ = counts;
    cell_items_.resize(counts[cells]);
    for (std::uint32_t i = 0; i < skeletons_.size(); ++i) {
      for_cells(skeletons_[i], [&](std::int64_t c) { cell_items_[counts[c]++] = i; });
    }
  }

  std::vector<Skeleton> skeletons_;
  BlobOptions options_;
  // Wyvill acceleration grid (empty when unused): cell (x, y, z) lists cell_items_[cell_start_[c] .. [c+1]).
  Vec3 grid_origin_ = Vec3::Zero();
  double inv_cell_ = 1.0;
  std::int64_t dims_[3] = {0, 0, 0};
  std::vector<std::uint32_t> cell_start_;
  std::vector<std::uint32_t> cell_items_;
  double lipschitz_ = 0.0;
};

Skeleton make_skeleton(const Vec3& a, const Vec3& b, double radius, double strength) {
  Skeleton s;
  s.a = a;
  s.ba = b - a;
  const double baba = s.ba.squaredNorm();
  s.inv_baba = baba > 0.0 ? 1.0 / baba : 0.0;
  s.inv_r2 = 1.0 / (radius * radius);
  s.strength = strength;
  s.support = Aabb{a.cwiseMin(b).array() - radius, a.cwiseMax(b).array() + radius};
  return s;
}

// Kernels use 1 / R^2: below ~1.5e-154 it is infinite and every value NaN.
void require_radius_in_range(const std::string& field, double radius) {
  constexpr double kMinRadius = 1e-150;
  if (radius < kMinRadius) {
    throw InvalidInput(field,
                       field + " (" + format_number(radius) + ") is too small; give a radius of at least 1e-150");
  }
}

}  // namespace

FieldPtr make_blobs(std::span<const PointSkeleton> points, std::span<const SegmentSkeleton> segments,
                    const BlobOptions& options) {
  if (points.empty() && segments.empty()) {
    throw InvalidInput("points", "points and segments are both empty; give at least one point or segment skeleton");
  }
  require_range_open_low("iso", options.iso, 0.0, kMaxCoordinate, "the default is 0.5");
  require_finite("blobbiness", options.blobbiness);
  // Blinn kernels peak at s e^b: beyond b = 100 a sum of them overflows.
  if (options.kernel == BlobKernel::kBlinn) {
    require_range_open_low("blobbiness", options.blobbiness, 0.0, 100.0, "the default is 1");
  }
  if (options.kernel != BlobKernel::kWyvill && options.kernel != BlobKernel::kBlinn) {
    throw InvalidInput("kernel", "kernel is not a known blob kernel; use Wyvill or Blinn");
  }
  if (points.size() + segments.size() > 0xffffffffu) {
    throw InvalidInput("points", "too many skeletons; give fewer than 2^32");
  }
  std::vector<Skeleton> skeletons;
  skeletons.reserve(points.size() + segments.size());
  for (std::size_t i = 0; i < points.size(); ++i) {
    const std::string f = "points[" + std::to_string(i) + "]";
    require_coordinate(f + ".center", points[i].center);
    require_length(f + ".radius", points[i].radius);
    require_radius_in_range(f + ".radius", points[i].radius);
    require_range(f + ".strength", points[i].strength, -kMaxCoordinate, kMaxCoordinate);
    skeletons.push_back(make_skeleton(points[i].center, points[i].center, points[i].radius, points[i].strength));
  }
  for (std::size_t i = 0; i < segments.size(); ++i) {
    const std::string f = "segments[" + std::to_string(i) + "]";
    require_coordinate(f + ".a", segments[i].a);
    require_coordinate(f + ".b", segments[i].b);
    require_length(f + ".radius", segments[i].radius);
    require_radius_in_range(f + ".radius", segments[i].radius);
    require_range(f + ".strength", segments[i].strength, -kMaxCoordinate, kMaxCoordinate);
    skeletons.push_back(make_skeleton(segments[i].a, segments[i].b, segments[i].radius, segments[i].strength));
  }
  return std::make_shared<Blobs>(std::move(skeletons), options);
}

}  // namespace surfacer
