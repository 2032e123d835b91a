// The narrow band of the active surface (core/active/narrow_band.h): topology, reinitialization and the initial
// shape. The choices (band and activity, block allocation, reinitialization that keeps the interface) are listed atop
// core/active/active_surface.cpp.
#include "core/active/narrow_band.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>
#include <unordered_set>

#include "core/active/schemes.h"
#include "core/util/errors.h"
#include "core/util/format.h"
#include "core/util/parallel.h"

namespace surfacer::active_detail {
namespace {

using sparse::apron_at;
using sparse::apron_side;
using sparse::kBlockMask;
using sparse::kBlockNodes;
using sparse::kBlockSize;
using sparse::local_index;
using sparse::neighbor_slot;

constexpr double kInterfaceSlack = 0.5;
constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

// The potential of block b with a 1-node apron. Out of line: inlined into the topology's band pass it costs that pass
// about a quarter more instructions (callgrind).
[[gnu::noinline]] void gather_potential_apron1(const sparse::SparseBlockGrid& grid, int b, float* out) {
  grid.gather<1>(b, kChanF, out);
}

// Whether block b of `grid` holds a band node.
bool holds_band(const sparse::SparseBlockGrid& grid, int b) {
  constexpr int G = 1;
  constexpr std::ptrdiff_t S = apron_side<G>();
  float* ap = scratch(0, S * S * S);
  gather_potential_apron1(grid, b, ap);
  unsigned char bits[kBlockNodes];
  band_bits<S>(ap, bits);
  unsigned char any = 0;
  for (int i = 0; i < kBlockNodes; ++i) any |= bits[i];
  return any != 0;
}

}  // namespace

NarrowBand::NarrowBand(const ActiveSurfaceOptions& options)
    : frame_(options.h, options.band_width, options.domain),
      domain_(options.domain),
      threads_(resolve_threads(options.threads)),
      tiles_threads_(options.threads),
      max_blocks_(options.max_blocks),
      vertex_margin_(options.vertex_margin) {}

int NarrowBand::add_channels(int count, float fill, NewBlocks new_blocks) {
  const int first = grid_.channels();
  grid_.add_channels(count, fill);
  if (new_blocks == NewBlocks::kFill) new_block_fills_.push_back({first, count, fill});
  return first;
}

void NarrowBand::fill_channels(int first, int count, float fill) {
  for (int b = 0; b < grid_.block_count(); ++b) {
    for (int ch = first; ch < first + count; ++ch) std::fill_n(grid_.data(b, ch), kBlockNodes, fill);
  }
}

// ------------------------------------------------------------------------------------------------------------------
// Topology: band flags, block allocation and release, active lists.

bool NarrowBand::owns_cubes(int b) const {
  for (int dz = 0; dz <= 1; ++dz)
    for (int dy = 0; dy <= 1; ++dy)
      for (int dx = 0; dx <= 1; ++dx) {
        const int n = grid_.neighbor(b, neighbor_slot(dx, dy, dz));
        if (n >= 0 && band_[n]) return true;
      }
  return false;
}

std::int64_t NarrowBand::active_count() const {
  std::int64_t n = 0;
  for (const auto& a : active_) n += static_cast<std::int64_t>(a.size());
  return n;
}

void NarrowBand::update_topology(const RunControl& control) {
  control.check();
  if (!grid_.neighbors_valid()) grid_.rebuild_neighbors();
  const int nb = grid_.block_count();

  // Band flags of the current blocks.
  std::vector<char> is_band(nb, 0);
  parallel_for(nb, threads_, [&](int b) { is_band[b] = holds_band(grid_, b); });

  // Allocate the 26 neighbours of every band block (in block order, so the result is deterministic).
  std::int64_t block_hi[3];
  const int wall_blocks = frame_.wall_blocks();
  for (int a = 0; a < 3; ++a)
    block_hi[a] = frame_.has_domain() ? frame_.last_node(a) / kBlockSize + wall_blocks : sparse::kCoordLimit - 1;
  // Collect first, so that exceeding max_blocks leaves the state untouched.
  struct NewBlock {
    sparse::BlockCoord coord;
    float fill;
  };
  std::vector<NewBlock> fresh;
  std::unordered_set<std::uint64_t> pending;
  for (int b = 0; b < nb; ++b) {
    if (!is_band[b]) continue;
    const sparse::BlockCoord c = grid_.coord(b);
    for (int dz = -1; dz <= 1; ++dz)
      for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx) {
          const sparse::BlockCoord n{c[0] + dx, c[1] + dy, c[2] + dz};
          bool inside = true;
          for (int a = 0; a < 3; ++a) {
            const std::int64_t lo = frame_.has_domain() ? -wall_blocks : -sparse::kCoordLimit;
            if (n[a] < lo || n[a] > block_hi[a]) inside = false;
          }
          if (!inside || grid_.find(n[0], n[1], n[2]) >= 0) continue;
          if (!pending.insert(sparse::pack_coord(n[0], n[1], n[2])).second) continue;
          // Parent node nearest to the new block.
          constexpr int kMid = kBlockSize / 2 - 1;
          const int px = dx < 0 ? 0 : (dx > 0 ? kBlockMask : kMid), py = dy < 0 ? 0 : (dy > 0 ? kBlockMask : kMid),
                    pz = dz < 0 ? 0 : (dz > 0 ? kBlockMask : kMid);
          fresh.push_back({n, grid_.data(b, kChanF)[local_index(px, py, pz)] > 0.0f ? 1.0f : -1.0f});
        }
  }
  if (grid_.block_count() + static_cast<std::int64_t>(fresh.size()) > max_blocks_) {
    throw ResourceLimit("max_blocks", "the narrow band needs more than max_blocks (" + std::to_string(max_blocks_) +
                                          ") blocks of 8^3 nodes; raise max_blocks or coarsen h");
  }
  for (const NewBlock& nbk_new : fresh) {
    const int nbk = grid_.insert(nbk_new.coord, nbk_new.fill);
    for (int ch = 0; ch < kChanCount; ++ch) apply_wall(nbk, ch);
    for (const ChannelFill& channels : new_block_fills_) {
      for (int ch = channels.first; ch < channels.first + channels.count; ++ch) {
        std::fill_n(grid_.data(nbk, ch), kBlockNodes, channels.fill);
      }
    }
  }

  // Release old blocks with no band block in their neighbourhood.
  std::vector<char> remove(grid_.block_count(), 0);
  bool any_removed = false;
  for (int b = 0; b < nb; ++b) {
    if (is_band[b]) continue;
    const sparse::BlockCoord c = grid_.coord(b);
    bool keep = false;
    for (int dz = -1; dz <= 1 && !keep; ++dz)
      for (int dy = -1; dy <= 1 && !keep; ++dy)
        for (int dx = -1; dx <= 1 && !keep; ++dx) {
          const int n = grid_.find(c[0] + dx, c[1] + dy, c[2] + dz);
          if (n >= 0 && n < nb && is_band[n]) keep = true;
        }
    if (!keep) {
      remove[b] = 1;
      any_removed = true;
    }
  }
  if (any_removed) grid_.remove_blocks(remove);
  if (!grid_.neighbors_valid()) grid_.rebuild_neighbors();

  // Band bits on a 10^3 region, dilated into the active lists; interface gradient error.
  const int count = grid_.block_count();
  active_.resize(count);
  band_.assign(count, 0);
  parallel_for(count, threads_, [&](int b) {
    constexpr int G = 2;
    constexpr std::ptrdiff_t S = apron_side<G>();
    float* ap = scratch(0, S * S * S);
    grid_.gather<G>(b, kChanF, ap);
    constexpr std::ptrdiff_t R = 10;  // band bits for local coordinates [-1, 9)
    unsigned char bits[R * R * R];
    band_bits<S>(ap, bits);
    std::vector<std::uint16_t>& list = active_[b];
    list.clear();
    bool any_band = false;
    const sparse::BlockCoord& c = grid_.coord(b);
    for (int z = 0; z < kBlockSize; ++z)
      for (int y = 0; y < kBlockSize; ++y)
        for (int x = 0; x < kBlockSize; ++x) {
          const unsigned char* q = bits + (x + 1) + R * ((y + 1) + R * (z + 1));
          any_band |= *q != 0;
          if (*q | q[1] | q[-1] | q[R] | q[-R] | q[R * R] | q[-R * R]) {
            // Nodes outside the domain hold the wall's ramp and are never updated.
            if (!frame_.has_domain() || frame_.node_in_domain(c, x, y, z))
              list.push_back(static_cast<std::uint16_t>(local_index(x, y, z)));
          }
        }
    band_[b] = any_band;
  });
  max_block_x_ = -sparse::kCoordLimit;
  for (int b = 0; b < count; ++b) max_block_x_ = std::max(max_block_x_, grid_.coord(b)[0]);
}

// ------------------------------------------------------------------------------------------------------------------
// Reinitialization (Russo & Smereka 2000), in grid units d = -ramp f.

void NarrowBand::reinitialize(const RunControl& control) {
  control.check();
  const int nb = grid_.block_count();
  const float ramp_f = static_cast<float>(frame_.band_width());
  // Frozen potential in B; subcell distance estimates of the interface nodes in Speed (NaN elsewhere).
  parallel_for(nb, threads_, [&](int b) { std::copy_n(grid_.data(b, kChanF), kBlockNodes, grid_.data(b, kChanB)); });
  parallel_for(nb, threads_, [&](int b) {
    constexpr int G = 2;
    constexpr std::ptrdiff_t S = apron_side<G>();
    float* ap = scratch(0, S * S * S);
    grid_.gather<G>(b, kChanB, ap);
    float* out = grid_.data(b, kChanSpeed);
    const std::ptrdiff_t st[3] = {1, S, S * S};
    constexpr int R = 10;  // classification of local coordinates [-1, 9): 0 off, 1 interface kept, 2 rescaled
    unsigned char cls[R * R * R];
    float dval[R * R * R];
    for (int z = -1; z < 9; ++z)
      for (int y = -1; y < 9; ++y)
        for (int x = -1; x < 9; ++x) {
          const float* p = ap + apron_at<G>(x, y, z);
          const int r = (x + 1) + R * ((y + 1) + R * (z + 1));
          const bool in = *p > 0.0f;
          bool iface = false;
          double g2 = 0.0;
          const double d0 = -frame_.band_width() * p[0];
          for (int a = 0; a < 3; ++a) {
            const double dp = -frame_.band_width() * p[st[a]], dm = -frame_.band_width() * p[-st[a]];
            const bool cross_p = (p[st[a]] > 0.0f) != in, cross_m = (p[-st[a]] > 0.0f) != in;
            iface |= cross_p || cross_m;
            const double fwd = dp - d0, bwd = d0 - dm;
            double g;
            const double af = std::abs(fwd), ab = std::abs(bwd);
            if (fwd * bwd > 0.0 && std::max(af, ab) <= 2.0 * std::min(af, ab)) {
              g = 0.5 * (af + ab);  // smooth along this axis: central difference
            } else if (cross_p != cross_m) {
              g = cross_p ? af : ab;  // a kink beyond the node: the difference across the crossing
            } else {
              g = std::max(af, ab);  // a kink, or a sheet thinner than two cells: Russo & Smereka
            }
            g2 += g * g;
          }
          double g = std::sqrt(std::max(g2, 1e-12));
          const bool keep = std::abs(g - 1.0) < kInterfaceSlack;
          cls[r] = iface ? (keep ? 1 : 2) : 0;
          dval[r] = static_cast<float>(keep ? d0 : d0 / g);
        }
    for (int z = 0; z < kBlockSize; ++z)
      for (int y = 0; y < kBlockSize; ++y)
        for (int x = 0; x < kBlockSize; ++x) {
          const int r = (x + 1) + R * ((y + 1) + R * (z + 1));
          float v = kNaN;
          if (cls[r] != 0) {
            v = dval[r];
          } else {
            const int nbr[6] = {r + 1, r - 1, r + R, r - R, r + R * R, r - R * R};
            bool any_kept = false, any_rescaled = false;
            for (const int q : nbr) {
              any_kept |= cls[q] == 1;
              any_rescaled |= cls[q] == 2;
            }
            if (any_kept && !any_rescaled) v = dval[r];  // next to a kept interface: keep too
          }
          out[local_index(x, y, z)] = v;
        }
  });
  const double dtau = 0.5;
  // Kept nodes reach a node beyond the interface; the rest of the ramp (ramp - 1 nodes) needs 2 (ramp - 1)
  // pseudo-time steps of 1/2 to be swept, plus two to settle.
  const int iterations = static_cast<int>(std::ceil(2.0 * (frame_.band_width() - 1.0))) + 2;
  for (int it = 0; it < iterations; ++it) {
    control.check();
    parallel_for(nb, threads_, [&](int b) {
      constexpr int G = 2;
      constexpr std::ptrdiff_t S = apron_side<G>();
      float* ap = scratch(0, S * S * S);
      grid_.gather<G>(b, kChanF, ap);
      const float* f0 = grid_.data(b, kChanB);
      const float* dsub = grid_.data(b, kChanSpeed);
      float* out = grid_.data(b, kChanA);
      const sparse::BlockCoord& c = grid_.coord(b);
      const std::ptrdiff_t st[3] = {1, S, S * S};
      const auto minmod = [](double a, double b) { return a * b <= 0.0 ? 0.0 : (std::abs(a) < std::abs(b) ? a : b); };
      for (int z = 0; z < kBlockSize; ++z)
        for (int y = 0; y < kBlockSize; ++y)
          for (int x = 0; x < kBlockSize; ++x) {
            const int i = local_index(x, y, z);
            const float* p = ap + apron_at<G>(x, y, z);
            // Saturated with saturated 6-neighbours of the same value: Godunov leaves it saturated.
            if ((p[0] == 1.0f || p[0] == -1.0f) && p[1] == p[0] && p[-1] == p[0] && p[S] == p[0] && p[-S] == p[0] &&
                p[S * S] == p[0] && p[-S * S] == p[0] && std::isnan(dsub[i])) {
              out[i] = frame_.has_domain() ? std::min(p[0], frame_.wall_potential(c, x, y, z)) : p[0];
              continue;
            }
            const double d = -frame_.band_width() * p[0];
            const double sgn = f0[i] > 0.0f ? -1.0 : 1.0;  // sign of d0
            double next;
            if (!std::isnan(dsub[i])) {
              next = d - dtau * (sgn * std::abs(d) - dsub[i]);
            } else {
              // Godunov with second-order ENO one-sided differences (Osher & Fedkiw 2003, §3.3): first-order
              // values off the interface would feed a bias back into the interface nodes' gradients at the
              // next reinitialization.
              double g2 = 0.0;
              for (int a = 0; a < 3; ++a) {
                const std::ptrdiff_t t = st[a];
                const double m2 = -frame_.band_width() * p[-2 * t], m1 = -frame_.band_width() * p[-t],
                             p1 = -frame_.band_width() * p[t], p2 = -frame_.band_width() * p[2 * t];
                const double c0 = p1 - 2.0 * d + m1;
                const double bm = (d - m1) + 0.5 * minmod(d - 2.0 * m1 + m2, c0);  // backward
                const double fp = (p1 - d) - 0.5 * minmod(c0, p2 - 2.0 * p1 + d);  // forward
                if (sgn > 0.0) {
                  g2 += std::max(std::max(bm, 0.0) * std::max(bm, 0.0), std::min(fp, 0.0) * std::min(fp, 0.0));
                } else {
                  g2 += std::max(std::min(bm, 0.0) * std::min(bm, 0.0), std::max(fp, 0.0) * std::max(fp, 0.0));
                }
              }
              next = d - dtau * sgn * (std::sqrt(g2) - 1.0);
              // A node off the interface keeps its side (a steep profile could otherwise push it across zero and
              // create or close a gap the surface never had).
              if (next * sgn < 1e-3) next = 1e-3 * sgn;
            }
            float fv = static_cast<float>(-next / ramp_f);
            fv = std::clamp(fv, -1.0f, 1.0f);
            if (frame_.has_domain()) fv = std::min(fv, frame_.wall_potential(c, x, y, z));
            out[i] = fv;
          }
    });
    grid_.swap_channels(kChanF, kChanA);
  }
}

// ------------------------------------------------------------------------------------------------------------------
// The initial shape.

void NarrowBand::covering_blocks(const Aabb& region, std::int64_t lo[3], std::int64_t hi[3]) const {
  for (int a = 0; a < 3; ++a) {
    // One block of margin: a solid touching the domain closes in the wall blocks just outside it. In double until
    // the range check: a shape of 1e8 at h = 1e-12 is 1e19 blocks, past what std::int64_t holds.
    double block_lo = std::floor((region.min[a] - frame_.origin()[a]) * frame_.inv_spacing() / kBlockSize) - 1.0;
    double block_hi = std::floor((region.max[a] - frame_.origin()[a]) * frame_.inv_spacing() / kBlockSize) + 1.0;
    if (frame_.has_domain()) {
      block_lo = std::max<double>(block_lo, -frame_.wall_blocks());
      block_hi =
          std::min<double>(block_hi, static_cast<double>(frame_.last_node(a) / kBlockSize + frame_.wall_blocks()));
    }
    if (!(block_lo >= -sparse::kCoordLimit) || !(block_hi < sparse::kCoordLimit)) {
      throw ResourceLimit("h", "the surface would reach " +
                                   format_number(kBlockSize * std::max(std::abs(block_lo), std::abs(block_hi))) +
                                   " grid nodes at h = " + format_number(frame_.spacing()) +
                                   " from the grid's origin (" +
                                   (frame_.has_domain() ? "the domain's min corner" : "0, without a domain") +
                                   ") along an axis, past the 2^23 it addresses; coarsen h" +
                                   (frame_.has_domain() ? "" : ", or give a domain (bounds) around the shape"));
    }
    lo[a] = static_cast<std::int64_t>(block_lo);
    hi[a] = static_cast<std::int64_t>(block_hi);
  }
}

Aabb NarrowBand::initial_region(const std::optional<Aabb>& shape_bounds) const {
  if (!shape_bounds && !frame_.has_domain()) {
    throw InvalidInput("domain", "the initial shape is unbounded (it has no bounds); set options.domain to confine it");
  }
  Aabb region;
  if (shape_bounds) {
    const double pad = (frame_.band_width() + 2.0) * frame_.spacing();
    region = Aabb{shape_bounds->min.array() - pad, shape_bounds->max.array() + pad};
    if (!region.min.allFinite() || !region.max.allFinite()) {
      if (!frame_.has_domain()) {
        throw InvalidInput("domain", "the initial shape's bounds are not finite; set options.domain to confine it");
      }
      region = *domain_;
    }
    if (frame_.has_domain()) region.intersect(*domain_);
  } else {
    region = *domain_;
  }
  if (!region.valid()) {
    throw InvalidInput("initial_shape", "the initial shape lies outside the domain; move it or enlarge the domain");
  }
  return region;
}

std::int64_t NarrowBand::initial_blocks(const std::optional<Aabb>& shape_bounds, std::int64_t lo[3],
                                        std::int64_t dims[3]) const {
  std::int64_t hi[3];
  covering_blocks(initial_region(shape_bounds), lo, hi);
  std::int64_t candidates = 1;
  for (int a = 0; a < 3; ++a) {
    dims[a] = hi[a] - lo[a] + 1;
    candidates *= dims[a];
    if (candidates > (std::int64_t{1} << 24)) {
      throw ResourceLimit("domain",
                          "the initial shape's box holds more than 2^24 blocks of 8^3 nodes to scan; coarsen "
                          "h or give a tighter domain");
    }
  }
  return candidates;
}

void NarrowBand::init(const Field& shape, const RunControl& control) {
  std::int64_t lo[3], dims[3];
  const std::int64_t candidates = initial_blocks(shape.bounds(), lo, dims);

  // Pass 1: blocks whose 9^3 nodes (the block and the first node of its + neighbours) see both signs.
  auto sample = [&](const sparse::BlockCoord& c, int x, int y, int z) -> double {
    if (!frame_.node_in_domain(c, x, y, z)) return kInf;  // beyond the wall: outside
    return shape.value(frame_.node_position(c, x, y, z));
  };
  std::vector<char> surface(candidates, 0);
  parallel_for(static_cast<int>(candidates), threads_, [&](int i) {
    if ((i & 63) == 0) control.check();
    const sparse::BlockCoord c{static_cast<int>(lo[0] + i % dims[0]), static_cast<int>(lo[1] + (i / dims[0]) % dims[1]),
                               static_cast<int>(lo[2] + i / (dims[0] * dims[1]))};
    bool any_in = false, any_out = false;
    for (int z = 0; z <= kBlockSize; ++z)
      for (int y = 0; y <= kBlockSize; ++y)
        for (int x = 0; x <= kBlockSize; ++x) {
          (sample(c, x, y, z) < 0.0 ? any_in : any_out) = true;
          if (any_in && any_out) {
            surface[i] = 1;
            return;
          }
        }
  });
  control.check();
  for (std::int64_t i = 0; i < candidates; ++i) {
    if (!surface[i]) continue;
    const sparse::BlockCoord c{static_cast<int>(lo[0] + i % dims[0]), static_cast<int>(lo[1] + (i / dims[0]) % dims[1]),
                               static_cast<int>(lo[2] + i / (dims[0] * dims[1]))};
    for (int dz = -1; dz <= 1; ++dz)
      for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx) {
          const sparse::BlockCoord n{c[0] + dx, c[1] + dy, c[2] + dz};
          if (!frame_.block_in_reach(n)) continue;
          if (grid_.find(n[0], n[1], n[2]) >= 0) continue;
          if (grid_.block_count() >= max_blocks_) {
            throw ResourceLimit("max_blocks", "the initial surface needs more than max_blocks (" +
                                                  std::to_string(max_blocks_) +
                                                  ") blocks of 8^3 nodes; raise max_blocks or coarsen h");
          }
          grid_.insert(n, -1.0f);
        }
  }
  if (grid_.block_count() == 0) {
    throw InvalidInput("initial_shape",
                       "the initial shape has no surface inside the domain (every sample has the same sign)");
  }
  grid_.rebuild_neighbors();

  // Pass 2: f = clamp(-value / (|grad value| w h)) on the allocated blocks.
  const double scale = 1.0 / (frame_.band_width() * frame_.spacing());
  parallel_for(grid_.block_count(), threads_, [&](int b) {
    if ((b & 15) == 0) control.check();
    const sparse::BlockCoord& c = grid_.coord(b);
    float* f = grid_.data(b, kChanF);
    for (int z = 0; z < kBlockSize; ++z)
      for (int y = 0; y < kBlockSize; ++y)
        for (int x = 0; x < kBlockSize; ++x) {
          float v = frame_.wall_potential(c, x, y, z);  // nodes outside the domain hold the wall's ramp
          if (frame_.node_in_domain(c, x, y, z)) {
            const float wall = v;
            Vec3 g;
            const double val = shape.value_and_gradient(frame_.node_position(c, x, y, z), g);
            const double gn = g.norm();
            double fv;
            if (gn > 1e-12 && std::isfinite(gn)) {
              fv = -val / gn * scale;
            } else {
              fv = val < 0.0 ? 1.0 : -1.0;
            }
            if (std::isnan(fv)) fv = -1.0;
            v = static_cast<float>(std::clamp(fv, -1.0, 1.0));
            // A value of exactly 0 is outside (as in Marching Cubes); keep the inside strictly positive.
            if (val < 0.0 && v <= 0.0f) v = std::numeric_limits<float>::min();
            if (val >= 0.0 && v > 0.0f) v = 0.0f;
            v = std::min(v, wall);
          }
          f[local_index(x, y, z)] = v;
        }
    std::copy_n(f, kBlockNodes, grid_.data(b, kChanA));
    std::copy_n(f, kBlockNodes, grid_.data(b, kChanB));
  });
  update_topology(control);
  reinitialize(control);
  update_topology(control);
  if (active_count() == 0) {
    throw InvalidInput("initial_shape", "the initial shape has no surface inside the domain");
  }
}

void NarrowBand::restore(std::span<const sparse::BlockCoord> coords,
                         const std::function<void(int block, float* f)>& read_potential, const RunControl& control) {
  for (const sparse::BlockCoord& c : coords) grid_.insert(c, 0.0f);
  for (int b = 0; b < grid_.block_count(); ++b) {
    if ((b & 255) == 0) control.check();
    float* f = grid_.data(b, kChanF);
    read_potential(b, f);
    std::copy_n(f, kBlockNodes, grid_.data(b, kChanA));
    std::copy_n(f, kBlockNodes, grid_.data(b, kChanB));
  }
  grid_.rebuild_neighbors();
}

}  // namespace surfacer::active_detail
