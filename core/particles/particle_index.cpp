// The particles' tiers and the searches over them (core/particles/particle_index.h).
#include "core/particles/particle_index.h"

#include <algorithm>
#include <cmath>

namespace surfacer::particle_index {
namespace {

// The pieces a tier's share of a band query's segment |t| <= window along n is read in: about two of the tier's
// largest r_outer long (at most kMaxPieces), when the hash cells their boxes overlap are fewer in all than those of
// the box around the whole segment (for a sparse hash: than its occupied cells, which a large box walks instead);
// else one, the whole segment at once (always while the window is below two of the radii).
LinePieces pieces_for(double window, const Tier& tier, const Vec3& n) {
  LinePieces pieces;
  pieces.window = window;
  const double radius = tier.max_outer, m = std::floor(window / radius);
  if (m >= 2.0) {
    const auto cells = [&](double half) {  // about the cells the box of a piece of that half length overlaps
      double c = 1.0;
      for (int a = 0; a < 3; ++a) c *= std::floor(2.0 * (half * std::abs(n[a]) + radius) / tier.hash.cell_size()) + 2.0;
      return tier.hash.dense() ? c : std::min(c, static_cast<double>(tier.hash.occupied_cells()));
    };
    const auto k = static_cast<std::uint32_t>(std::min(m, static_cast<double>(kMaxPieces)));
    if (k * cells(window / k) < cells(window)) pieces.count = k;
  }
  pieces.length = 2.0 * window / pieces.count;
  return pieces;
}

// The box of piece j of the segment x + t n grown by `grow`: its centre, and its half extent per axis.
struct PieceBox {
  Eigen::Array3d centre, half;
};
PieceBox piece_box(const LinePieces& pieces, std::uint32_t j, const Vec3& x, const Vec3& n, double grow) {
  const Vec3 centre = pieces.count == 1 ? x : Vec3(x + pieces.centre(j) * n);
  return {centre.array(), pieces.half() * n.array().abs() + grow};
}

}  // namespace

void Particles::index(double band, double spread) {
  box = Aabb::of(positions);
  tiers.clear();
  main_tier = 0;
  if (!weighted) {
    // Dense data: cells of r_inner keep the scans short. Scattered data (the hash falls back to its sparse layout, one
    // table lookup per cell): cells of the query reach (r_outer + band), so a query looks up at most 27 cells.
    Tier& t = tiers.emplace_back();
    t.hash.build(positions, r_inner);
    if (!t.hash.dense()) t.hash.build(positions, std::max(r_outer + band, r_inner));
    t.max_inner = r_inner;
    t.max_outer = r_outer;
    return;
  }
  if (positions.empty()) {
    tiers.emplace_back();
    return;
  }
  // The tiers' smallest outer radii: the smallest radius, then each time the smallest beyond `spread` times the last.
  std::vector<double> starts{*std::min_element(outer.begin(), outer.end())};
  while (starts.size() < kMaxTiers) {
    const double above = spread * starts.back();
    double next = kInf;
    for (const double o : outer) {
      if (o > above && o < next) next = o;
    }
    if (next == kInf) break;
    starts.push_back(next);
  }
  // Weighted radii: cells of the tier's largest r_outer, or of the query reach for scattered data.
  const auto build = [&](Tier& t, std::span<const Vec3> points) {
    t.hash.build(points, hash_cell(t.max_outer));
    if (!t.hash.dense()) t.hash.build(points, hash_cell(t.max_outer + band));
    t.slot_inner.resize(points.size());
    t.slot_outer.resize(points.size());
    for (std::uint32_t s = 0; s < points.size(); ++s) {
      const std::uint32_t i = t.particle(s);
      t.slot_inner[s] = inner[i];
      t.slot_outer[s] = outer[i];
    }
  };
  if (starts.size() == 1) {
    Tier& t = tiers.emplace_back();
    t.max_inner = max_inner;
    t.max_outer = max_outer;
    build(t, positions);
    return;
  }
  std::vector<std::uint8_t> tier_of(positions.size());
  std::vector<std::size_t> counts(starts.size(), 0);
  for (std::size_t i = 0; i < positions.size(); ++i) {
    tier_of[i] =
        static_cast<std::uint8_t>(std::upper_bound(starts.begin(), starts.end(), outer[i]) - starts.begin() - 1);
    ++counts[tier_of[i]];
  }
  tiers.resize(starts.size());
  for (std::size_t k = 0; k < starts.size(); ++k) {
    Tier& t = tiers[k];
    std::vector<Vec3> points;
    points.reserve(counts[k]);
    t.index.reserve(counts[k]);
    for (std::size_t i = 0; i < positions.size(); ++i) {
      if (tier_of[i] != k) continue;
      points.push_back(positions[i]);
      t.index.push_back(static_cast<std::uint32_t>(i));
      t.max_inner = std::max(t.max_inner, inner[i]);
      t.max_outer = std::max(t.max_outer, outer[i]);
    }
    build(t, points);
    if (t.hash.size() > tiers[main_tier].hash.size()) main_tier = k;
  }
}

bool Particles::any_pair_within(double distance, const RunControl& control) const {
  for (const Tier& t : tiers) {
    if (t.hash.any_pair_within(distance, control)) return true;
  }
  for (std::size_t b = 1; b < tiers.size(); ++b) {
    const std::span<const Vec3> pts = tiers[b].hash.sorted_points();
    for (std::size_t s = 0; s < pts.size(); ++s) {
      if ((s & 63) == 0) control.check();
      for (std::size_t a = 0; a < b; ++a) {
        if (tiers[a].hash.nearest(pts[s], distance)) return true;
      }
    }
  }
  return false;
}

void Particles::nearest_weighted(const Vec3& x, Hit& in, Hit& out) const {
  in = out = Hit{};
  for (const Tier& t : tiers) {
    const Hit in_before = in, out_before = out;
    const std::span<const Vec3> pts = t.hash.sorted_points();
    double r = kFirstSearch * t.max_outer;  // as in nearest()
    while (true) {
      in = in_before;
      out = out_before;
      t.hash.for_each_range(x.array() - r, x.array() + r, [&](std::uint32_t begin, std::uint32_t end) {
        for (std::uint32_t s = begin; s < end; ++s) {
          const double d = (pts[s] - x).norm();
          if (d - t.slot_inner[s] < in.value) in = Hit{t.particle(s), d, d - t.slot_inner[s]};
          if (d - t.slot_outer[s] < out.value) out = Hit{t.particle(s), d, d - t.slot_outer[s]};
        }
      });
      // The tier's particles outside the box are farther than r, so their values exceed r - its largest radius.
      if ((in.value + t.max_inner <= r && out.value + t.max_outer <= r) || r > all_radius(x)) break;
      r *= 2.0;
    }
  }
}

bool Particles::project(Vec3& x) const {
  for (int round = 0; round < kMaxProjectionRounds; ++round) {
    Hit in, out;
    nearest_weighted(x, in, out);
    if (in.value < -kBandTolerance * inner[in.index]) {
      const Vec3& p = positions[in.index];
      x = p + inner[in.index] * (in.distance > 0.0 ? Vec3((x - p) / in.distance) : Vec3::UnitZ());
      continue;
    }
    if (out.value > kBandTolerance * outer[out.index]) {
      const Vec3& p = positions[out.index];
      x = p + (x - p) * (outer[out.index] / out.distance);
      continue;  // may land inside the inner ball of a larger particle
    }
    return true;
  }
  return false;
}

std::optional<Particles::LineBand> Particles::band_on_line(const Vec3& x, const Vec3& n, double reach, double cell,
                                                           BandScratch& scratch) const {
  double window = tiers.size() == 1 ? reach : std::min(reach, tiers[main_tier].max_outer - min_inner);
  for (;;) {
    bool exact = true;
    std::optional<LineBand> line = band_in_window(x, n, reach, window, cell, scratch, exact);
    if (exact || !(window < reach)) return line;
    window = std::min(kWindowGrowth * window, reach);
  }
}

// The chords read are those of the particles in each tier's hash cells of the box around the segment (|t| <= window)
// grown by the tier's largest r_outer. A chord not read lies wholly beyond the window, so:
//  * whether a point of the window is faithful is known exactly, and so is the nearest faithful point when one lies in
//    the window (every chord end nearer to x is read);
//  * a band whose ends lie strictly inside the window is exact: a chord not read can neither join the piece of the
//    union that holds `at` at an end inside the window, nor bring an inner ball nearer to `at` than that end.
// Otherwise `exact` is false (unless the window is the whole reach).
std::optional<Particles::LineBand> Particles::band_in_window(const Vec3& x, const Vec3& n, double reach, double window,
                                                             double cell, BandScratch& scratch, bool& exact) const {
  std::vector<Interval>& allowed = scratch.allowed;
  std::vector<Interval>& forbidden = scratch.forbidden;
  std::vector<double>& ends = scratch.ends;
  std::vector<BandScratch::Chord>& chords = scratch.chords;
  chords.clear();
  allowed.clear();
  forbidden.clear();
  ends.clear();
  scratch.spheres.clear();
  scratch.deeper.clear();
  std::vector<SlotRange>& ranges = scratch.ranges;
  ranges.clear();
  scratch.pieces.clear();
  for (std::uint32_t k = 0; k < tiers.size(); ++k) {
    const Tier& t = tiers[k];
    const LinePieces& pieces = scratch.pieces.emplace_back(pieces_for(window, t, n));
    for (std::uint32_t j = 0; j < pieces.count; ++j) {
      const auto keep = [&ranges, k, j](std::uint32_t begin, std::uint32_t end) {
        ranges.push_back({k, j, begin, end});
      };
      if (cell > 0.0) {
        // Also every ball balls_near can take, wherever in the window it is asked: the box of its query about any
        // point of the piece, grown by far more than the rounding of either box.
        const PieceBox wide = piece_box(pieces, j, x, n, t.max_outer + cell);
        const double margin =
            kSkipSlack * (x.cwiseAbs().maxCoeff() + wide.half.maxCoeff() + (pieces.count == 1 ? 0.0 : window));
        t.hash.for_each_range(wide.centre - wide.half - margin, wide.centre + wide.half + margin, keep);
      } else {
        // A piece's walk is grown by the slack of `near` below (the whole segment's needs none: see there).
        const PieceBox line = piece_box(pieces, j, x, n, t.max_outer);
        const double margin = pieces.count == 1 ? 0.0 : kSkipSlack * (x.cwiseAbs().maxCoeff() + window + t.max_outer);
        t.hash.for_each_range(line.centre - line.half - margin, line.centre + line.half + margin, keep);
      }
    }
  }
  // Only the chords that meet [-window, window] are kept: one beyond it changes neither the faithful points within
  // the window nor the band where it is exact (above), and its ends are out of the window. A particle outside `near`
  // (the line's box grown by far more than the chords' tolerance and their rounding) has no such chord. The wider walk
  // for balls_near holds more than the line's cells: a chord of a particle outside the line's box is kept only when
  // its cell is one of them (never, but for rounding at the box's faces), so the chords are those of the line's cells.
  // Read in pieces, a particle belongs to the piece that holds its foot on the segment (clamped into it): within its
  // r_outer of some point of the segment, it is within that of its foot, so inside that piece's box; so every chord
  // that meets the window is read once.
  const double uniform_ro = r_outer * (1.0 + kBandTolerance), uniform_ri = r_inner * (1.0 - kBandTolerance);
  std::uint32_t current_tier = std::numeric_limits<std::uint32_t>::max(), current_piece = 0;
  const Tier* t = nullptr;
  const LinePieces* pieces = nullptr;
  std::span<const Vec3> pts;
  Eigen::Array3d near_lo = Eigen::Array3d::Zero(), near_hi = Eigen::Array3d::Zero();
  std::optional<SpatialHash::RangeVisits> line_visits;
  for (const SlotRange& range : ranges) {
    if (range.tier != current_tier || range.piece != current_piece) {
      if (range.tier != current_tier) {
        t = &tiers[range.tier];
        pts = t->hash.sorted_points();
        pieces = &scratch.pieces[range.tier];
      }
      current_tier = range.tier;
      current_piece = range.piece;
      const PieceBox line = piece_box(*pieces, range.piece, x, n, t->max_outer);
      const Eigen::Array3d line_lo = line.centre - line.half, line_hi = line.centre + line.half;
      const double slack = kSkipSlack * (x.cwiseAbs().maxCoeff() + window + t->max_outer);
      near_lo = line_lo - slack;
      near_hi = line_hi + slack;
      line_visits.emplace(t->hash, line_lo, line_hi);
    }
    for (std::uint32_t slot = range.begin; slot < range.end; ++slot) {
      const Vec3& p = pts[slot];
      if (!((p.array() >= near_lo).all() && (p.array() <= near_hi).all())) continue;
      const Vec3 q = x - p;
      const double b = n.dot(q), c = q.squaredNorm() - b * b;  // t along the line, c: squared distance of p to it
      if (pieces->count > 1 && pieces->of(-b) != range.piece) continue;
      const double ro = weighted ? t->slot_outer[slot] * (1.0 + kBandTolerance) : uniform_ro;
      if (!(c < ro * ro)) continue;
      const double h = std::sqrt(ro * ro - c);
      const Interval chord{-b - h, -b + h};
      if (chord.hi < -window || chord.lo > window) continue;
      if (cell > 0.0 && !(*line_visits)(slot)) continue;
      const double inner_r = weighted ? t->slot_inner[slot] : r_inner;
      const double outer_r = weighted ? t->slot_outer[slot] : r_outer;
      const double ri = weighted ? inner_r * (1.0 - kBandTolerance) : uniform_ri;
      allowed.push_back(chord);
      if (c < ri * ri) {
        const double hi = std::sqrt(ri * ri - c);
        forbidden.push_back({-b - hi, -b + hi});  // open
      }
      chords.push_back({b, c, inner_r, outer_r});
    }
  }
  const auto faithful_at = [&](double at) {
    const auto holds = [at](const Interval& c) { return c.lo <= at && at <= c.hi; };
    const auto inside = [at](const Interval& c) { return c.lo < at && at < c.hi; };
    return std::any_of(allowed.begin(), allowed.end(), holds) &&
           std::none_of(forbidden.begin(), forbidden.end(), inside);
  };
  const bool whole = !(window < reach);
  LineBand line;
  if (!faithful_at(0.0)) {
    // The candidates: the ends of every chord on the spheres themselves (inside the tolerance faithful_at allows).
    for (const BandScratch::Chord& k : chords) {
      const double outer_end = std::sqrt(std::max(0.0, k.outer * k.outer - k.c));
      ends.insert(ends.end(), {-k.b - outer_end, -k.b + outer_end});
      if (k.c < k.inner * k.inner) {
        const double inner_end = std::sqrt(k.inner * k.inner - k.c);
        ends.insert(ends.end(), {-k.b - inner_end, -k.b + inner_end});
      }
    }
    std::erase_if(ends, [window](double at) { return !(std::abs(at) <= window); });
    // The nearest first (ties: the lower), without sorting them all: mostly the first is faithful.
    const auto nearer = [](double a, double b) {
      return std::abs(a) < std::abs(b) || (std::abs(a) == std::abs(b) && a < b);
    };
    for (;;) {
      if (ends.empty()) {
        exact = whole;
        return std::nullopt;
      }
      const auto it = std::min_element(ends.begin(), ends.end(), nearer);
      if (faithful_at(*it)) {
        line.at = *it;
        break;
      }
      *it = ends.back();
      ends.pop_back();
    }
  }
  const double at = line.at;
  // The piece of the union of the allowed intervals that holds `at`: the intervals holding it, then grown by every
  // interval that meets it until none does (no sort: a few passes over a short list). Absorbed intervals are
  // swapped to the front. The nearest forbidden intervals on either side bound it.
  Interval piece{0.0, -1.0};  // empty
  std::size_t absorbed = 0;
  for (std::size_t k = 0; k < allowed.size(); ++k) {
    if (allowed[k].lo <= at && allowed[k].hi >= at) {
      piece =
          absorbed == 0 ? allowed[k] : Interval{std::min(piece.lo, allowed[k].lo), std::max(piece.hi, allowed[k].hi)};
      std::swap(allowed[absorbed++], allowed[k]);
    }
  }
  if (absorbed == 0) {
    line.band = {0.0, 0.0};
    exact = whole || std::abs(at) < window;
  } else {
    for (bool grew = true; grew;) {
      grew = false;
      for (std::size_t k = absorbed; k < allowed.size(); ++k) {
        if (allowed[k].lo <= piece.hi && allowed[k].hi >= piece.lo) {
          piece.lo = std::min(piece.lo, allowed[k].lo);
          piece.hi = std::max(piece.hi, allowed[k].hi);
          std::swap(allowed[absorbed++], allowed[k]);
          grew = true;
        }
      }
    }
    double lo_in = -reach, hi_in = reach;
    for (const Interval& f : forbidden) {
      if (f.lo >= at) {
        hi_in = std::min(hi_in, f.lo);
      } else if (f.hi <= at) {
        lo_in = std::max(lo_in, f.hi);
      } else {  // `at` inside an inner ball: only a rounding-level violation can get here
        hi_in = std::min(hi_in, at);
        lo_in = std::max(lo_in, at);
      }
    }
    const double lo = std::max({piece.lo, lo_in, -reach}), hi = std::min({piece.hi, hi_in, reach});
    line.band = {lo - at, hi - at};
    exact = whole || (lo > -window && hi < window);
  }
  if (cell > 0.0 && exact) balls_near(x, n, at, cell, scratch);
  return line;
}

void Particles::balls_near(const Vec3& origin, const Vec3& n, double at, double cell, BandScratch& scratch) const {
  const Vec3 x = origin + at * n;
  std::uint32_t current = std::numeric_limits<std::uint32_t>::max();
  const Tier* t = nullptr;
  const LinePieces* pieces = nullptr;
  std::span<const Vec3> pts;
  double r2 = 0.0, reach = 0.0;
  std::optional<SpatialHash::RangeVisits> visits;
  for (const SlotRange& range : scratch.ranges) {
    if (range.tier != current) {
      current = range.tier;
      t = &tiers[current];
      pts = t->hash.sorted_points();
      pieces = &scratch.pieces[current];
      const double radius = t->max_outer + cell;
      r2 = radius * radius;
      visits.emplace(t->hash, x.array() - radius, x.array() + radius);
      // A ball within `radius` of x has its foot within that of `at`: pieces farther along hold none of them.
      reach = radius + kSkipSlack * (origin.cwiseAbs().maxCoeff() + pieces->window + radius);
    }
    if (pieces->count > 1) {
      const double lo = pieces->centre(range.piece) - pieces->half(), hi = lo + 2.0 * pieces->half();
      if (hi < at - reach || lo > at + reach) continue;
    }
    for (std::uint32_t slot = range.begin; slot < range.end; ++slot) {
      const Vec3& p = pts[slot];
      const double d2 = (p - x).squaredNorm();
      if (!(d2 <= r2)) continue;
      if (!(*visits)(slot)) continue;
      if (pieces->count > 1 && pieces->of(-n.dot(origin - p)) != range.piece) continue;  // read in another piece
      const double r = weighted ? t->slot_outer[slot] : r_outer;
      if (d2 > (r + cell) * (r + cell)) continue;
      (d2 >= (r - cell) * (r - cell) ? scratch.spheres : scratch.deeper).push_back({p, r});
    }
  }
}

}  // namespace surfacer::particle_index
