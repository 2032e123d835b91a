// Particle surfacing pipeline (core/particles/particle_surfacer.h). Smoothing matrices and sweeps live in
// smoothing.cpp; this file holds the particle side: radii, the distance field given to Marching
// Tiles, constraint projection, and the stage driver.
#include "core/particles/particle_surfacer.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <limits>
#include <mutex>
#include <numbers>
#include <numeric>
#include <string>

#include "core/particles/cusp_search.h"
#include "core/particles/particle_index.h"
#include "core/particles/smoothing.h"
#include "core/particles/spatial_hash.h"
#include "core/polygonize/marching_tiles.h"
#include "core/util/checks.h"
#include "core/util/errors.h"
#include "core/util/format.h"
#include "core/util/memory.h"
#include "core/util/parallel.h"
#include "core/util/triangle_limit.h"

namespace surfacer {
namespace {

namespace ps = particle_smoothing;
using particle_cusps::Ball;
using particle_cusps::CuspPlane;
using particle_cusps::HeldCusp;
using particle_cusps::kCuspFacing;
using particle_cusps::kMaxCuspSpheres;
using particle_cusps::lowest_cusp;
using particle_index::BandScratch;
using particle_index::Interval;
using particle_index::kInf;
using particle_index::Particles;
using particle_index::Tier;
using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

constexpr int kMaxNewtonSteps = 16;
// Particles closer than this (in r_inner) to an earlier one are merged into it (docs/ALGORITHMS.md §1, CHOICE
// "coincident particles merged").
constexpr double kCoincidentTolerance = 1e-6;
// Frames of at least this many particles give their stages' free pages back to the system (docs/ALGORITHMS.md §1,
// CHOICE "memory returned between stages"). Below it the pages are soon reused: 24 frames of 64 k particles on 2
// workers took 1.9-2.7 s of system time with the trims against 0.6-1.2 s without, for a peak 411-435 MB against
// 467-470 MB.
constexpr std::size_t kGiveBackParticles = 250'000;
// Rounds of 1-ring sums that carry the cusps' planes to the vertices around them (CHOICE "a start on the cusps'
// planes"): enough to cover r_outer, at most this many.
constexpr int kMaxDescentPasses = 16;

// Where f < 0 is certain without a search: a bit per cube of side c of a grid over the particles, set when some
// particle lies closer than r_outer - c sqrt(3) / 2 to the cube's centre (per-particle radii: the smallest r_outer_i of
// the tier holding the most particles, and only the particles of that tier and those above),
// so that every point of the cube is strictly inside that particle's ball. Inside a fluid nearly every sample of the
// polygonizer falls in such a cube and its sign costs one bit lookup, and Marching Tiles skips the cubes of cells
// whose boxes it covers (covers()). Built by rasterizing each particle's ball row by row as spans of
// bits, from a table of rows per class of the particle's offset in its cube (Stencils: no square root per particle);
// rows are padded to whole 64-bit words and z-slabs of rows go to different workers, so no word is written by two (and
// the bits do not depend on the order anyway). Not built when the grid would hold more than
// kMaxBitsPerParticle bits per particle (scattered data): the search then answers every query.
class InsideMask {
 public:
  static constexpr double kMaxBitsPerParticle = 512.0;

  InsideMask(const Particles& P, int threads) {
    // Scattered data (the largest tier's hash is sparse) is left to the search.
    if (P.positions.empty()) return;
    const Tier* most = &P.tiers[P.main_tier];
    if (!most->hash.dense()) return;
    // Per-particle radii: the balls of the smallest radii of the largest tier, about the centres of that tier and of
    // the tiers above (each ball holds such a ball about its centre), so a sound mask; the smaller tiers' particles
    // are left to the search, so that a few tiny radii do not make the cubes too many to keep.
    const double r_inner = P.weighted ? *std::min_element(most->slot_inner.begin(), most->slot_inner.end()) : P.r_inner;
    const double r_outer = P.weighted ? *std::min_element(most->slot_outer.begin(), most->slot_outer.end()) : P.r_outer;
    // Half r_inner, or coarser when r_outer is many times r_inner, so that a ball spans at most kMaxReachCells cells.
    cell_ = std::max(0.5 * r_inner, r_outer / Stencils::kMaxReachCells);
    const double reach = r_outer - cell_ * std::sqrt(3.0) / 2.0;
    if (!(reach > 0.0)) return;
    origin_ = P.box.min.array() - r_outer;
    for (int a = 0; a < 3; ++a) {
      dims_[a] = static_cast<std::int64_t>(std::ceil((P.box.size()[a] + 2.0 * r_outer) / cell_)) + 1;
    }
    row_words_ = (dims_[0] + 63) / 64;
    const double words =
        static_cast<double>(row_words_) * static_cast<double>(dims_[1]) * static_cast<double>(dims_[2]);
    if (64.0 * words > kMaxBitsPerParticle * static_cast<double>(P.positions.size()) + 65536.0) return;
    words_.assign(static_cast<std::size_t>(words), 0);
    // A tier's particles in hash order are sorted by z cell (the hash's cells are x fastest), so each slab's
    // particles are a contiguous range of each tier found by binary search on z.
    const double inv = 1.0 / cell_;
    const Stencils stencils(reach * inv);
    const int slabs = static_cast<int>(std::min<std::int64_t>(dims_[2], 4 * resolve_threads(threads)));
    parallel_for(slabs, threads, [&](int slab) {
      const std::int64_t kb = dims_[2] * slab / slabs, ke = dims_[2] * (slab + 1) / slabs;  // rows [kb, ke)
      const double z_lo = origin_.z() + (kb - stencils.reach) * cell_,
                   z_hi = origin_.z() + (ke + stencils.reach) * cell_;
      for (std::size_t t = P.main_tier; t < P.tiers.size(); ++t) rasterize(P.tiers[t], stencils, kb, ke, z_lo, z_hi);
    });
  }

  // True only where every point within the cube of x is inside some particle's r_outer ball.
  bool certainly_inside(const Vec3& x) const {
    if (words_.empty()) return false;
    std::int64_t c[3];
    for (int a = 0; a < 3; ++a) {
      const double v = (x[a] - origin_[a]) / cell_;
      if (!(v >= 0.0) || v >= static_cast<double>(dims_[a])) return false;
      c[a] = static_cast<std::int64_t>(v);
    }
    const std::uint64_t w = words_[static_cast<std::size_t>((c[2] * dims_[1] + c[1]) * row_words_ + (c[0] >> 6))];
    return (w >> (c[0] & 63)) & 1u;
  }

  bool usable() const { return !words_.empty(); }

  // True only where every point of `box` is inside some particle's r_outer ball: every cube the box meets is marked.
  bool covers(const Aabb& box) const {
    if (words_.empty()) return false;
    std::int64_t lo[3], hi[3];
    for (int a = 0; a < 3; ++a) {
      const double l = (box.min[a] - origin_[a]) / cell_, h = (box.max[a] - origin_[a]) / cell_;
      if (!(l >= 0.0) || !(h < static_cast<double>(dims_[a]))) return false;
      lo[a] = static_cast<std::int64_t>(l);
      hi[a] = static_cast<std::int64_t>(h);
    }
    for (std::int64_t k = lo[2]; k <= hi[2]; ++k) {
      for (std::int64_t j = lo[1]; j <= hi[1]; ++j) {
        const std::uint64_t* row = &words_[static_cast<std::size_t>((k * dims_[1] + j) * row_words_)];
        for (std::int64_t w = lo[0] >> 6; w <= hi[0] >> 6; ++w) {
          const std::int64_t first = std::max(lo[0], 64 * w) - 64 * w, last = std::min(hi[0], 64 * w + 63) - 64 * w;
          const std::uint64_t bits = (last == 63 ? ~std::uint64_t{0} : (std::uint64_t{1} << (last + 1)) - 1) &
                                     ~((std::uint64_t{1} << first) - 1);
          if ((row[w] & bits) != bits) return false;
        }
      }
    }
    return true;
  }

 private:
  // The cells strictly within `reach` (in cells) of a particle, as rows of cells relative to the particle's cell,
  // one list per class of its offset in the cell (kClasses per axis). A list is made for the class's centre with the
  // reach shortened by the largest distance from it to a point of the class, so it holds for every particle of the
  // class: no square root per particle and row.
  class Stencils {
   public:
    static constexpr int kClasses = 8;
    static constexpr double kMaxReachCells = 8.0;  // keeps the table small (~100 k rows) and the offsets in int8
    struct Row {
      std::int8_t dk, dj, di0, di1;
    };
    explicit Stencils(double full_reach) : reach(full_reach) {
      const double r = full_reach - std::sqrt(3.0) * 0.5 / kClasses;
      const int extent = static_cast<int>(std::ceil(full_reach)) + 1;
      start_.push_back(0);
      for (int cz = 0; cz < kClasses; ++cz) {
        for (int cy = 0; cy < kClasses; ++cy) {
          for (int cx = 0; cx < kClasses; ++cx) {
            const double o[3] = {(cx + 0.5) / kClasses, (cy + 0.5) / kClasses, (cz + 0.5) / kClasses};
            for (int dk = -extent; dk <= extent && r > 0.0; ++dk) {
              for (int dj = -extent; dj <= extent; ++dj) {
                const double dz = dk + 0.5 - o[2], dy = dj + 0.5 - o[1], ry2 = r * r - dz * dz - dy * dy;
                if (!(ry2 > 0.0)) continue;
                const double ry = std::sqrt(ry2);
                // Strictly inside: centres with (di + 0.5 - o.x)^2 < ry^2.
                const int di0 = static_cast<int>(std::floor(o[0] - ry - 0.5)) + 1;
                const int di1 = static_cast<int>(std::ceil(o[0] + ry - 0.5)) - 1;
                if (di0 <= di1) {
                  rows_.push_back({static_cast<std::int8_t>(dk), static_cast<std::int8_t>(dj),
                                   static_cast<std::int8_t>(di0), static_cast<std::int8_t>(di1)});
                }
              }
            }
            start_.push_back(static_cast<std::uint32_t>(rows_.size()));
          }
        }
      }
    }
    std::span<const Row> rows(int cls) const { return {rows_.data() + start_[cls], rows_.data() + start_[cls + 1]}; }
    const double reach;

   private:
    std::vector<Row> rows_;
    std::vector<std::uint32_t> start_;
  };

  // Sets the bits of the rows [kb, ke) that the tier's particles with z in [z_lo, z_hi] cover.
  void rasterize(const Tier& tier, const Stencils& stencils, std::int64_t kb, std::int64_t ke, double z_lo,
                 double z_hi) {
    const std::span<const Vec3> pts = tier.hash.sorted_points();
    const double inv = 1.0 / cell_, slack = tier.hash.cell_size();
    const auto first =
        std::lower_bound(pts.begin(), pts.end(), z_lo - slack, [](const Vec3& p, double z) { return p.z() < z; });
    for (auto it = first; it != pts.end() && it->z() <= z_hi + slack; ++it) {
      const Vec3 q = (*it - origin_) * inv;  // in cells; cell (i, j, k) has its centre at (i + 0.5, ...)
      std::int64_t base[3];
      int cls = 0;
      for (int a = 2; a >= 0; --a) {
        const double fl = std::floor(q[a]);
        base[a] = static_cast<std::int64_t>(fl);
        cls = cls * Stencils::kClasses +
              std::min(Stencils::kClasses - 1, static_cast<int>((q[a] - fl) * Stencils::kClasses));
      }
      for (const Stencils::Row& row : stencils.rows(cls)) {
        const std::int64_t k = base[2] + row.dk, j = base[1] + row.dj;
        if (k < kb || k >= ke || j < 0 || j >= dims_[1]) continue;
        const std::int64_t i0 = std::max<std::int64_t>(0, base[0] + row.di0);
        const std::int64_t i1 = std::min<std::int64_t>(dims_[0] - 1, base[0] + row.di1);
        if (i0 <= i1) set_span(&words_[static_cast<std::size_t>((k * dims_[1] + j) * row_words_)], i0, i1 - i0 + 1);
      }
    }
  }

  static void set_span(std::uint64_t* row, std::int64_t first, std::int64_t count) {
    while (count > 0) {
      const std::int64_t b = first & 63;
      const std::int64_t n = std::min<std::int64_t>(count, 64 - b);
      row[first >> 6] |= (n == 64 ? ~std::uint64_t{0} : ((std::uint64_t{1} << n) - 1)) << b;
      first += n;
      count -= n;
    }
  }

  double cell_ = 0.0;
  Vec3 origin_ = Vec3::Zero();
  std::int64_t dims_[3] = {0, 0, 0};
  std::int64_t row_words_ = 0;
  std::vector<std::uint64_t> words_;
};

// f(x) = min_i (|x - p_i| - r_outer_i) for Marching Tiles. Exact where |f| <= band; elsewhere a value of the same
// sign and no larger magnitude (a deep-inside sample stops at the first particle closer than r_outer - band, a far
// outside one returns band). With band above the longest lattice edge, every crossed edge has exact end values, and
// polygonizers that skip regions by |f(c)| > L r stay correct (the bound only gets more conservative).
class ParticleField final : public Field {
 public:
  ParticleField(const Particles& particles, double band, int threads)
      : particles_(particles), band_(band), inside_(particles, threads) {}

  double value(const Vec3& x) const override {
    count();
    if (!particles_.weighted) {
      const double d = particles_.hash().bounded_distance(x, particles_.r_outer + band_, particles_.r_outer - band_);
      return std::isinf(d) ? band_ : d - particles_.r_outer;
    }
    double best = band_;
    for (const Tier& t : particles_.tiers) {
      const std::span<const Vec3> pts = t.hash.sorted_points();
      const double r = t.max_outer + band_;
      if (!t.hash.for_each_range(x.array() - r, x.array() + r, [&](std::uint32_t begin, std::uint32_t end) {
            for (std::uint32_t s = begin; s < end; ++s) best = std::min(best, (pts[s] - x).norm() - t.slot_outer[s]);
            return best >= -band_;
          })) {
        break;
      }
    }
    return best;
  }

  // Inside (f < 0) exactly when some particle is closer than its r_outer: the first one found decides.
  double sign_value(const Vec3& x) const override {
    count();
    if (inside_.certainly_inside(x)) return -band_;
    if (!particles_.weighted) return particles_.hash().any_within(x, particles_.r_outer) ? -band_ : band_;
    bool inside = false;
    for (const Tier& t : particles_.tiers) {
      const std::span<const Vec3> pts = t.hash.sorted_points();
      t.hash.for_each_range(x.array() - t.max_outer, x.array() + t.max_outer,
                            [&](std::uint32_t begin, std::uint32_t end) {
                              for (std::uint32_t s = begin; s < end && !inside; ++s)
                                inside = (pts[s] - x).norm() < t.slot_outer[s];
                              return !inside;
                            });
      if (inside) break;
    }
    return inside ? -band_ : band_;
  }
  bool sign_is_cheaper() const override { return true; }
  bool inside_everywhere(const Aabb& box) const override { return inside_.covers(box); }
  bool answers_inside_boxes() const override { return inside_.usable(); }

  double value_and_gradient(const Vec3& x, Vec3& gradient) const override {
    count();
    Particles::Hit hit;
    if (particles_.weighted) {
      Particles::Hit in;
      particles_.nearest_weighted(x, in, hit);
    } else {
      hit = particles_.nearest(x);
      hit.value = hit.distance - particles_.r_outer;
    }
    const Vec3 d = x - particles_.positions[hit.index];
    gradient = hit.distance > 0.0 ? Vec3(d / hit.distance) : Vec3::UnitZ();
    return hit.value;
  }

  std::optional<Aabb> bounds() const override {
    return Aabb{particles_.box.min.array() - particles_.max_outer, particles_.box.max.array() + particles_.max_outer};
  }

  std::int64_t evaluations() const {
    std::int64_t n = 0;
    for (const Counter& c : counters_) n += c.n.load(std::memory_order_relaxed);
    return n;
  }

 private:
  struct alignas(64) Counter {
    std::atomic<std::int64_t> n{0};
  };
  void count() const {
    static std::atomic<unsigned> next{0};
    thread_local const unsigned slot = next.fetch_add(1, std::memory_order_relaxed) % kCounters;
    counters_[slot].n.fetch_add(1, std::memory_order_relaxed);
  }
  static constexpr unsigned kCounters = 16;

  const Particles& particles_;
  double band_;
  InsideMask inside_;
  mutable std::array<Counter, kCounters> counters_;
};

// --- Container ------------------------------------------------------------------------------------------------------

struct Container {
  std::optional<Aabb> box;
  const Field* solid = nullptr;
  double inside_margin = 0.0;

  bool active() const { return box.has_value() || solid != nullptr; }

  void project(Vec3& x) const {
    if (box) x = x.cwiseMax(box->min).cwiseMin(box->max);
    if (solid == nullptr) return;
    Vec3 g;
    double f = solid->value_and_gradient(x, g);
    for (int step = 0; step < kMaxNewtonSteps && f > 0.0; ++step) {
      const double g2 = g.squaredNorm();
      if (!(g2 > 0.0) || !std::isfinite(g2)) break;
      x -= ((f + inside_margin) / g2) * g;
      f = solid->value_and_gradient(x, g);
    }
    if (box) x = x.cwiseMax(box->min).cwiseMin(box->max);
  }
};

// --- Frame setup ------------------------------------------------------------------------------------------------

// Mean nearest-neighbour distance over a deterministic sample of at most 65536 particles, leaving out particles whose
// neighbour is farther than 4x the median (stray spray). Neighbours are searched within 4 cells of a hash whose cells
// hold a few particles each; only when most of the sample finds none there (very sparse input) is an unbounded search
// run, on at most 4096 of them.
double derive_r_inner(std::span<const Vec3> points, int threads, const RunControl& control) {
  if (points.size() < 2) {
    throw InvalidInput("r_inner", "cannot derive r_inner from " + std::to_string(points.size()) +
                                      " particle(s); set r_inner (e.g. the simulation's particle radius)");
  }
  const Aabb box = Aabb::of(points);
  const Vec3 extent = box.max - box.min;
  if (!(extent.maxCoeff() > 0.0)) {
    throw InvalidInput("r_inner", "cannot derive r_inner: all " + std::to_string(points.size()) +
                                      " particles are at one position; set r_inner (e.g. the simulation's particle "
                                      "radius)");
  }
  const double floor_extent = std::max(extent.maxCoeff() * 1e-3, 1e-300);
  double volume = 1.0;
  for (int a = 0; a < 3; ++a) volume *= std::max(extent[a], floor_extent);
  double cell = std::cbrt(volume / static_cast<double>(points.size()));
  SpatialHash hash;
  for (int attempt = 0; attempt < 4; ++attempt) {
    hash.build(points, cell);
    const double occupancy = static_cast<double>(points.size()) / static_cast<double>(hash.occupied_cells());
    if (occupancy <= 16.0) break;
    cell /= std::cbrt(occupancy / 4.0);
  }
  const std::span<const Vec3> pts = hash.sorted_points();
  const double all = extent.norm() + cell;
  // Nearest other point of slot s within r (or up to `all` when r is infinite); infinity when none.
  auto nearest_other = [&](std::uint32_t s, double r) {
    const bool widen = std::isinf(r);
    if (widen) r = cell;
    while (true) {
      double best2 = r * r;
      bool found = false;
      hash.for_each_range(pts[s].array() - r, pts[s].array() + r, [&](std::uint32_t b, std::uint32_t e) {
        for (std::uint32_t t = b; t < e; ++t) {
          const double d2 = (pts[t] - pts[s]).squaredNorm();
          if (t != s && d2 <= best2) {
            best2 = d2;
            found = true;
          }
        }
      });
      if (found) return std::sqrt(best2);
      if (!widen || r > all) return kInf;
      r *= 2.0;
    }
  };
  const std::size_t stride = std::max<std::size_t>(1, points.size() / 65536);
  std::vector<double> nn((points.size() + stride - 1) / stride);
  for_chunks(nn.size(), threads, [&](std::size_t begin, std::size_t end) {
    control.check();
    for (std::size_t k = begin; k < end; ++k) nn[k] = nearest_other(static_cast<std::uint32_t>(k * stride), 4.0 * cell);
  });
  const std::size_t found =
      static_cast<std::size_t>(std::count_if(nn.begin(), nn.end(), [](double d) { return d < kInf; }));
  if (2 * found < nn.size()) {
    const std::size_t step = std::max<std::size_t>(1, nn.size() / 4096);
    std::vector<double> wide((nn.size() + step - 1) / step);
    for_chunks(wide.size(), threads, [&](std::size_t begin, std::size_t end) {
      control.check();
      for (std::size_t k = begin; k < end; ++k)
        wide[k] = nearest_other(static_cast<std::uint32_t>(k * step * stride), kInf);
    });
    nn = std::move(wide);
  }
  std::vector<double> sorted = nn;
  const auto mid = sorted.begin() + static_cast<std::ptrdiff_t>(sorted.size() / 2);
  std::nth_element(sorted.begin(), mid, sorted.end());
  const double limit = 4.0 * *mid;
  double sum = 0.0;
  std::size_t count = 0;
  for (const double d : nn) {
    if (d <= limit) {
      sum += d;
      ++count;
    }
  }
  const double mean = count > 0 ? sum / static_cast<double>(count) : 0.0;
  if (!(mean > 0.0)) {
    throw InvalidInput("r_inner",
                       "cannot derive r_inner: the particles' nearest-neighbour distances are all 0 "
                       "(duplicate positions); set r_inner");
  }
  return mean;
}

// Whether p lies inside the closed triangle set `faces` of `x`: its winding number (the solid angles its triangles
// subtend from p, summed: 4 pi inside an outward surface, -4 pi inside an inward one, 0 outside) is away from 0.
bool encloses(std::span<const Vec3> x, std::span<const Triangle> faces, const Vec3& p) {
  double solid_angle = 0.0;
  for (const Triangle& t : faces) {
    const Vec3 a = x[t[0]] - p, b = x[t[1]] - p, c = x[t[2]] - p;
    const double la = a.norm(), lb = b.norm(), lc = c.norm();
    const double det = a.dot(b.cross(c));
    const double div = la * lb * lc + a.dot(b) * lc + a.dot(c) * lb + b.dot(c) * la;
    solid_angle += 2.0 * std::atan2(det, div);  // Van Oosterom and Strackee
  }
  return std::abs(solid_angle) > 2.0 * 3.14159265358979323846;
}

// Drops the closed components of the mesh that span less than `span` on every axis and enclose no particle: bubbles,
// voids among the outer balls, below the size of a particle (docs/ALGORITHMS.md §1, CHOICE "sub-particle bubbles").
// Returns how many; the other vertices and triangles keep their order.
std::size_t drop_bubbles(Mesh& mesh, const Particles& P, double span) {
  const std::size_t nv = mesh.vertices.size();
  std::vector<std::uint32_t> root(nv);
  std::iota(root.begin(), root.end(), 0u);
  const auto find = [&root](std::uint32_t v) {
    while (root[v] != v) v = root[v] = root[root[v]];
    return v;
  };
  for (const Triangle& t : mesh.triangles) {
    for (int k = 1; k < 3; ++k) {
      const std::uint32_t a = find(t[0]), b = find(t[k]);
      if (a != b) root[std::max(a, b)] = std::min(a, b);
    }
  }
  // Components numbered in vertex order (a root is its component's smallest vertex), and their boxes.
  std::vector<std::uint32_t>& component = root;  // root[v] becomes v's component number
  std::vector<Aabb> box;
  for (std::uint32_t v = 0; v < nv; ++v) {
    if (root[v] == v) {
      component[v] = static_cast<std::uint32_t>(box.size());
      box.push_back(Aabb::empty());
    } else {
      component[v] = component[root[v]];  // links point to smaller vertices: root[v] holds its number already
    }
    box[component[v]].merge(mesh.vertices[v]);
  }
  // The small ones, and their triangles, gathered in one pass.
  std::vector<std::int32_t> small(box.size(), -1);
  std::vector<std::uint32_t> smalls;
  for (std::uint32_t c = 0; c < box.size(); ++c) {
    if (box[c].valid() && (box[c].size().array() < span).all()) {
      small[c] = static_cast<std::int32_t>(smalls.size());
      smalls.push_back(c);
    }
  }
  if (smalls.empty()) return 0;
  std::vector<std::vector<Triangle>> faces(smalls.size());
  for (const Triangle& t : mesh.triangles) {
    if (const std::int32_t c = small[component[t[0]]]; c >= 0) faces[c].push_back(t);
  }
  std::vector<char> drop(smalls.size(), 0);
  std::size_t dropped = 0;
  for (std::size_t c = 0; c < smalls.size(); ++c) {
    const Aabb& b = box[smalls[c]];
    bool holds = false;
    for (const Tier& t : P.tiers) {
      const std::span<const Vec3> pts = t.hash.sorted_points();
      t.hash.for_each_range(b.min.array(), b.max.array(), [&](std::uint32_t begin, std::uint32_t end) {
        for (std::uint32_t s = begin; s < end && !holds; ++s) {
          holds = b.contains(pts[s]) && encloses(mesh.vertices, faces[c], pts[s]);
        }
        return !holds;
      });
      if (holds) break;
    }
    if (!holds) {
      drop[c] = 1;
      ++dropped;
    }
  }
  if (dropped == 0) return 0;
  std::vector<std::uint32_t> remap(nv, std::numeric_limits<std::uint32_t>::max());
  std::uint32_t kept = 0;
  for (std::uint32_t v = 0; v < nv; ++v) {
    const std::int32_t c = small[component[v]];
    if (c >= 0 && drop[c]) continue;
    mesh.vertices[kept] = mesh.vertices[v];
    remap[v] = kept++;
  }
  mesh.vertices.resize(kept);
  std::erase_if(mesh.triangles,
                [&](const Triangle& t) { return remap[t[0]] == std::numeric_limits<std::uint32_t>::max(); });
  for (Triangle& t : mesh.triangles) {
    for (std::uint32_t& v : t) v = remap[v];
  }
  return dropped;
}

// Every particle within `tolerance` of an earlier kept one (group_coincident) merged into it, which takes the largest
// radii of its group (docs/ALGORITHMS.md §1, CHOICE "coincident particles merged"): exact duplicates leave the unions
// of the inner and outer balls as they were; near ones move them by at most `tolerance`. Returns, per kept particle,
// how many input particles it stands for; empty (and P untouched) when nothing merged. P is not indexed.
std::vector<std::uint32_t> merge_coincident(Particles& P, double tolerance, const RunControl& control) {
  const CoincidentGroups groups = group_coincident(P.positions, tolerance, control);
  const std::size_t kept = groups.kept.size();
  if (kept == P.positions.size()) return {};
  std::vector<std::uint32_t> weight(kept, 0);
  for (const std::uint32_t g : groups.group) ++weight[g];
  if (P.weighted) {
    std::vector<double> inner(kept, 0.0), outer(kept, 0.0);
    for (std::size_t i = 0; i < groups.group.size(); ++i) {
      const std::uint32_t g = groups.group[i];
      inner[g] = std::max(inner[g], P.inner[i]);
      outer[g] = std::max(outer[g], P.outer[i]);
    }
    P.inner = std::move(inner);
    P.outer = std::move(outer);
    P.min_inner = *std::min_element(P.inner.begin(), P.inner.end());
  }
  std::vector<Vec3> positions(kept);
  for (std::size_t k = 0; k < kept; ++k) positions[k] = P.positions[groups.kept[k]];
  P.replace_positions(std::move(positions));
  return weight;
}

// Union-find over particles whose r_outer balls overlap; returns the kept flags and the number of dropped clusters.
// A particle counts `weight` input particles (empty: one each).
// Per tier a spatial hash of its own with cells of the tier's largest reach (2 of its largest r_outer), so a query
// touches at most 27 cells even for scattered spray. A particle is paired with those of its own tier and of the tiers
// above, each searched as far as its own r_outer and that tier's largest one reach.
std::vector<char> filter_components(const Particles& all, int min_size, std::span<const std::uint32_t> weight,
                                    std::size_t& dropped, const RunControl& control) {
  const std::size_t n = all.positions.size();
  struct Level {
    SpatialHash hash;
    std::vector<std::uint32_t> particle;  // per slot
    std::vector<double> outer;            // per slot
    double max_outer = 0.0;
  };
  std::vector<Level> levels(all.tiers.size());
  for (std::size_t k = 0; k < levels.size(); ++k) {
    const Tier& tier = all.tiers[k];
    Level& level = levels[k];
    level.hash.build(tier.hash.sorted_points(), all.hash_cell(2.0 * tier.max_outer));
    level.max_outer = tier.max_outer;
    level.particle.resize(level.hash.size());
    level.outer.resize(level.hash.size());
    for (std::uint32_t s = 0; s < level.hash.size(); ++s) {
      level.particle[s] = tier.particle(level.hash.order()[s]);
      level.outer[s] = all.weighted ? all.outer[level.particle[s]] : all.r_outer;
    }
  }
  std::vector<std::uint32_t> parent(n);
  std::iota(parent.begin(), parent.end(), 0u);
  auto find = [&](std::uint32_t i) {
    while (parent[i] != i) {
      parent[i] = parent[parent[i]];
      i = parent[i];
    }
    return i;
  };
  std::size_t visited = 0;
  for (std::size_t k = 0; k < levels.size(); ++k) {
    const Level& level = levels[k];
    const std::span<const Vec3> pts = level.hash.sorted_points();
    for (std::uint32_t s = 0; s < pts.size(); ++s) {
      if ((visited++ & 4095) == 0) control.check();
      const double ro = level.outer[s];
      for (std::size_t k2 = k; k2 < levels.size(); ++k2) {
        const Level& other = levels[k2];
        const std::span<const Vec3> other_pts = other.hash.sorted_points();
        const double reach = ro + other.max_outer;
        other.hash.for_each_range(pts[s].array() - reach, pts[s].array() + reach,
                                  [&](std::uint32_t b, std::uint32_t e) {
                                    for (std::uint32_t t = k2 == k ? std::max(b, s + 1) : b; t < e; ++t) {
                                      const double limit = ro + other.outer[t];
                                      if ((other_pts[t] - pts[s]).squaredNorm() > limit * limit) continue;
                                      const std::uint32_t x = find(level.particle[s]), y = find(other.particle[t]);
                                      if (x != y) parent[std::max(x, y)] = std::min(x, y);
                                    }
                                  });
      }
    }
  }
  std::vector<std::uint32_t> size(n, 0);
  for (std::uint32_t i = 0; i < n; ++i) size[find(i)] += weight.empty() ? 1 : weight[i];
  std::vector<char> keep(n, 0);
  dropped = 0;
  for (std::uint32_t i = 0; i < n; ++i) {
    const std::uint32_t root = find(i);
    keep[i] = size[root] >= static_cast<std::uint32_t>(min_size);
    if (root == i && size[root] < static_cast<std::uint32_t>(min_size)) ++dropped;
  }
  return keep;
}

// Marching Tiles' triangles per h^2 of surface, at least: each is a planar section of an A15 tetrahedron, whose edges
// are at most sqrt(6) / a15::kMeanEdge = 1.063 h, so its area is at most pi (1.063 h)^2 / 4 = 0.887 h^2 (that of a disk
// of the same diameter); halved for the chords by which a mesh falls inside the sphere it follows.
constexpr double kFewestTrianglesPerArea = 0.5 / 0.887;

// Refuses, before any lattice block is visited, a frame whose largest outer ball alone asks Marching Tiles for more
// triangles than the limit allows (a radius far above the rest: its seed's blocks alone could take hours to list).
// The union of the outer balls holds that ball, so its surface is no smaller than the ball's sphere (the nearest-point
// projection onto a convex body shortens every surface around it).
void require_room_for_largest_ball(const Particles& P, double h, const RunControl& control) {
  if (!P.weighted || control.triangles == nullptr || P.outer.empty()) return;
  const std::size_t i = static_cast<std::size_t>(std::max_element(P.outer.begin(), P.outer.end()) - P.outer.begin());
  const double r = P.outer[i];
  const double fewest = kFewestTrianglesPerArea * 4.0 * std::numbers::pi * r * r / (h * h);
  const TriangleLimit& limit = *control.triangles;
  if (!(fewest > static_cast<double>(limit.max_triangles))) return;
  const Vec3& p = P.positions[i];
  throw ResourceLimit(limit.name, "the particle at (" + format_number(p.x()) + ", " + format_number(p.y()) + ", " +
                                      format_number(p.z()) + ") has r_outer " + format_number(r) +
                                      ": its sphere alone needs at least " + format_number(fewest) +
                                      " triangles at spacing " + format_number(h) + ", over the limit of " +
                                      std::to_string(limit.max_triangles) + " triangles per mesh (" + limit.name +
                                      "); check the radii (one far above the rest, such as a default pscale), use a "
                                      "larger spacing_factor, or raise " +
                                      limit.name);
}

int min_valence(const ps::Graph& ring) {
  int m = 0;
  for (std::size_t i = 0; i < ring.rows(); ++i) {
    const int d = static_cast<int>(ring.degree(i));
    if (d > 0 && (m == 0 || d < m)) m = d;
  }
  return m;
}

}  // namespace

void validate(const ParticleSurfacingOptions& o) {
  const ParticleSurfacingOptions defaults;
  require_range("min_angle_degrees", o.min_angle_degrees, 0.0, 30.0,
                "0 switches the sliver repair off; the default is " + format_number(defaults.min_angle_degrees));
  if (o.output_grid) {
    require_box("output_grid.box", o.output_grid->box);
    require_count("output_grid.bits", o.output_grid->bits, 1, 30);
  }
  if (o.r_inner && o.derive_r_inner) {
    throw InvalidInput("derive_r_inner", "derive_r_inner and r_inner (" + format_number(*o.r_inner) +
                                             ") are both set; give one (r_inner, or derive_r_inner to estimate it "
                                             "from the particle spacing)");
  }
  if (o.r_inner) require_length("r_inner", *o.r_inner, "a radius in scene units");
  if (o.r_outer) require_length("r_outer", *o.r_outer, "a radius in scene units");
  if (o.r_inner && o.r_outer && !(*o.r_outer > *o.r_inner)) {
    throw InvalidInput("r_outer", "r_outer (" + format_number(*o.r_outer) + ") must exceed r_inner (" +
                                      format_number(*o.r_inner) + "); the default is " +
                                      format_number(ParticleSurfacingOptions::kDefaultOuterRatio) + " x r_inner");
  }
  if (!(std::isfinite(o.spacing_factor) && o.spacing_factor >= ParticleSurfacingOptions::kMinSpacingFactor &&
        o.spacing_factor <= 10.0)) {
    throw InvalidInput("spacing_factor", "spacing_factor (" + format_number(o.spacing_factor) + ") must be in [" +
                                             format_number(ParticleSurfacingOptions::kMinSpacingFactor) +
                                             ", 10]; the thesis uses 0.8 (samples 0.8 r_inner apart), the default is " +
                                             format_number(defaults.spacing_factor));
  }
  const std::pair<const char*, int> sweeps[] = {{"laplacian_sweeps", o.laplacian_sweeps},
                                                {"bilaplacian_sweeps", o.bilaplacian_sweeps},
                                                {"polish_sweeps", o.polish_sweeps}};
  for (const auto& [name, value] : sweeps) {
    if (value < 0 || value > 100000) {
      throw InvalidInput(name, std::string(name) + " (" + std::to_string(value) + ") must be in 0..100000");
    }
  }
  if (!(std::isfinite(o.relaxation) && o.relaxation > 0.0 && o.relaxation <= 1.0)) {
    throw InvalidInput("relaxation", "relaxation (" + format_number(o.relaxation) +
                                         ") must be in (0, 1]; the thesis uses 0.6, the default is " +
                                         format_number(defaults.relaxation));
  }
  if (o.erosion && !(std::isfinite(*o.erosion) && *o.erosion >= 0.0 && *o.erosion <= 10.0)) {
    throw InvalidInput("erosion", "erosion (" + format_number(*o.erosion) +
                                      ") must be in [0, 10] (units of r_inner; the thesis shows 0.5); leave it unset "
                                      "to switch erosion off");
  }
  if (o.container_box &&
      !(o.container_box->min.allFinite() && o.container_box->max.allFinite() && o.container_box->valid())) {
    throw InvalidInput("container_box", "container_box must have finite min < max on every axis");
  }
  if (o.min_particles_per_component < 0) {
    throw InvalidInput("min_particles_per_component", "min_particles_per_component (" +
                                                          std::to_string(o.min_particles_per_component) +
                                                          ") must be >= 0 (0 keeps every particle)");
  }
  if (o.threads < 0) {
    throw InvalidInput("threads",
                       "threads (" + std::to_string(o.threads) + ") must be >= 0; 0 uses every hardware thread");
  }
}

void require_r_inner_source(bool frame_has_radii, bool has_r_inner, bool derive_r_inner) {
  if (frame_has_radii || has_r_inner || derive_r_inner) return;
  throw InvalidInput("r_inner",
                     "r_inner is required: set it (e.g. the simulation's particle radius), ask for derive_r_inner, "
                     "or give per-particle radii");
}

// --- The surfacer ---------------------------------------------------------------------------------------------------

struct ParticleSurfacer::State {
  ParticleSurfacingOptions options;
  Particles particles;
  // return_free_memory() between stages of a frame of at least kGiveBackParticles (stats.particles: the input's count)
  // (docs/ALGORITHMS.md §1, CHOICE "memory returned between stages"); a small frame's pages are reused by its next
  // stages and frames, and returning them costs page faults.
  static void give_back_memory(const ParticleSurfacingStats& stats) {
    if (stats.particles >= kGiveBackParticles) return_free_memory();
  }

  Mesh run(std::span<const Vec3> input, std::span<const double> radii, const RunControl& control,
           ParticleSurfacingStats* stats_out, bool initial_only);

  // The stages, in order (each named as in the stats and the progress reports).
  void check_inputs(std::span<const Vec3> input, std::span<const double> radii) const;
  // "distance_field": resolves the radii, hashes the particles and drops small components.
  void distance_field(std::span<const Vec3> input, std::span<const double> radii, int threads,
                      const RunControl& control, ParticleSurfacingStats& stats);
  // "polygonize": the Marching Tiles mesh of f = d - r_outer.
  Mesh polygonize(int threads, const RunControl& control, ParticleSurfacingStats& stats) const;
  // "laplacian" .. "erosion": the constrained smoothing of the polygonized mesh.
  void smooth(Mesh& mesh, int threads, const RunControl& control, ParticleSurfacingStats& stats);
};

namespace {

// A band of 1.25 h keeps every crossed lattice edge of the initial surface exact: every lattice edge is shorter
// than 1.07 h (A15 edges are 2, sqrt 5 and sqrt 6 lattice units, mean 2.30).
constexpr double kFieldBandSpacings = 1.25;

// The smoothing stages over one mesh (thesis Fig. 3.2, steps 3-7). The Laplacian stage moves vertices freely (its
// point is to even out the triangles), and step 4 brings them into the band along their normals; from then on every
// vertex moves along its normal only, x = x0 + t n, and the band becomes one interval of t per vertex, computed exactly
// once (Particles::band_on_line), so the constrained sweeps clamp instead of searching for particles
// (docs/ALGORITHMS.md §1, CHOICE "constrained stages along the normals").
class Smoother {
 public:
  // Gauss-Seidel over-relaxation of the constrained and polish sweeps (projected SOR; 1 is the thesis' plain GS).
  // 1.7 with 15 sweeps reaches a lower energy than 1.4 with 25 (docs/ALGORITHMS.md §1, CHOICE "over-relaxed sweeps").
  static constexpr double kOverRelaxation = 1.7;

  Smoother(Mesh& mesh, const ParticleSurfacingOptions& options, const Particles& particles, int threads)
      : mesh_(mesh),
        positions_(mesh.vertices),
        vertex_count_(positions_.size()),
        options_(options),
        particles_(particles),
        threads_(threads),
        ring_(ps::one_ring(vertex_count_, mesh.triangles, threads)),
        blocks_(ps::default_block_count(vertex_count_)) {
    container_.box = options_.container_box;
    container_.solid = options_.container_solid.get();
    container_.inside_margin = 1e-9 * particles_.r_inner;
  }

  const ps::Graph& ring() const { return ring_; }

  // Step 3, then the projection of every vertex into the band (and the container).
  void laplacian(const RunControl& control) {
    const ps::SweepPlan plan = ps::plan_sweeps(ring_, blocks_);
    for (int s = 0; s < options_.laplacian_sweeps; ++s) {
      control.check();
      ps::laplacian_sweep(positions_, ring_, options_.relaxation, plan, threads_);
      control.report("laplacian", (s + 1.0) / options_.laplacian_sweeps);
    }
    control.check();
    // The thesis' projection; else every vertex is brought into the band along its normal in step 4.
    if (options_.vertex_only_band) constrain(true);
  }

  // Step 4 (with the end of step 3): the normals fixed; every vertex brought into the band along its normal, its
  // interval of the band there, lowered below the cusps it holds, and the start moved onto the cusps' planes; then
  // B = W^T D^-1 W (through W and D) of that start, for moves along the normals. From here until place() the mesh's
  // vertex array holds the start x0: where step 3 left the vertices is not needed again, and is freed.
  void build_b(const RunControl& control, ParticleSurfacingStats& stats) {
    normals_ = smoothed_normals();
    {
      std::vector<Vec3> start(
          vertex_count_);  // written in parallel by intervals(): first touched by the threads that use it
      intervals(start, control, stats);
      positions_.swap(start);
    }
    if (!options_.vertex_only_band) descend(control);
    smoothing_.emplace(ring_, mesh_.triangles, positions_, normals_, blocks_, threads_, control);
    stats.seam_fraction =
        vertex_count_ > 0 ? static_cast<double>(smoothing_->plan().seams.size()) / static_cast<double>(vertex_count_)
                          : 0.0;
    control.report("build_b", 1.0);
  }

  // Step 5: sweeps clamped to the band, then the faithfulness after them.
  void bilaplacian(const RunControl& control, ParticleSurfacingStats& stats) {
    for (int s = 0; s < options_.bilaplacian_sweeps; ++s) {
      control.check();
      smoothing_->sweep(lo_, hi_, kOverRelaxation, threads_);
      control.report("bilaplacian", (s + 1.0) / options_.bilaplacian_sweeps);
    }
    faithfulness(stats.faithful_after_constrained, stats.max_violation_after_constrained);
  }

  // Step 6: sweeps clamped to the container only, then (unless the thesis' unconstrained polish is asked for) the
  // final projection: every offset back into its interval, a move along the normal (docs/ALGORITHMS.md §1, CHOICE
  // "faithful at the end").
  void polish(const RunControl& control, ParticleSurfacingStats& stats) {
    offsets_.assign(smoothing_->offsets().begin(), smoothing_->offsets().end());  // before the sweeps
    for (int s = 0; s < options_.polish_sweeps; ++s) {
      control.check();
      smoothing_->sweep(container_lo_, container_hi_, kOverRelaxation, threads_);
      control.report("polish", (s + 1.0) / options_.polish_sweeps);
    }
    faithfulness(stats.faithful_after_polish_sweeps, stats.max_violation_after_polish_sweeps);
    if (!options_.unconstrained_polish) stats.max_final_projection = smoothing_->clamp(lo_, hi_);
    const std::span<const double> t = smoothing_->offsets();
    for (std::size_t i = 0; i < vertex_count_; ++i) {
      stats.max_polish_displacement = std::max(stats.max_polish_displacement, std::abs(t[i] - offsets_[i]));
    }
    std::copy(t.begin(), t.end(), offsets_.begin());
    place();
    // What the sweeps needed goes before the cleanup stage: the final offsets and the band (lo_, hi_ and the
    // exceptions) are all that is read later.
    smoothing_.reset();
    release(normals_);
    release(container_lo_);
    release(container_hi_);
  }

  // Step 7, when asked for.
  void erosion(const RunControl& control, ParticleSurfacingStats& stats) {
    control.check();
    const std::vector<Vec3> before = positions_;
    const std::vector<Vec3> normals = ps::vertex_normals(positions_, mesh_.triangles, threads_);
    const double depth = *options_.erosion * particles_.r_inner;
    for (std::size_t i = 0; i < vertex_count_; ++i) positions_[i] -= depth * normals[i];
    constrain(false);
    for (std::size_t i = 0; i < vertex_count_; ++i) {
      stats.max_polish_displacement = std::max(stats.max_polish_displacement, (positions_[i] - before[i]).norm());
    }
    control.report("erosion", 1.0);
  }

  // Moves x into the band along n (or, when no point of that line within reach is faithful, to the band's nearest
  // point), then into the container; for the sliver repair's vertex moves, false when x does not end faithful (a
  // container wall in the way).
  bool place_in_band(Vec3& x, const Vec3& n) const {
    BandScratch scratch;
    project_along(x, n, scratch);
    if (container_.active()) container_.project(x);
    return particles_.faithful(particles_.weighted ? particles_.violation(x) : particles_.violation_uniform(x));
  }

  // The figures of the final surface.
  void finish(ParticleSurfacingStats& stats) {
    if (options_.erosion && *options_.erosion > 0.0) {
      measure(stats.faithful_after_polish, stats.max_violation_after_polish);  // erosion leaves the band on purpose
    } else {
      faithfulness(stats.faithful_after_polish, stats.max_violation_after_polish);
    }
  }

 private:
  // Area-weighted vertex normals averaged once over the 1-ring: the r_outer start is corrugated at the particle
  // scale, and these tilt less with it.
  std::vector<Vec3> smoothed_normals() const {
    const std::vector<Vec3> raw = ps::vertex_normals(positions_, mesh_.triangles, threads_);
    std::vector<Vec3> out(vertex_count_);
    for_chunks(vertex_count_, threads_, [&](std::size_t begin, std::size_t end) {
      for (std::size_t i = begin; i < end; ++i) {
        Vec3 sum = raw[i];
        for (std::uint32_t e = ring_.offsets[i]; e < ring_.offsets[i + 1]; ++e) sum += raw[ring_.cols[e]];
        const double len = sum.norm();
        out[i] = len > 0.0 ? Vec3(sum / len) : raw[i];
      }
    });
    return out;
  }

  // Every vertex's start x0, its line's faithful point nearest to where step 3 left it (docs/ALGORITHMS.md §1, CHOICE
  // "projection along the normals"; the thesis' projection when the line has none within reach), then the container;
  // and its interval of offsets along its normal there: the band's (exact, once), its upper end lowered below the
  // lowest cusp the vertex holds (unless vertex_only_band), and the container box's; the constrained sweeps use their
  // intersection. A vertex holds the cusps of its Voronoi cell among its 1-ring (as step 3 left them), within its
  // longest 1-ring edge of its start; the root mean square edge (summed per vertex, then in vertex order) sets the
  // descent's passes.
  void intervals(std::vector<Vec3>& x0, const RunControl& control, ParticleSurfacingStats& stats) {
    std::mutex exceptions_mutex;
    lo_.resize(vertex_count_);
    hi_.resize(vertex_count_);
    if (container_.box) {  // else every vertex's container interval is the whole line, and none is stored
      container_lo_.resize(vertex_count_);
      container_hi_.resize(vertex_count_);
    }
    const bool cusps = !options_.vertex_only_band;
    if (cusps) cusp_.resize(vertex_count_);
    std::vector<double> edge_sum(cusps ? vertex_count_ : 0);
    const double reach = this->reach();
    std::atomic<std::size_t> cusp_vertices{0};
    for_chunks(vertex_count_, threads_, [&](std::size_t begin, std::size_t end) {
      control.check();
      BandScratch scratch;
      std::size_t lowered = 0;
      std::vector<BandException> exceptions;
      for (std::size_t i = begin; i < end; ++i) {
        // Every vertex: one cusp search can take milliseconds where many outer spheres pass near it (kMaxCuspSpheres
        // of them: about 15 ms), so 64 of them could keep a cancelled job past half a second; a check is one load.
        control.check();
        const Vec3& at = positions_[i];  // where step 3 left it
        const Vec3& n = normals_[i];
        double cell = 0.0;
        if (cusps) {
          double sum = 0.0, longest = 0.0;  // squared lengths
          for (std::uint32_t e = ring_.offsets[i]; e < ring_.offsets[i + 1]; ++e) {
            const double length2 = (positions_[ring_.cols[e]] - at).squaredNorm();
            longest = std::max(longest, length2);
            sum += length2;
          }
          cell = std::sqrt(longest);
          edge_sum[i] = sum;
        }
        // The band at a point placed otherwise than along the line: empty when that point is not faithful.
        const auto band_at = [&](const Vec3& y, double cusp_cell) {
          const std::optional<Particles::LineBand> there = particles_.band_on_line(y, n, reach, cusp_cell, scratch);
          return there && there->at == 0.0 ? there->band : Interval{0.0, 0.0};
        };
        Vec3 x = at;
        Interval band;
        if (const std::optional<Particles::LineBand> line = particles_.band_on_line(at, n, reach, cell, scratch)) {
          x += line->at * n;
          band = line->band;
        } else {  // no faithful point of the line within reach: the thesis' projection
          particles_.project_any(x);
          band = band_at(x, cell);
        }
        if (container_.active()) {
          Vec3 inside = x;
          container_.project(inside);
          if (inside != x) {  // the wall wins; no cusp is held there
            x = inside;
            band = band_at(x, 0.0);
            scratch.spheres.clear();
            scratch.deeper.clear();
          }
        }
        x0[i] = x;
        double hi = band.hi;
        if (cusps) {
          // Owned by i: no 1-ring neighbour is nearer, all as step 3 left them (a tie gives the cusp to both).
          const auto owns = [&](const Vec3& q) {
            const double mine = (q - at).squaredNorm();
            for (std::uint32_t e = ring_.offsets[i]; e < ring_.offsets[i + 1]; ++e) {
              if ((q - positions_[ring_.cols[e]]).squaredNorm() < mine) return false;
            }
            return true;
          };
          // The search is cubic in the spheres around the vertex: past kMaxCuspSpheres (a cluster far denser than
          // any fluid, CHOICE "coincident particles merged") the vertex holds none.
          const std::optional<HeldCusp> held =
              scratch.spheres.size() <= kMaxCuspSpheres
                  ? lowest_cusp(x, n, cell, scratch.spheres, scratch.deeper, owns, scratch.circles)
                  : std::nullopt;
          cusp_[i] = held ? held->plane : CuspPlane{};
          // A cusp below the inner edge: the vertex waits there (eq. 3.5 does not hold around it).
          if (held && held->bound < hi) {
            hi = std::max(band.lo, held->bound);
            ++lowered;
          }
        }
        double container_lo = -kInf, container_hi = kInf;
        if (container_.box) {
          for (int a = 0; a < 3; ++a) {
            const double na = normals_[i][a];
            if (na == 0.0) continue;
            double t0 = (container_.box->min[a] - x[a]) / na, t1 = (container_.box->max[a] - x[a]) / na;
            if (t0 > t1) std::swap(t0, t1);
            container_lo = std::max(container_lo, std::min(t0, 0.0));
            container_hi = std::min(container_hi, std::max(t1, 0.0));
          }
          container_lo_[i] = container_lo;
          container_hi_[i] = container_hi;
        }
        lo_[i] = std::max(band.lo, container_lo);
        hi_[i] = std::min(hi, container_hi);
        if (lo_[i] > hi_[i]) lo_[i] = hi_[i] = std::clamp(0.0, container_lo, container_hi);  // the wall wins
        if (band.lo != lo_[i] || band.hi != hi_[i]) {
          exceptions.push_back({static_cast<std::uint32_t>(i), band.lo, band.hi});
        }
      }
      cusp_vertices += lowered;
      const std::lock_guard lock(exceptions_mutex);
      band_exceptions_.insert(band_exceptions_.end(), exceptions.begin(), exceptions.end());
    });
    std::sort(band_exceptions_.begin(), band_exceptions_.end(),
              [](const BandException& a, const BandException& b) { return a.vertex < b.vertex; });
    stats.cusp_vertices = cusp_vertices.load();
    if (cusps) {
      double total = 0.0;
      for (const double sum : edge_sum) total += sum;
      const std::size_t entries = ring_.cols.size();
      rms_edge_ = entries > 0 ? std::sqrt(total / static_cast<double>(entries)) : 0.0;
    }
  }

  // The start of the constrained sweeps on the planes of the cusps held (docs/ALGORITHMS.md §1, CHOICE "a start on
  // the cusps' planes"): every held cusp's plane equation (axis, offset) is summed over `passes` rounds of 1-ring sums,
  // enough rounds to cover r_outer, and every vertex that some cusp reached moves along its normal onto the summed
  // plane, clamped into its interval. x0 moves with it, the intervals shift by the move (the same lines), so the sweeps
  // start at offset 0 again. Sums in a fixed order per vertex: the same start whatever the threads.
  void descend(const RunControl& control) {
    if (vertex_count_ == 0 || !(rms_edge_ > 0.0)) return;
    const double outer = particles_.weighted ? particles_.max_outer : particles_.r_outer;
    const int passes = static_cast<int>(std::clamp(std::ceil(outer / rms_edge_), 1.0, double{kMaxDescentPasses}));
    Buffer<CuspPlane> next(vertex_count_);
    for (int pass = 0; pass < passes; ++pass) {
      control.check();
      for_chunks(vertex_count_, threads_, [&](std::size_t begin, std::size_t end) {
        for (std::size_t i = begin; i < end; ++i) {
          Eigen::Vector4d sum = cusp_[i].equation;
          for (std::uint32_t e = ring_.offsets[i]; e < ring_.offsets[i + 1]; ++e) sum += cusp_[ring_.cols[e]].equation;
          next[i].equation = sum;
        }
      });
      std::swap(cusp_, next);
    }
    for_chunks(vertex_count_, threads_, [&](std::size_t begin, std::size_t end) {
      for (std::size_t i = begin; i < end; ++i) {
        const Vec3 axis = cusp_[i].axis();
        const double facing = axis.dot(normals_[i]);
        if (!(facing > 0.0 && facing >= kCuspFacing * axis.norm())) continue;  // none near, or facing away
        const double move = std::clamp((cusp_[i].offset() - axis.dot(positions_[i])) / facing, lo_[i], hi_[i]);
        positions_[i] += move * normals_[i];
        for (Buffer<double>* bound : {&lo_, &hi_, &container_lo_, &container_hi_}) {
          if (!bound->empty()) (*bound)[i] -= move;  // the container's are empty without a box (the whole line)
        }
        if (BandException* band = band_exception(i)) {
          band->lo -= move;
          band->hi -= move;
        }
      }
    });
    release(cusp_);
  }

  // x = x0 + t n (and the container solid, which wins over the band).
  void place() {
    const std::span<const double> t = smoothing_->offsets();
    for_chunks(vertex_count_, threads_, [&](std::size_t begin, std::size_t end) {
      for (std::size_t i = begin; i < end; ++i) positions_[i] += t[i] * normals_[i];  // x0 + t n
    });
    if (container_.solid != nullptr) constrain(false);
  }

  // The fraction of vertices inside the band and the largest distance outside it, from the exact intervals: a vertex
  // whose offset lies in its band interval is faithful (up to rounding); one outside it is off by its distance to the
  // interval along its normal, at least as far as it is from the band.
  void faithfulness(double& fraction, double& max_violation) const {
    const std::span<const double> t = smoothing_ ? smoothing_->offsets() : std::span<const double>(offsets_);
    std::size_t good = 0;
    double worst = 0.0;
    auto exception = band_exceptions_.begin();
    for (std::size_t i = 0; i < vertex_count_; ++i) {
      double band_lo = lo_[i], band_hi = hi_[i];
      if (exception != band_exceptions_.end() && exception->vertex == i) {
        band_lo = exception->lo;
        band_hi = exception->hi;
        ++exception;
      }
      const double v = std::max({band_lo - t[i], t[i] - band_hi, 0.0});
      good += v == 0.0;
      worst = std::max(worst, v);
    }
    fraction = vertex_count_ > 0 ? static_cast<double>(good) / static_cast<double>(vertex_count_) : 1.0;
    max_violation = worst;
  }

  // x to the nearest faithful point of the line x + t n, |t| <= reach; without one, the thesis' projection to the
  // band's nearest point.
  void project_along(Vec3& x, const Vec3& n, BandScratch& scratch) const {
    if (const std::optional<Particles::LineBand> line = particles_.band_on_line(x, n, reach(), 0.0, scratch)) {
      x += line->at * n;
    } else {
      particles_.project_any(x);
    }
  }
  // From the outer edge of the band to its inner edge (with per-particle radii, the widest such span: equal radii
  // give the uniform intervals).
  double reach() const { return particles_.max_outer - particles_.min_inner; }

  // The particle band (when `to_particles`) and the container, on every vertex.
  void constrain(bool to_particles) {
    if (!to_particles && !container_.active()) return;
    for_chunks(vertex_count_, threads_, [&](std::size_t begin, std::size_t end) {
      for (std::size_t i = begin; i < end; ++i) {
        if (to_particles) particles_.project_any(positions_[i]);
        if (container_.active()) container_.project(positions_[i]);
      }
    });
  }

  // The exact fraction of vertices inside the band and the largest distance outside it (nearest-particle queries).
  void measure(double& fraction, double& max_violation) {
    std::mutex mutex;
    std::size_t good_total = 0;
    double worst_total = 0.0;
    for_chunks(vertex_count_, threads_, [&](std::size_t begin, std::size_t end) {
      std::size_t good = 0;
      double worst = 0.0;
      for (std::size_t i = begin; i < end; ++i) {
        const double v =
            particles_.weighted ? particles_.violation(positions_[i]) : particles_.violation_uniform(positions_[i]);
        good += particles_.faithful(v);
        worst = std::max(worst, v);
      }
      const std::lock_guard lock(mutex);
      good_total += good;
      worst_total = std::max(worst_total, worst);
    });
    fraction = vertex_count_ > 0 ? static_cast<double>(good_total) / static_cast<double>(vertex_count_) : 1.0;
    max_violation = worst_total;
  }

  Mesh& mesh_;
  std::vector<Vec3>& positions_;
  const std::size_t vertex_count_;
  const ParticleSurfacingOptions& options_;
  const Particles& particles_;
  const int threads_;
  const ps::Graph ring_;
  const std::size_t blocks_;
  Container container_;
  std::vector<Vec3> normals_;
  Buffer<CuspPlane> cusp_;  // per vertex, the plane of the lowest cusp it holds (zero: none), until the descent
  double rms_edge_ = 0.0;   // of the mesh at step 4
  std::optional<ps::OffsetSmoothing> smoothing_;
  std::vector<double> offsets_;  // polish: the offsets before its sweeps, then the final ones (the smoothing is gone)
  // Per vertex, its interval of offsets for the constrained sweeps, and the container box's (empty without one).
  Buffer<double> lo_, hi_, container_lo_, container_hi_;
  // Its band interval, stored only where it differs from (lo_, hi_): a cusp below the band's upper end, or a wall
  // (7 % of the block's vertices), sorted by vertex.
  struct BandException {
    std::uint32_t vertex;
    double lo, hi;
  };
  std::vector<BandException> band_exceptions_;
  BandException* band_exception(std::size_t vertex) {
    const auto it = std::lower_bound(band_exceptions_.begin(), band_exceptions_.end(), vertex,
                                     [](const BandException& e, std::size_t v) { return e.vertex < v; });
    return it != band_exceptions_.end() && it->vertex == vertex ? &*it : nullptr;
  }
};

}  // namespace

void ParticleSurfacer::State::check_inputs(std::span<const Vec3> input, std::span<const double> radii) const {
  for (std::size_t i = 0; i < input.size(); ++i) {
    if (!input[i].allFinite()) {
      throw InvalidInput("particles", "particle " + std::to_string(i) + " has a non-finite coordinate; remove it");
    }
  }
  if (!radii.empty() && radii.size() != input.size()) {
    throw InvalidInput("radii", "radii has " + std::to_string(radii.size()) + " values for " +
                                    std::to_string(input.size()) + " particles; give one per particle or none");
  }
  for (std::size_t i = 0; i < radii.size(); ++i) {
    if (!(std::isfinite(radii[i]) && radii[i] > 0.0)) {
      throw InvalidInput("radii",
                         "radius " + std::to_string(i) + " (" + format_number(radii[i]) + ") must be finite and > 0");
    }
  }
  require_r_inner_source(!radii.empty(), options.r_inner.has_value(), options.derive_r_inner);
}

void ParticleSurfacer::State::distance_field(std::span<const Vec3> input, std::span<const double> radii, int threads,
                                             const RunControl& control, ParticleSurfacingStats& stats) {
  const ParticleSurfacingOptions& o = options;
  control.report("distance_field", 0.0);
  Particles& P = particles;
  P.weighted = !radii.empty();
  double r_inner = 0.0;
  if (P.weighted) {
    if (o.r_inner) {
      r_inner = *o.r_inner;
    } else {  // the median (the upper one of an even count): a few radii far from the rest do not move it
      std::vector<double> sorted(radii.begin(), radii.end());
      std::nth_element(sorted.begin(), sorted.begin() + static_cast<std::ptrdiff_t>(sorted.size() / 2), sorted.end());
      r_inner = sorted[sorted.size() / 2];
    }
  } else {
    r_inner = o.r_inner ? *o.r_inner : derive_r_inner(input, threads, control);
  }
  const double r_outer = o.r_outer ? *o.r_outer : ParticleSurfacingOptions::kDefaultOuterRatio * r_inner;
  if (!(r_outer > r_inner)) {
    throw InvalidInput("r_outer", "r_outer (" + format_number(r_outer) + ") must exceed r_inner (" +
                                      format_number(r_inner) + (o.r_inner ? ")" : ", derived)") + "; the default is " +
                                      format_number(ParticleSurfacingOptions::kDefaultOuterRatio) + " x r_inner");
  }
  const double ratio = r_outer / r_inner;
  const double h = o.spacing_factor * r_inner;
  stats.r_inner = r_inner;
  stats.r_outer = r_outer;
  stats.spacing = h;
  P.r_inner = r_inner;
  P.r_outer = r_outer;
  P.positions = input;
  release(P.edited);  // a previous frame's
  P.inner.clear();
  P.outer.clear();
  if (P.weighted) {
    P.inner.assign(radii.begin(), radii.end());
    P.outer.resize(radii.size());
    for (std::size_t i = 0; i < radii.size(); ++i) P.outer[i] = ratio * radii[i];
    const auto [smallest, largest] = std::minmax_element(P.inner.begin(), P.inner.end());
    P.min_inner = *smallest;
    P.max_inner = *largest;
    P.max_outer = ratio * P.max_inner;
  } else {
    P.min_inner = P.max_inner = r_inner;
    P.max_outer = r_outer;
  }
  const double field_band = kFieldBandSpacings * h;
  P.index(field_band);
  std::vector<std::uint32_t> weight;  // per particle, the input particles it stands for; empty: one each
  if (const double tolerance = kCoincidentTolerance * r_inner; P.any_pair_within(tolerance, control)) {
    weight = merge_coincident(P, tolerance, control);
    P.index(field_band);
  }

  if (o.min_particles_per_component > 1) {
    const std::vector<char> keep =
        filter_components(P, o.min_particles_per_component, weight, stats.components_dropped, control);
    if (stats.components_dropped > 0) {
      std::size_t k = 0;
      std::vector<Vec3> positions;
      positions.reserve(static_cast<std::size_t>(std::count(keep.begin(), keep.end(), 1)));
      for (std::size_t i = 0; i < P.positions.size(); ++i) {
        if (!keep[i]) continue;
        positions.push_back(P.positions[i]);
        if (P.weighted) {
          P.inner[k] = P.inner[i];
          P.outer[k] = P.outer[i];
        }
        if (!weight.empty()) weight[k] = weight[i];
        ++k;
      }
      P.replace_positions(std::move(positions));
      if (P.weighted) {
        P.inner.resize(k);
        P.outer.resize(k);
      }
      if (!weight.empty()) weight.resize(k);
      if (k > 0) P.index(field_band);
    }
  }
  stats.particles_used =
      weight.empty() ? P.positions.size() : std::accumulate(weight.begin(), weight.end(), std::size_t{0});
  control.report("distance_field", 1.0);
}

Mesh ParticleSurfacer::State::polygonize(int threads, const RunControl& control, ParticleSurfacingStats& stats) const {
  const Particles& P = particles;
  const double h = stats.spacing;
  require_room_for_largest_ball(P, h, control);
  const ParticleField field(P, kFieldBandSpacings * h, threads);
  MarchingTilesOptions mt;
  mt.bounds = P.box.padded(P.max_outer + 2.0 * h);
  mt.spacing = h;
  mt.threads = threads;
  mt.seeds = P.positions;
  mt.seed_radius = (P.weighted ? 0.0 : P.r_outer) + h;
  if (P.weighted) mt.seed_radii = P.outer;  // each particle's own reach
  stats.seeds = mt.seeds.size();
  Mesh mesh = marching_tiles(field, mt, control);
  stats.field_evaluations = field.evaluations();
  stats.initial_vertices = mesh.vertices.size();
  stats.initial_triangles = mesh.triangles.size();
  return mesh;
}

void ParticleSurfacer::State::smooth(Mesh& mesh, int threads, const RunControl& control,
                                     ParticleSurfacingStats& stats) {
  const ParticleSurfacingOptions& o = options;
  Clock::time_point t0 = Clock::now();
  mesh.normals.clear();
  Smoother smoother(mesh, o, particles, threads);
  give_back_memory(stats);  // the 1-ring's buckets
  stats.initial_min_valence = min_valence(smoother.ring());
  smoother.laplacian(control);
  stats.seconds_laplacian = seconds_since(t0);
  t0 = Clock::now();
  smoother.build_b(control, stats);
  stats.seconds_build_b = seconds_since(t0);
  t0 = Clock::now();
  smoother.bilaplacian(control, stats);
  stats.seconds_bilaplacian = seconds_since(t0);
  t0 = Clock::now();
  smoother.polish(control, stats);
  give_back_memory(stats);
  stats.seconds_polish = seconds_since(t0);
  if (o.erosion && *o.erosion > 0.0) {
    t0 = Clock::now();
    smoother.erosion(control, stats);
    stats.seconds_erosion = seconds_since(t0);
  }
  smoother.finish(stats);
  t0 = Clock::now();
  control.check();
  stats.bubbles_dropped = drop_bubbles(mesh, particles, 2.0 * particles.min_inner);
  if (o.min_angle_degrees > 0.0 || o.output_grid) {
    SliverOptions slivers;
    slivers.min_angle_degrees = o.min_angle_degrees;
    slivers.grid = o.output_grid;
    slivers.threads = threads;
    // A vertex the repair moves lands in the band again (not after erosion, which leaves it on purpose).
    if (!(o.erosion && *o.erosion > 0.0)) {
      slivers.place = [&smoother](std::uint32_t, Vec3& x, const Vec3& n) { return smoother.place_in_band(x, n); };
    }
    const SliverReport r = repair_slivers(mesh, slivers, control);
    stats.slivers_found = r.candidates;
    stats.sliver_flips = r.flips;
    stats.sliver_collapses = r.collapses;
    stats.sliver_moves = r.moves;
    stats.slivers_left = r.remaining;
  }
  stats.seconds_cleanup = seconds_since(t0);
  control.report("cleanup", 1.0);
  if (o.normals) mesh.normals = ps::vertex_normals(mesh.vertices, mesh.triangles, threads);
}

Mesh ParticleSurfacer::State::run(std::span<const Vec3> input, std::span<const double> radii, const RunControl& control,
                                  ParticleSurfacingStats* stats_out, bool initial_only) {
  const int threads = resolve_threads(options.threads);
  ParticleSurfacingStats stats;
  const Clock::time_point t_start = Clock::now();
  stats.particles = input.size();
  auto finish = [&](Mesh mesh) {
    stats.vertices = mesh.vertices.size();
    stats.triangles = mesh.triangles.size();
    stats.seconds_total = seconds_since(t_start);
    if (stats_out != nullptr) *stats_out = stats;
    return mesh;
  };

  control.check();
  check_inputs(input, radii);
  if (input.empty()) return finish({});

  // particles.positions views `input` (the caller's) for this run only: the view goes when the run returns or throws,
  // so a surfacer kept for the next frame holds no pointer into this one's array.
  struct ForgetInput {
    Particles& P;
    ~ForgetInput() { P.positions = {}; }
  } forget_input{particles};
  Clock::time_point t0 = Clock::now();
  distance_field(input, radii, threads, control, stats);
  // Each stage's scratch goes back to the system before the next one's arrays (docs/ALGORITHMS.md §1, CHOICE
  // "memory returned between stages").
  give_back_memory(stats);
  stats.seconds_distance_field = seconds_since(t0);
  if (particles.positions.empty()) return finish({});

  t0 = Clock::now();
  Mesh mesh = polygonize(threads, control, stats);
  give_back_memory(stats);  // the tiles' block outputs: many small blocks, which the smoothing's arrays would not reuse
  stats.seconds_polygonize = seconds_since(t0);
  if (initial_only) {
    stats.initial_min_valence = min_valence(ps::one_ring(mesh.vertices.size(), mesh.triangles, threads));
    return finish(std::move(mesh));
  }

  smooth(mesh, threads, control, stats);
  return finish(std::move(mesh));
}

ParticleSurfacer::ParticleSurfacer(const ParticleSurfacingOptions& options) : state_(std::make_unique<State>()) {
  validate(options);
  state_->options = options;
}
ParticleSurfacer::~ParticleSurfacer() = default;
ParticleSurfacer::ParticleSurfacer(ParticleSurfacer&&) noexcept = default;
ParticleSurfacer& ParticleSurfacer::operator=(ParticleSurfacer&&) noexcept = default;

const ParticleSurfacingOptions& ParticleSurfacer::options() const { return state_->options; }

Mesh ParticleSurfacer::surface(std::span<const Vec3> particles, std::span<const double> radii,
                               const RunControl& control, ParticleSurfacingStats* stats) {
  return state_->run(particles, radii, control, stats, false);
}

Mesh ParticleSurfacer::initial_surface(std::span<const Vec3> particles, std::span<const double> radii,
                                       const RunControl& control, ParticleSurfacingStats* stats) {
  return state_->run(particles, radii, control, stats, true);
}

Mesh surface_particles(std::span<const Vec3> particles, std::span<const double> radii,
                       const ParticleSurfacingOptions& options, const RunControl& control,
                       ParticleSurfacingStats* stats) {
  return ParticleSurfacer(options).surface(particles, radii, control, stats);
}

Mesh initial_particle_surface(std::span<const Vec3> particles, std::span<const double> radii,
                              const ParticleSurfacingOptions& options, const RunControl& control,
                              ParticleSurfacingStats* stats) {
  return ParticleSurfacer(options).initial_surface(particles, radii, control, stats);
}

Aabb particle_sequence_box(const Aabb& particle_bounds, double max_radius, std::optional<double> r_inner,
                           std::optional<double> r_outer, const std::function<std::vector<Vec3>()>& first_frame,
                           const std::optional<Aabb>& container) {
  constexpr double kDerivedPadSafety = 3.0;
  Aabb box = particle_bounds;
  const double ratio = r_outer && r_inner ? *r_outer / *r_inner : ParticleSurfacingOptions::kDefaultOuterRatio;
  double pad = 0.0;
  if (max_radius > 0.0) {
    pad = ratio * max_radius;
  } else if (r_inner) {
    pad = r_outer.value_or(ParticleSurfacingOptions::kDefaultOuterRatio * *r_inner);
  } else {
    // The spacing derive_r_inner finds, the one the frames are surfaced with (the one estimator of it).
    const double spacing = derive_r_inner(first_frame(), 0, {});
    pad = kDerivedPadSafety * ratio * std::max(spacing, 1e-6 * std::max(box.size().maxCoeff(), 1.0));
  }
  box = box.padded(1.5 * pad);
  if (container) {
    // A wall that misses the particles' reach would flatten the whole surface onto itself, outside this box.
    if (!Aabb(box).intersect(*container).valid()) {
      throw InvalidInput("container_box", "container_box (min " + format_point(container->min) + ", max " +
                                              format_point(container->max) + ") does not overlap the particles' " +
                                              "surface (within min " + format_point(box.min) + ", max " +
                                              format_point(box.max) + "); give a box around the fluid");
    }
    box.intersect(*container);
  }
  return box;
}

}  // namespace surfacer
