// The particles of a surfacing run and the searches over them (docs/ALGORITHMS.md §1): nearest particles, the band
// along a vertex's normal, the outer balls a cusp search needs. Used by core/particles/particle_surfacer.cpp; a header
// of its own so that tests can hold the searches over tiers against the search of one tier.
//
// Per-particle radii are indexed in tiers (CHOICE "radius tiers"): a tier holds the particles whose outer radius is
// within kTierSpread of the tier's smallest, in a spatial hash whose cell follows the tier's largest radius. A query
// scans each tier's hash as far as that tier's own largest radius reaches, so one particle whose radius is far above
// the rest adds a short scan of its own tier instead of widening every scan to its radius.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <optional>
#include <span>
#include <utility>
#include <vector>

#include "core/mesh/mesh.h"
#include "core/particles/cusp_search.h"
#include "core/particles/spatial_hash.h"
#include "core/util/run_control.h"

namespace surfacer::particle_index {

constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr double kBandTolerance = 1e-12;     // relative slack before a projection moves a vertex
constexpr double kFaithfulTolerance = 1e-9;  // relative slack of the faithfulness statistics
constexpr int kMaxProjectionRounds = 8;
// Relative slack of the box tests by which a band query skips particles that cannot matter (Particles::band_on_line):
// far above the rounding of a chord's ends (~1e-8 of the query's reach, the square root of a cancelling difference).
constexpr double kSkipSlack = 1e-6;
// The first radius of a nearest-particle search, in r_outer (Particles::nearest).
constexpr double kFirstSearch = 1.25;
// Radius tiers (CHOICE "radius tiers"): a tier spans outer radii from its smallest to this many times it; at most
// kMaxTiers tiers, the last taking every larger radius.
constexpr double kTierSpread = 2.0;
constexpr std::size_t kMaxTiers = 16;
// A band query's segment longer than two of a tier's largest r_outer is read from that tier in pieces about that
// long (at most this many), so that a long window costs the tube around the line, not the box around it
// (Particles::band_in_window).
constexpr std::uint32_t kMaxPieces = 256;
// A band query's window grows by this factor while its answer touches the window's ends (Particles::band_on_line):
// on droplets with one radius 100x, and on scattered particles of radii spread over a decade, 4 took 0.8x and 0.8x
// the time of 2 to build the bands, and 8 no less than 4.
constexpr double kWindowGrowth = 4.0;

struct Interval {
  double lo = 0.0, hi = 0.0;
};

// A slot range [begin, end) of one tier's hash, read for one piece of a band query's segment.
struct SlotRange {
  std::uint32_t tier, piece, begin, end;
};

// The pieces a tier's share of a band query's segment |t| <= window is read in (Particles::band_in_window): `count`
// pieces of equal length, or one, the whole segment.
struct LinePieces {
  double window = 0.0, length = 0.0;
  std::uint32_t count = 1;

  // The half length of a piece and its centre's offset along the line (the whole segment: exactly window and 0).
  double half() const { return count == 1 ? window : 0.5 * length; }
  double centre(std::uint32_t j) const { return count == 1 ? 0.0 : -window + (j + 0.5) * length; }
  // The piece that holds offset s clamped into the segment: the one that reads a particle whose foot is at s.
  std::uint32_t of(double s) const {
    if (count == 1) return 0;
    const double u = (std::clamp(s, -window, window) + window) / length;
    return std::min(count - 1, static_cast<std::uint32_t>(u));
  }
};

// A thread's scratch for band queries.
struct BandScratch {
  std::vector<Interval> allowed, forbidden;
  std::vector<double> ends;
  // The particles whose outer balls meet a line: t along it of the foot (-b) and squared distance c, and their radii.
  struct Chord {
    double b, c, inner, outer;
  };
  std::vector<Chord> chords;
  // The outer balls within their radius + cell of the vertex: those whose sphere passes within cell of it, and those
  // deeper around it.
  std::vector<particle_cusps::Ball> spheres, deeper;
  std::vector<particle_cusps::Circle> circles;  // lowest_cusp's
  // The tiers' slot ranges a band query reads, by tier and piece, each piece's in ascending order, and per tier the
  // pieces they were read for (Particles::band_in_window).
  std::vector<SlotRange> ranges;
  std::vector<LinePieces> pieces;
};

// The particles of one tier in a spatial hash, with their radii in slot order (per-particle radii).
struct Tier {
  SpatialHash hash;
  std::vector<std::uint32_t> index;            // hash input index -> particle; empty: the same (a single tier)
  std::vector<double> slot_inner, slot_outer;  // per slot; empty for uniform radii
  double max_inner = 0.0, max_outer = 0.0;

  std::uint32_t particle(std::uint32_t slot) const {
    const std::uint32_t i = hash.order()[slot];
    return index.empty() ? i : index[i];
  }
};

struct Particles {
  // The particles in use, in input order: a view of the caller's array for the run, or of `edited` once coincident
  // particles were merged or small components dropped (no copy of the input otherwise).
  std::span<const Vec3> positions;
  std::vector<Vec3> edited;
  std::vector<double> inner, outer;  // per particle; empty when uniform
  bool weighted = false;
  double r_inner = 0.0, r_outer = 0.0;  // uniform radii, or (weighted) the reference r_inner and ratio * it
  double min_inner = 0.0, max_inner = 0.0, max_outer = 0.0;
  Aabb box;
  // Uniform radii: one tier. Per-particle radii: by outer radius, smallest first (see the top of this file).
  std::vector<Tier> tiers;
  std::size_t main_tier = 0;  // the tier holding the most particles (the first such)

  // `kept` becomes the particles in use.
  void replace_positions(std::vector<Vec3> kept) {
    edited = std::move(kept);
    positions = edited;
  }

  // Builds the box and the tiers. `band`: how far beyond a particle's r_outer the field is asked (sets the cells of
  // scattered data). `spread`: a tier's outer radii from its smallest to `spread` times it (tests give infinity: one
  // tier).
  void index(double band, double spread = kTierSpread);

  // A tier's hash cell: `cell`, or coarser where the particles' extent would span more than 2^28 such cells (a few
  // particles of tiny radii among the rest): a coarser cell costs a search speed, never an answer.
  double hash_cell(double cell) const { return std::max(cell, std::ldexp((box.max - box.min).maxCoeff(), -28)); }

  // The hash of uniform radii (the only tier).
  const SpatialHash& hash() const { return tiers.front().hash; }

  double all_radius(const Vec3& x) const {
    return (x - 0.5 * (box.min + box.max)).norm() + 0.5 * (box.max - box.min).norm() + max_outer;
  }

  // Whether two particles lie within `distance` of each other (in one tier or across tiers).
  bool any_pair_within(double distance, const RunControl& control) const;

  struct Hit {
    std::uint32_t index = 0;
    double distance = kInf;
    double value = kInf;  // distance - the particle's radius of the query
  };

  // Exact nearest particle (uniform radii). Particles must be non-empty.
  // The queries come from near the r_outer surface (lattice points within 1.25 h of it, vertices before the snap:
  // after the Laplacian sweeps 44 % of the block's lie outside r_outer, none beyond 1.12 r_outer), so the search
  // starts at kFirstSearch r_outer and mostly ends there. Starting at one cell and retrying without a bound took three
  // rounds, the last one 8 times the volume, for every vertex outside r_outer.
  Hit nearest(const Vec3& x) const {
    const std::optional<SpatialHash::Neighbor> n = hash().nearest(x, kInf, kFirstSearch * r_outer);
    return Hit{n->index, n->distance, n->distance};
  }

  // Exact minimisers of |x - p_i| - inner_i and |x - p_i| - outer_i (weighted radii); ties go to the first tier, then
  // the first slot.
  void nearest_weighted(const Vec3& x, Hit& in, Hit& out) const;

  // Weighted radii: distance outside the faithful band (0 when faithful), exact.
  double violation(const Vec3& x) const {
    Hit in, out;
    nearest_weighted(x, in, out);
    return std::max({-in.value, out.value, 0.0});
  }
  bool faithful(double violation) const { return violation <= kFaithfulTolerance * (weighted ? max_outer : r_outer); }

  // The band along the line x + t n (|t| <= reach) at its faithful point nearest to x: that point's offset `at`, and
  // the offsets around it for which the line stays faithful, as an interval relative to it; nullopt when no point of
  // the line within reach is faithful. Along the line the particles' outer balls allow t in a union of closed
  // intervals (chords) and their inner balls forbid t in open ones. `at` is 0 when x is faithful, else an end of one
  // of the chords (the nearest point of such a union to 0 is one), taken on the sphere itself, inside the tolerance
  // the chords allow. Exact. When cell > 0, scratch.spheres and scratch.deeper receive the outer balls lowest_cusp
  // needs around the faithful point; one walk of the hashes serves both.
  // With tiers the chords are first read within a window |t| <= w of the main tier's band width (its largest r_outer
  // less the smallest r_inner), w growing kWindowGrowth-fold up to reach while the answer reaches the window's ends
  // (an answer strictly inside the window is the answer over the whole reach: see band_in_window).
  struct LineBand {
    double at = 0.0;
    Interval band;
  };
  std::optional<LineBand> band_on_line(const Vec3& x, const Vec3& n, double reach, double cell,
                                       BandScratch& scratch) const;

  // Uniform radii: moves x into the faithful band (see particle_surfacer.h): out of the nearest inner ball (again
  // while the push lands in another), or toward the nearest particle onto its outer sphere (it stays the nearest on
  // the way).
  void project_uniform(Vec3& x) const {
    for (int round = 0; round < kMaxProjectionRounds; ++round) {
      const Hit n = nearest(x);
      const Vec3& p = positions[n.index];
      if (n.distance < r_inner * (1.0 - kBandTolerance)) {
        x = p + r_inner * (n.distance > 0.0 ? Vec3((x - p) / n.distance) : Vec3::UnitZ());
        continue;
      }
      if (n.distance > r_outer * (1.0 + kBandTolerance)) x = p + (x - p) * (r_outer / n.distance);
      return;
    }
  }
  double violation_uniform(const Vec3& x) const {
    const double d = nearest(x).distance;
    return std::max({r_inner - d, d - r_outer, 0.0});
  }

  // The thesis' projection (see particle_surfacer.h) for either kind of radii.
  void project_any(Vec3& x) const {
    if (weighted) {
      project(x);
    } else {
      project_uniform(x);
    }
  }

  // Weighted radii: moves x into the faithful band (see particle_surfacer.h); returns false when rounds ran out.
  bool project(Vec3& x) const;

 private:
  // band_on_line over the chords that meet |t| <= window (<= reach); `exact` tells whether the answer is the one over
  // the whole reach.
  std::optional<LineBand> band_in_window(const Vec3& x, const Vec3& n, double reach, double window, double cell,
                                         BandScratch& scratch, bool& exact) const;
  // Into scratch.spheres and scratch.deeper, in tier then hash order, the outer balls within their radius + cell of
  // x + at n, as lowest_cusp needs them: those whose sphere passes within cell of it, and the others. The candidates
  // are those SpatialHash::for_each_within(x + at n, tier's max_outer + cell) finds in each tier. They are taken from
  // the slots of scratch.ranges, which band_in_window read for the segment x + t n, |t| <= window, and which must hold
  // them all.
  void balls_near(const Vec3& x, const Vec3& n, double at, double cell, BandScratch& scratch) const;
};

}  // namespace surfacer::particle_index
