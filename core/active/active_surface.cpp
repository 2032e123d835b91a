// Active implicit surface engine (core/active/active_surface.h; docs/ALGORITHMS.md §4). Choices beyond the paper:
//
// * Clamped distance profile. The paper thresholds an arbitrary potential at +-1. Here f is kept close to
//   clamp(-d / (w h), -1, 1) (w = band_width): a linear ramp w nodes wide on each side of the surface, so the
//   one-sided WENO stencils of the nodes next to the surface see a smooth function and |grad f| = 1 / (w h) is
//   known. The ramp is restored by reinitialization (below); in normal-speed modes the speed extension moves the
//   whole band with the surface, so the profile barely drifts.
// * Band and activity (paper §4.5). A node is in the band when |f| < 1 or when a 6-neighbour has the other sign (a
//   steep interface without an unsaturated node must still move). Active nodes = band plus its 6-neighbours, the
//   "woken" nodes, which may enter (-1, 1) as the surface approaches; a node whose value is clamped back to +-1 with
//   no band neighbour drops out. Blocks of 8^3 nodes exist around every band block (its 26 neighbours), so the
//   3-node WENO aprons of active nodes always read stored values; the surface moves less than one node per
//   sub-step (CFL), so the allocation, redone after every sub-step, keeps up. A new block takes the sign of its
//   parent band block's node nearest to it: blocks are missing only where f is saturated, so their sign is uniform.
// * Speed extension (paper §4.3) goes beyond the voxels next to the surface: nodes with no crossed incident edge take
//   the mean speed of already-assigned 6-neighbours, one layer per pass, so the whole band moves
//   with the surface speed (Adalsteinsson & Sethian 1999 in spirit) and df/dt vanishes when the surface is at rest.
//   Evaluating the target at far band nodes instead would fight the clamp and keep max |df/dt| from ever falling.
// * Tension is part of the extended speed: kappa is evaluated at the two nodes of each crossed edge and interpolated
//   to the sample point, so only nodes next to the surface (whose stencils are clear of the clamp) matter.
// * Space and time: HJ-WENO5 with WENO-Z weights, TVD-RK3 in every mode (the speed is frozen over a sub-step in
//   normal-speed modes: one polygonization and one target evaluation per crossing per sub-step). The stage kernels
//   run densely over the 512 nodes of each block with an active node (vectorized), keeping only active results.
// * Time-dependent velocities: the step is chosen from |u| at the step's start, at most twice the previous step, and
//   rejected (recomputed with a smaller dt) when |u| at the second stage breaks the CFL limit of 1.
// * Control terms on top of advection (not in the paper, nor in OpenVDB's LevelSetAdvection): with beta, gamma or
//   delta (or alpha and a target) the extended normal speed s is added, df/dt = -u . grad f + s |grad f|, each term
//   upwinded on its own, s frozen over the sub-step, the CFL speed |u| + |s|, and the controllers' step bounds as in
//   the normal-speed modes. Volume control then holds the volume the advection scheme loses (Enright test).
// * Reinitialization every reinit_interval sub-steps: d_tau = -S(d0) (|grad d| - 1) in grid units, Godunov with
//   second-order ENO differences, pseudo-time step 1/2, ceil(2 (w - 1)) + 2 iterations over all allocated blocks. The
//   surface must not move, and every rescaling of the nodes at a crossed edge moves the linearly interpolated
//   crossing (the two ends see slightly different gradients); repeated reinitializations let that creep pile up
//   (measured: a static sphere grew by several % over tens of reinitializations with Russo & Smereka's fix, and
//   the thin sheets of the Enright test gained or lost tens of %). So the interface nodes (a 6-neighbour of the other
//   sign) and their 6-neighbours keep their values while the interface gradient is within kInterfaceSlack of the
//   ramp's; only where it is not are the interface nodes rescaled, d <- d0 / |grad d0| (Russo & Smereka 2000 with
//   per-axis differences chosen to avoid kinks: central where both sides agree, else across the crossing, else the
//   larger one-sided difference), relaxed toward with d <- d - dtau (S |d| - D).
#include <algorithm>
#include <cmath>
#include <limits>
#include <string>
#include <unordered_set>

#include "core/active/engine.h"
#include "core/active/schemes.h"
#include "core/polygonize/edge_margin.h"
#include "core/util/errors.h"
#include "core/util/format.h"
#include "core/util/parallel.h"

namespace surfacer {
namespace {

using sparse::apron_at;
using sparse::apron_side;
using sparse::kBlockMask;
using sparse::kBlockNodes;
using sparse::kBlockSize;
using sparse::local_index;
using sparse::local_x;
using sparse::local_y;
using sparse::local_z;
using sparse::neighbor_slot;

constexpr double kInterfaceSlack = 0.5;
constexpr double kMinBandWidth = 2.0, kMaxBandWidth = 8.0;  // ActiveSurfaceOptions::band_width, grid spacings
constexpr int kMaxCflRetries = 8;  // shorter retries of an advecting step that breaks the CFL bound
constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

// Per-thread scratch arrays for aprons.
float* scratch(int slot, std::size_t size) {
  thread_local std::vector<float> buffers[6];
  if (buffers[slot].size() < size) buffers[slot].resize(size);
  return buffers[slot].data();
}

}  // namespace

void validate(const ActiveSurfaceOptions& o) {
  const ActiveSurfaceOptions defaults;
  if (!(o.h > 0.0) || !std::isfinite(o.h))
    throw InvalidInput("h", "h (" + format_number(o.h) + ") must be a finite spacing > 0");
  if (o.domain) {
    const Aabb& d = *o.domain;
    if (!d.min.allFinite() || !d.max.allFinite() || !d.valid()) {
      throw InvalidInput("domain", "domain must be a finite box with min < max on every axis");
    }
    for (int a = 0; a < 3; ++a) {
      if ((d.max[a] - d.min[a]) / o.h > double(sparse::kCoordLimit) * kBlockSize) {
        throw ResourceLimit("domain", "domain spans more than 2^23 nodes per axis; coarsen h or shrink the domain");
      }
    }
  }
  if (!(o.band_width >= kMinBandWidth) || !(o.band_width <= kMaxBandWidth)) {
    throw InvalidInput("band_width", "band_width (" + format_number(o.band_width) + ") must be in [" +
                                         format_number(kMinBandWidth) + ", " + format_number(kMaxBandWidth) +
                                         "] grid spacings; the default is " + format_number(defaults.band_width));
  }
  const std::pair<const char*, double> coeffs[] = {
      {"alpha", o.alpha}, {"beta", o.beta}, {"gamma", o.gamma}, {"delta", o.delta}};
  for (const auto& [name, v] : coeffs) {
    if (!(v >= 0.0) || !std::isfinite(v)) {
      throw InvalidInput(name, std::string(name) + " (" + format_number(v) + ") must be finite and >= 0");
    }
  }
  if (o.cfl && !(*o.cfl > 0.0 && *o.cfl <= 1.0)) {
    throw InvalidInput(
        "cfl", "cfl (" + format_number(*o.cfl) + ") must be in (0, 1]; the default is " + format_number(*defaults.cfl));
  }
  if (o.substeps_per_frame < 1) throw InvalidInput("substeps_per_frame", "substeps_per_frame must be >= 1");
  if (o.max_substeps_per_frame < 1) throw InvalidInput("max_substeps_per_frame", "max_substeps_per_frame must be >= 1");
  if (o.reinit_interval < 1)
    throw InvalidInput("reinit_interval",
                       "reinit_interval must be >= 1; the default is " + std::to_string(defaults.reinit_interval));
  if (!(o.max_curvature > 0.0) || !std::isfinite(o.max_curvature)) {
    throw InvalidInput("max_curvature", "max_curvature must be > 0 (in units of 1/h); the default is " +
                                            format_number(defaults.max_curvature));
  }
  if (o.threads < 0) throw InvalidInput("threads", "threads must be >= 0 (0: all hardware threads)");
  if (o.max_blocks < 1) throw InvalidInput("max_blocks", "max_blocks must be >= 1");
  check_vertex_margin(o.vertex_margin);
  if (o.polygonizer != Polygonizer::kCubes && o.polygonizer != Polygonizer::kTiles) {
    throw InvalidInput("polygonizer", "polygonizer must be tiles or cubes");
  }
}

// ------------------------------------------------------------------------------------------------------------------
// Topology: band flags, block allocation and release, active lists.

bool active_detail::Engine::owns_cubes(int b) const {
  for (int dz = 0; dz <= 1; ++dz)
    for (int dy = 0; dy <= 1; ++dy)
      for (int dx = 0; dx <= 1; ++dx) {
        const int n = grid.neighbor(b, neighbor_slot(dx, dy, dz));
        if (n >= 0 && band[n]) return true;
      }
  return false;
}

std::int64_t active_detail::Engine::active_count() const {
  std::int64_t n = 0;
  for (const auto& a : active) n += static_cast<std::int64_t>(a.size());
  return n;
}

void active_detail::Engine::update_topology(const RunControl& control) {
  control.check();
  if (!grid.neighbors_valid()) grid.rebuild_neighbors();
  const int nb = grid.block_count();

  // Band flags of the current blocks.
  std::vector<char> is_band(nb, 0);
  parallel_for(nb, threads, [&](int b) {
    constexpr int G = 1;
    constexpr std::ptrdiff_t S = apron_side<G>();
    float* ap = scratch(0, S * S * S);
    grid.gather<G>(b, kChanF, ap);
    unsigned char bits[kBlockNodes];
    active_detail::band_bits<S>(ap, bits);
    unsigned char any = 0;
    for (int i = 0; i < kBlockNodes; ++i) any |= bits[i];
    is_band[b] = any != 0;
  });

  // Allocate the 26 neighbours of every band block (in block order, so the result is deterministic).
  std::int64_t block_hi[3];
  const int wall_blocks = frame.wall_blocks();
  for (int a = 0; a < 3; ++a)
    block_hi[a] = frame.has_domain() ? frame.last_node(a) / kBlockSize + wall_blocks : sparse::kCoordLimit - 1;
  // Collect first, so that exceeding max_blocks leaves the state untouched.
  struct NewBlock {
    sparse::BlockCoord coord;
    float fill;
  };
  std::vector<NewBlock> fresh;
  std::unordered_set<std::uint64_t> pending;
  for (int b = 0; b < nb; ++b) {
    if (!is_band[b]) continue;
    const sparse::BlockCoord c = grid.coord(b);
    for (int dz = -1; dz <= 1; ++dz)
      for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx) {
          const sparse::BlockCoord n{c[0] + dx, c[1] + dy, c[2] + dz};
          bool inside = true;
          for (int a = 0; a < 3; ++a) {
            const std::int64_t lo = frame.has_domain() ? -wall_blocks : -sparse::kCoordLimit;
            if (n[a] < lo || n[a] > block_hi[a]) inside = false;
          }
          if (!inside || grid.find(n[0], n[1], n[2]) >= 0) continue;
          if (!pending.insert(sparse::pack_coord(n[0], n[1], n[2])).second) continue;
          // Parent node nearest to the new block.
          constexpr int kMid = kBlockSize / 2 - 1;
          const int px = dx < 0 ? 0 : (dx > 0 ? kBlockMask : kMid), py = dy < 0 ? 0 : (dy > 0 ? kBlockMask : kMid),
                    pz = dz < 0 ? 0 : (dz > 0 ? kBlockMask : kMid);
          fresh.push_back({n, grid.data(b, kChanF)[local_index(px, py, pz)] > 0.0f ? 1.0f : -1.0f});
        }
  }
  if (grid.block_count() + static_cast<std::int64_t>(fresh.size()) > opt.max_blocks) {
    throw ResourceLimit("max_blocks", "the narrow band needs more than max_blocks (" + std::to_string(opt.max_blocks) +
                                          ") blocks of 8^3 nodes; raise max_blocks or coarsen h");
  }
  for (const NewBlock& nbk_new : fresh) {
    const int nbk = grid.insert(nbk_new.coord, nbk_new.fill);
    for (int ch = 0; ch < kChanCount; ++ch) apply_wall(nbk, ch);
    if (velocity_cache >= 0) {
      for (int a = 0; a < 3; ++a) std::fill_n(grid.data(nbk, velocity_cache + a), kBlockNodes, kNaN);
    }
  }

  // Release old blocks with no band block in their neighbourhood.
  std::vector<char> remove(grid.block_count(), 0);
  bool any_removed = false;
  for (int b = 0; b < nb; ++b) {
    if (is_band[b]) continue;
    const sparse::BlockCoord c = grid.coord(b);
    bool keep = false;
    for (int dz = -1; dz <= 1 && !keep; ++dz)
      for (int dy = -1; dy <= 1 && !keep; ++dy)
        for (int dx = -1; dx <= 1 && !keep; ++dx) {
          const int n = grid.find(c[0] + dx, c[1] + dy, c[2] + dz);
          if (n >= 0 && n < nb && is_band[n]) keep = true;
        }
    if (!keep) {
      remove[b] = 1;
      any_removed = true;
    }
  }
  if (any_removed) grid.remove_blocks(remove);
  if (!grid.neighbors_valid()) grid.rebuild_neighbors();

  // Band bits on a 10^3 region, dilated into the active lists; interface gradient error.
  const int count = grid.block_count();
  active.resize(count);
  band.assign(count, 0);
  parallel_for(count, threads, [&](int b) {
    constexpr int G = 2;
    constexpr std::ptrdiff_t S = apron_side<G>();
    float* ap = scratch(0, S * S * S);
    grid.gather<G>(b, kChanF, ap);
    constexpr std::ptrdiff_t R = 10;  // band bits for local coordinates [-1, 9)
    unsigned char bits[R * R * R];
    active_detail::band_bits<S>(ap, bits);
    std::vector<std::uint16_t>& list = active[b];
    list.clear();
    bool any_band = false;
    const sparse::BlockCoord& c = grid.coord(b);
    for (int z = 0; z < kBlockSize; ++z)
      for (int y = 0; y < kBlockSize; ++y)
        for (int x = 0; x < kBlockSize; ++x) {
          const unsigned char* q = bits + (x + 1) + R * ((y + 1) + R * (z + 1));
          any_band |= *q != 0;
          if (*q | q[1] | q[-1] | q[R] | q[-R] | q[R * R] | q[-R * R]) {
            // Nodes outside the domain hold the wall's ramp and are never updated.
            if (!frame.has_domain() || frame.node_in_domain(c, x, y, z))
              list.push_back(static_cast<std::uint16_t>(local_index(x, y, z)));
          }
        }
    band[b] = any_band;
  });
  max_block_x = -sparse::kCoordLimit;
  for (int b = 0; b < count; ++b) max_block_x = std::max(max_block_x, grid.coord(b)[0]);
}

// ------------------------------------------------------------------------------------------------------------------
// Reinitialization (Russo & Smereka 2000), in grid units d = -ramp f.

void active_detail::Engine::reinitialize(const RunControl& control) {
  control.check();
  const int nb = grid.block_count();
  const float ramp_f = static_cast<float>(frame.band_width());
  // Frozen potential in B; subcell distance estimates of the interface nodes in Speed (NaN elsewhere).
  parallel_for(nb, threads, [&](int b) { std::copy_n(grid.data(b, kChanF), kBlockNodes, grid.data(b, kChanB)); });
  parallel_for(nb, threads, [&](int b) {
    constexpr int G = 2;
    constexpr std::ptrdiff_t S = apron_side<G>();
    float* ap = scratch(0, S * S * S);
    grid.gather<G>(b, kChanB, ap);
    float* out = grid.data(b, kChanSpeed);
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
          const double d0 = -frame.band_width() * p[0];
          for (int a = 0; a < 3; ++a) {
            const double dp = -frame.band_width() * p[st[a]], dm = -frame.band_width() * p[-st[a]];
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
  const int iterations = static_cast<int>(std::ceil(2.0 * (frame.band_width() - 1.0))) + 2;
  for (int it = 0; it < iterations; ++it) {
    control.check();
    parallel_for(nb, threads, [&](int b) {
      constexpr int G = 2;
      constexpr std::ptrdiff_t S = apron_side<G>();
      float* ap = scratch(0, S * S * S);
      grid.gather<G>(b, kChanF, ap);
      const float* f0 = grid.data(b, kChanB);
      const float* dsub = grid.data(b, kChanSpeed);
      float* out = grid.data(b, kChanA);
      const sparse::BlockCoord& c = grid.coord(b);
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
              out[i] = frame.has_domain() ? std::min(p[0], frame.wall_potential(c, x, y, z)) : p[0];
              continue;
            }
            const double d = -frame.band_width() * p[0];
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
                const double m2 = -frame.band_width() * p[-2 * t], m1 = -frame.band_width() * p[-t],
                             p1 = -frame.band_width() * p[t], p2 = -frame.band_width() * p[2 * t];
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
            if (frame.has_domain()) fv = std::min(fv, frame.wall_potential(c, x, y, z));
            out[i] = fv;
          }
    });
    grid.swap_channels(kChanF, kChanA);
  }
  steps_since_reinit = 0;
  update_topology(control);
}

// ------------------------------------------------------------------------------------------------------------------
// Construction from a normalized field.

void active_detail::Engine::configure() {
  validate(opt);
  threads = resolve_threads(opt.threads);
  frame = active_detail::GridFrame(opt.h, opt.band_width, opt.domain);
}

void active_detail::Engine::covering_blocks(const Aabb& region, std::int64_t lo[3], std::int64_t hi[3]) const {
  for (int a = 0; a < 3; ++a) {
    // One block of margin: a solid touching the domain closes in the wall blocks just outside it. In double until
    // the range check: a shape of 1e8 at h = 1e-12 is 1e19 blocks, past what std::int64_t holds.
    double block_lo = std::floor((region.min[a] - frame.origin()[a]) * frame.inv_spacing() / kBlockSize) - 1.0;
    double block_hi = std::floor((region.max[a] - frame.origin()[a]) * frame.inv_spacing() / kBlockSize) + 1.0;
    if (frame.has_domain()) {
      block_lo = std::max<double>(block_lo, -frame.wall_blocks());
      block_hi = std::min<double>(block_hi, static_cast<double>(frame.last_node(a) / kBlockSize + frame.wall_blocks()));
    }
    if (!(block_lo >= -sparse::kCoordLimit) || !(block_hi < sparse::kCoordLimit)) {
      throw ResourceLimit("h", "the surface would reach " +
                                   format_number(kBlockSize * std::max(std::abs(block_lo), std::abs(block_hi))) +
                                   " grid nodes at h = " + format_number(frame.spacing()) +
                                   " from the grid's origin (" +
                                   (frame.has_domain() ? "the domain's min corner" : "0, without a domain") +
                                   ") along an axis, past the 2^23 it addresses; coarsen h" +
                                   (frame.has_domain() ? "" : ", or give a domain (bounds) around the shape"));
    }
    lo[a] = static_cast<std::int64_t>(block_lo);
    hi[a] = static_cast<std::int64_t>(block_hi);
  }
}

Aabb active_detail::Engine::initial_region(const std::optional<Aabb>& shape_bounds) const {
  if (!shape_bounds && !frame.has_domain()) {
    throw InvalidInput("domain", "the initial shape is unbounded (it has no bounds); set options.domain to confine it");
  }
  Aabb region;
  if (shape_bounds) {
    const double pad = (frame.band_width() + 2.0) * frame.spacing();
    region = Aabb{shape_bounds->min.array() - pad, shape_bounds->max.array() + pad};
    if (!region.min.allFinite() || !region.max.allFinite()) {
      if (!frame.has_domain()) {
        throw InvalidInput("domain", "the initial shape's bounds are not finite; set options.domain to confine it");
      }
      region = *opt.domain;
    }
    if (frame.has_domain()) region.intersect(*opt.domain);
  } else {
    region = *opt.domain;
  }
  if (!region.valid()) {
    throw InvalidInput("initial_shape", "the initial shape lies outside the domain; move it or enlarge the domain");
  }
  return region;
}

std::int64_t active_detail::Engine::initial_blocks(const std::optional<Aabb>& shape_bounds, std::int64_t lo[3],
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

void check_grid_reach(const std::optional<Aabb>& initial_bounds, const Aabb& region,
                      const ActiveSurfaceOptions& options) {
  active_detail::Engine engine;
  engine.opt = options;
  engine.configure();
  std::int64_t lo[3], hi[3], dims[3];
  engine.covering_blocks(region, lo, hi);
  engine.initial_blocks(initial_bounds, lo, dims);
}

void active_detail::Engine::init(const Field& shape, const RunControl& control) {
  configure();
  std::int64_t lo[3], dims[3];
  const std::int64_t candidates = initial_blocks(shape.bounds(), lo, dims);

  // Pass 1: blocks whose 9^3 nodes (the block and the first node of its + neighbours) see both signs.
  auto sample = [&](const sparse::BlockCoord& c, int x, int y, int z) -> double {
    if (!frame.node_in_domain(c, x, y, z)) return kInf;  // beyond the wall: outside
    return shape.value(frame.node_position(c, x, y, z));
  };
  std::vector<char> surface(candidates, 0);
  parallel_for(static_cast<int>(candidates), threads, [&](int i) {
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
          if (!frame.block_in_reach(n)) continue;
          if (grid.find(n[0], n[1], n[2]) >= 0) continue;
          if (grid.block_count() >= opt.max_blocks) {
            throw ResourceLimit("max_blocks", "the initial surface needs more than max_blocks (" +
                                                  std::to_string(opt.max_blocks) +
                                                  ") blocks of 8^3 nodes; raise max_blocks or coarsen h");
          }
          grid.insert(n, -1.0f);
        }
  }
  if (grid.block_count() == 0) {
    throw InvalidInput("initial_shape",
                       "the initial shape has no surface inside the domain (every sample has the same sign)");
  }
  grid.rebuild_neighbors();

  // Pass 2: f = clamp(-value / (|grad value| w h)) on the allocated blocks.
  const double scale = 1.0 / (frame.band_width() * frame.spacing());
  parallel_for(grid.block_count(), threads, [&](int b) {
    if ((b & 15) == 0) control.check();
    const sparse::BlockCoord& c = grid.coord(b);
    float* f = grid.data(b, kChanF);
    for (int z = 0; z < kBlockSize; ++z)
      for (int y = 0; y < kBlockSize; ++y)
        for (int x = 0; x < kBlockSize; ++x) {
          float v = frame.wall_potential(c, x, y, z);  // nodes outside the domain hold the wall's ramp
          if (frame.node_in_domain(c, x, y, z)) {
            const float wall = v;
            Vec3 g;
            const double val = shape.value_and_gradient(frame.node_position(c, x, y, z), g);
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
    std::copy_n(f, kBlockNodes, grid.data(b, kChanA));
    std::copy_n(f, kBlockNodes, grid.data(b, kChanB));
  });
  update_topology(control);
  reinitialize(control);
  if (active_count() == 0) {
    throw InvalidInput("initial_shape", "the initial shape has no surface inside the domain");
  }
  measures.set_last(measure(nullptr, control));
  measures.set_reference(measures.last().area, measures.last().volume);
}

// ------------------------------------------------------------------------------------------------------------------
// One sub-step.

// The normal speed over the active nodes (normal-speed modes): sampled where the surface crosses grid edges
// (tracking and tension at the crossings, plus the area and volume terms), then extended outward layer by layer.
void active_detail::Engine::extend_speed(const RunControl& control) {
  measures.set_last(measure(&edge_speed, control));
  const double gterm = measures.speed(opt.gamma, opt.delta);
  const int nb = grid.block_count();
  // Level 0: mean over the crossed incident edges.
  const float gterm_f = static_cast<float>(gterm);
  parallel_for(nb, threads, [&](int b) {
    float* s = grid.data(b, kChanSpeed);
    std::fill_n(s, kBlockNodes, kNaN);
    for (const std::uint16_t i : active[b]) {
      const int x = local_x(i), y = local_y(i), z = local_z(i);
      const int lc[3] = {x, y, z};
      const int st[3] = {1, kBlockSize, sparse::kBlockRows};
      double sum = 0.0;
      int n = 0;
      for (int a = 0; a < 3; ++a) {
        // Edge (node, a) owned by this block.
        if (!edge_speed[b].empty()) {
          const float e = edge_speed[b][i * 3 + a];
          if (!std::isnan(e)) {
            sum += e;
            ++n;
          }
        }
        // Edge (node - e_a, a).
        int owner = b, j = i - st[a];
        if (lc[a] == 0) {
          const int off[3] = {a == 0 ? -1 : 0, a == 1 ? -1 : 0, a == 2 ? -1 : 0};
          owner = grid.neighbor(b, neighbor_slot(off[0], off[1], off[2]));
          j = i + kBlockMask * st[a];
        }
        if (owner >= 0 && !edge_speed[owner].empty()) {
          const float e = edge_speed[owner][j * 3 + a];
          if (!std::isnan(e)) {
            sum += e;
            ++n;
          }
        }
      }
      if (n > 0) s[i] = static_cast<float>(sum / n) + gterm_f;
    }
  });
  // Outer layers: mean of assigned 6-neighbours, one layer per pass (Jacobi).
  // Active nodes lie within about ramp + 2 nodes of the surface, which along a diagonal is up to sqrt(3) times as
  // many 6-neighbour hops; the passes stop early once nothing changes.
  const int layers = static_cast<int>(std::ceil((frame.band_width() + 2.0) * std::sqrt(3.0))) + 1;
  const float nan_fill = kNaN;
  for (int layer = 0; layer < layers; ++layer) {
    control.check();
    std::vector<char> changed(nb, 0);
    parallel_for(nb, threads, [&](int b) {
      const float* s = grid.data(b, kChanSpeed);
      float* out = grid.data(b, kChanA);
      std::copy_n(s, kBlockNodes, out);
      bool need = false;
      for (const std::uint16_t i : active[b]) need |= std::isnan(s[i]);
      if (!need) return;
      constexpr int G = 1;
      constexpr std::ptrdiff_t S = apron_side<G>();
      float* ap = scratch(0, S * S * S);
      grid.gather<G>(b, kChanSpeed, ap, &nan_fill);
      for (const std::uint16_t i : active[b]) {
        if (!std::isnan(s[i])) continue;
        const float* p = ap + apron_at<G>(local_x(i), local_y(i), local_z(i));
        const float nbv[6] = {p[1], p[-1], p[S], p[-S], p[S * S], p[-S * S]};
        double sum = 0.0;
        int n = 0;
        for (const float v : nbv) {
          if (!std::isnan(v)) {
            sum += v;
            ++n;
          }
        }
        if (n > 0) {
          out[i] = static_cast<float>(sum / n);
          changed[b] = 1;
        }
      }
    });
    grid.swap_channels(kChanSpeed, kChanA);
    if (std::find(changed.begin(), changed.end(), 1) == changed.end()) break;
  }
  // Fallback: the speed at the node itself.
  parallel_for(nb, threads, [&](int b) {
    float* s = grid.data(b, kChanSpeed);
    bool need = false;
    for (const std::uint16_t i : active[b]) need |= std::isnan(s[i]);
    if (!need) return;
    constexpr int G = 1;
    constexpr std::ptrdiff_t S = apron_side<G>();
    float* ap = scratch(0, S * S * S);
    grid.gather<G>(b, kChanF, ap);
    const sparse::BlockCoord& c = grid.coord(b);
    for (const std::uint16_t i : active[b]) {
      if (!std::isnan(s[i])) continue;
      const int x = local_x(i), y = local_y(i), z = local_z(i);
      double v = gterm;
      if (target && opt.alpha > 0.0) v += -opt.alpha * target->value(frame.node_position(c, x, y, z));
      if (opt.beta > 0.0) {
        const double kmax = opt.max_curvature * frame.inv_spacing();
        const double k = active_detail::curvature(ap + apron_at<G>(x, y, z), 1, S, S * S, frame.inv_spacing());
        v -= opt.beta * std::clamp(k, -kmax, kmax);
      }
      s[i] = static_cast<float>(v);
    }
  });
}

void active_detail::Engine::stage_rate(int b, int in_ch, double t_stage, float* rate, double* max_speed) {
  const bool advect = advecting();
  const float inv_h_f = static_cast<float>(frame.inv_spacing());
  constexpr std::size_t kApron = active_detail::kApronSide;
  float* ap = scratch(1, kApron * kApron * kApron);
  grid.gather<3>(b, in_ch, ap);
  if (advect) {
    float* u = scratch(2, std::size_t{3} * kBlockNodes);
    std::fill_n(u, 3 * kBlockNodes, 0.0f);
    const sparse::BlockCoord& c = grid.coord(b);
    double ms = 0.0;
    if (separable.spatial) {
      const double scale = separable.time_scale ? separable.time_scale(t_stage) : 1.0;
      float* cache[3] = {grid.data(b, velocity_cache), grid.data(b, velocity_cache + 1),
                         grid.data(b, velocity_cache + 2)};
      for (const std::uint16_t i : active[b]) {
        if (std::isnan(cache[0][i])) {
          const Vec3 v = separable.spatial(frame.node_position(c, local_x(i), local_y(i), local_z(i)));
          for (int a = 0; a < 3; ++a) cache[a][i] = static_cast<float>(v[a]);
        }
        const Vec3 v = scale * Vec3(cache[0][i], cache[1][i], cache[2][i]);
        for (int a = 0; a < 3; ++a) u[a * kBlockNodes + i] = static_cast<float>(v[a]);
        ms = std::max(ms, v.norm());
      }
    } else {
      for (const std::uint16_t i : active[b]) {
        const Vec3 v = velocity(frame.node_position(c, local_x(i), local_y(i), local_z(i)), t_stage);
        u[i] = static_cast<float>(v.x());
        u[kBlockNodes + i] = static_cast<float>(v.y());
        u[2 * kBlockNodes + i] = static_cast<float>(v.z());
        ms = std::max(ms, v.norm());
      }
    }
    active_detail::advect_rate_block(ap, u, u + kBlockNodes, u + std::ptrdiff_t{2} * kBlockNodes, inv_h_f, rate);
    if (advect_controls()) {
      // The control terms' normal speed on top of the advection: df/dt = -u . grad f + s |grad f|, each term upwinded
      // on its own, and the block's speed is the largest |u| + |s|.
      const float* speed = grid.data(b, kChanSpeed);
      float* s = scratch(4, kBlockNodes);
      float* normal_rate = scratch(5, kBlockNodes);
      std::fill_n(s, kBlockNodes, 0.0f);
      ms = 0.0;
      for (const std::uint16_t i : active[b]) {
        s[i] = speed[i];
        const Vec3 ui(u[i], u[kBlockNodes + i], u[2 * kBlockNodes + i]);
        ms = std::max(ms, ui.norm() + std::abs(static_cast<double>(speed[i])));
      }
      active_detail::normal_rate_block(ap, s, inv_h_f, normal_rate);
      for (const std::uint16_t i : active[b]) rate[i] += normal_rate[i];
    }
    if (max_speed != nullptr) *max_speed = ms;
  } else {
    const float* speed = grid.data(b, kChanSpeed);
    float* s = scratch(2, kBlockNodes);
    double ms = 0.0;
    for (int i = 0; i < kBlockNodes; ++i) s[i] = 0.0f;
    for (const std::uint16_t i : active[b]) {
      s[i] = speed[i];
      ms = std::max(ms, static_cast<double>(std::abs(speed[i])));
    }
    if (max_speed != nullptr) *max_speed = ms;
    active_detail::normal_rate_block(ap, s, inv_h_f, rate);
  }
}

// The largest stable sub-step for the maxima of the current rates (speed vmax), within the controllers' own bounds.
double active_detail::Engine::stable_dt(double vmax) const {
  const bool advect = advecting();
  const double cfl = opt.cfl ? *opt.cfl : 1.0;
  double dt_stable = kInf;
  if (vmax > 0.0) dt_stable = cfl * frame.spacing() / vmax;
  if (!advect || advect_controls()) {
    if (opt.beta > 0.0) dt_stable = std::min(dt_stable, cfl * frame.spacing() * frame.spacing() / (6.0 * opt.beta));
    // The controllers are stiff too: tracking relaxes the distance to the target at the rate alpha |grad g|, volume
    // control the volume at delta A / V0, area control the area at about gamma mean|kappa| A / A0; an explicit
    // step must stay below the inverse rates. (measures.last() is the sub-step's own: extend_speed measured it.)
    const ActiveMeasures& m = measures.last();
    if (target && opt.alpha > 0.0 && m.max_target_gradient > 0.0) {
      dt_stable = std::min(dt_stable, cfl / (opt.alpha * m.max_target_gradient));
    }
    dt_stable = std::min(dt_stable, measures.stable_dt(opt.gamma, opt.delta, cfl));
  }
  // A time-dependent velocity may grow within the step: at most double the previous step, and the stages below
  // reject the step when the velocity they see breaks the CFL bound.
  if (advect && last_dt > 0.0) dt_stable = std::min(dt_stable, 2.0 * last_dt);
  return dt_stable;
}

// TVD-RK3 from the stage-1 rates (kChanA, or advect_rate_channel() when advecting), into kChanA: Shu-Osher's three
// stages, the result clamped to [-1, 1] and cut by the domain wall. An advecting step whose stage-2 speed breaks the
// CFL bound is retried shorter (at most kMaxCflRetries times). Returns the dt taken.
double active_detail::Engine::runge_kutta(double dt, const RunControl& control) {
  const bool advect = advecting();
  const int nb = grid.block_count();
  const double cfl = opt.cfl ? *opt.cfl : 1.0;
  std::vector<double> block_max_speed(nb, 0.0);
  for (int attempt = 0;; ++attempt) {
    const float dt_f = static_cast<float>(dt);
    if (advect) {
      parallel_for(nb, threads, [&](int b) {
        const float* f = grid.data(b, kChanF);
        const float* rate = grid.data(b, advect_rate_channel());
        float* out = grid.data(b, kChanA);
        std::copy_n(f, kBlockNodes, out);
        for (const std::uint16_t i : active[b]) out[i] = f[i] + dt_f * rate[i];
      });
    } else {
      parallel_for(nb, threads, [&](int b) {
        const float* f = grid.data(b, kChanF);
        float* out = grid.data(b, kChanA);
        for (const std::uint16_t i : active[b]) out[i] = f[i] + dt_f * out[i];
      });
    }
    // Stage 2: B = 3/4 f + 1/4 (A + dt L(A)).
    control.check();
    std::fill(block_max_speed.begin(), block_max_speed.end(), 0.0);
    parallel_for(nb, threads, [&](int b) {
      const float* f = grid.data(b, kChanF);
      const float* in = grid.data(b, kChanA);
      float* out = grid.data(b, kChanB);
      std::copy_n(f, kBlockNodes, out);
      if (active[b].empty()) return;
      float* rate = scratch(3, kBlockNodes);
      stage_rate(b, kChanA, time + dt, rate, &block_max_speed[b]);
      for (const std::uint16_t i : active[b]) out[i] = 0.75f * f[i] + 0.25f * (in[i] + dt_f * rate[i]);
    });
    if (advect) {
      // No block left (the surface vanished under the grid's resolution): no speed at all.
      const double v2 = nb == 0 ? 0.0 : *std::max_element(block_max_speed.begin(), block_max_speed.end());
      if (v2 * dt > frame.spacing() &&
          attempt < kMaxCflRetries) {  // beyond the CFL limit of 1 at t + dt: retry with the larger speed
        dt = std::min(dt, cfl * frame.spacing() / v2);
        continue;
      }
    }
    // Stage 3: A = 1/3 f + 2/3 (B + dt L(B)), clamped; then A becomes f.
    control.check();
    parallel_for(nb, threads, [&](int b) {
      const float* f = grid.data(b, kChanF);
      const float* in = grid.data(b, kChanB);
      float* out = grid.data(b, kChanA);
      std::copy_n(f, kBlockNodes, out);
      if (active[b].empty()) return;
      float* rate = scratch(3, kBlockNodes);
      stage_rate(b, kChanB, time + 0.5 * dt, rate, nullptr);
      const sparse::BlockCoord& c = grid.coord(b);
      for (const std::uint16_t i : active[b]) {
        float v = f[i] * (1.0f / 3.0f) + (2.0f / 3.0f) * (in[i] + dt_f * rate[i]);
        v = std::clamp(v, -1.0f, 1.0f);
        if (frame.has_domain()) v = std::min(v, frame.wall_potential(c, local_x(i), local_y(i), local_z(i)));
        out[i] = v;
      }
    });
    break;
  }
  return dt;
}

double active_detail::Engine::step(double dt_limit, const RunControl& control) {
  control.check();
  const bool advect = advecting();
  const int nb = grid.block_count();
  const double cfl = opt.cfl ? *opt.cfl : 1.0;
  if (advect_controls() && advect_rate < 0) {
    advect_rate = grid.channels();
    grid.add_channels(1, 0.0f);
  }
  if (!advect || advect_controls()) extend_speed(control);

  // Runge-Kutta stages. stage_rate computes L(in) = df/dt for the 512 nodes of a block (dense, vectorized WENO);
  // only active nodes keep it. Stage outputs equal f at inactive nodes.
  std::vector<double> block_max_rate(nb, 0.0), block_max_speed(nb, 0.0);
  // Stage 1: L(f) (into A in normal-speed modes; when advecting into Speed, free unless it holds the control speed,
  // else into the extra channel, so that a rejected step can restart from it), with the maxima for the time step.
  const int rate_ch = advect ? advect_rate_channel() : kChanA;
  control.check();
  parallel_for(nb, threads, [&](int b) {
    const float* f = grid.data(b, kChanF);
    float* out = grid.data(b, rate_ch);
    std::copy_n(f, kBlockNodes, out);
    if (active[b].empty()) return;
    float* rate = scratch(3, kBlockNodes);
    stage_rate(b, kChanF, time, rate, &block_max_speed[b]);
    double mr = 0.0;
    for (const std::uint16_t i : active[b]) {
      out[i] = rate[i];
      mr = std::max(mr, static_cast<double>(std::abs(rate[i])));
    }
    block_max_rate[b] = mr;
  });
  double vmax = 0.0, rmax = 0.0;
  for (int b = 0; b < nb; ++b) {
    vmax = std::max(vmax, block_max_speed[b]);
    rmax = std::max(rmax, block_max_rate[b]);
  }
  last_max_speed = vmax;
  last_max_dfdt = rmax;
  double dt = std::min(dt_limit, stable_dt(vmax));
  if (!std::isfinite(dt)) dt = cfl * frame.spacing();  // nothing moves: any step leaves f unchanged

  dt = runge_kutta(dt, control);
  last_dt = dt;
  restored = false;
  last_node_steps = active_count();
  grid.swap_channels(kChanF, kChanA);
  time += dt;

  update_topology(control);
  ++steps_since_reinit;
  if (steps_since_reinit >= opt.reinit_interval) reinitialize(control);
  return dt;
}

ActiveFrameStats active_detail::Engine::make_stats() const {
  ActiveFrameStats s;
  s.time = time;
  s.active_nodes = active_count();
  s.allocated_blocks = grid.block_count();
  s.max_dfdt = last_max_dfdt;
  s.max_speed = last_max_speed;
  s.memory_bytes = grid.memory_bytes();
  return s;
}

// ------------------------------------------------------------------------------------------------------------------
// Public class.

ActiveSurface::ActiveSurface(const Field& initial_shape, const ActiveSurfaceOptions& options, const RunControl& control)
    : impl_(std::make_unique<active_detail::Engine>()) {
  impl_->opt = options;
  impl_->init(initial_shape, control);
}

ActiveSurface::~ActiveSurface() = default;
ActiveSurface::ActiveSurface(ActiveSurface&&) noexcept = default;
ActiveSurface& ActiveSurface::operator=(ActiveSurface&&) noexcept = default;

void ActiveSurface::set_target(FieldPtr target) { impl_->target = std::move(target); }
void active_detail::Engine::clear_velocity_cache() {
  if (velocity_cache < 0) {
    velocity_cache = grid.channels();
    grid.add_channels(3, kNaN);
    return;
  }
  for (int b = 0; b < grid.block_count(); ++b) {
    for (int a = 0; a < 3; ++a) std::fill_n(grid.data(b, velocity_cache + a), kBlockNodes, kNaN);
  }
}

void ActiveSurface::set_velocity(VelocityFn velocity) {
  impl_->separable = {};
  impl_->velocity = std::move(velocity);
  if (!impl_->restored) impl_->last_dt = 0.0;
}

void ActiveSurface::set_velocity(SeparableVelocity velocity) {
  if (!velocity.spatial) throw InvalidInput("velocity", "a separable velocity needs its spatial part u(x)");
  impl_->velocity = {};
  impl_->separable = std::move(velocity);
  impl_->clear_velocity_cache();
  if (!impl_->restored) impl_->last_dt = 0.0;
}

void ActiveSurface::set_reference_measures(double area, double volume) {
  if (!(area > 0.0) || !std::isfinite(area)) throw InvalidInput("area", "reference area must be finite and > 0");
  if (!(volume > 0.0) || !std::isfinite(volume)) {
    throw InvalidInput("volume", "reference volume must be finite and > 0");
  }
  impl_->measures.set_reference(area, volume);
}

double ActiveSurface::time() const { return impl_->time; }
const ActiveSurfaceOptions& ActiveSurface::options() const { return impl_->opt; }

ActiveFrameStats ActiveSurface::advance(double duration, const RunControl& control) {
  active_detail::Engine& m = *impl_;
  if (!(duration > 0.0) || !std::isfinite(duration)) {
    throw InvalidInput("duration", "duration (" + format_number(duration) + ") must be finite and > 0");
  }
  const double t_end = m.time + duration;
  const double eps = 1e-12 * std::max(1.0, std::abs(t_end));
  const double fixed = m.opt.cfl ? kInf : duration / m.opt.substeps_per_frame;
  int substeps = 0, reinits = 0;
  std::int64_t node_steps = 0;
  double min_dt = kInf;
  while (t_end - m.time > eps) {
    if (substeps >= m.opt.max_substeps_per_frame) {
      throw ResourceLimit("max_substeps_per_frame",
                          "the frame needs more than max_substeps_per_frame (" +
                              std::to_string(m.opt.max_substeps_per_frame) +
                              ") sub-steps at the CFL limit; raise the limit, shorten the frame or lower the speeds");
    }
    const double remaining = t_end - m.time;
    const int before = m.steps_since_reinit;
    const double dt = m.step(std::min(remaining, fixed), control);
    node_steps += m.last_node_steps;
    if (m.steps_since_reinit <= before) ++reinits;
    ++substeps;
    if (dt < remaining - eps || substeps == 1) min_dt = std::min(min_dt, dt);
  }
  m.time = t_end;
  ActiveFrameStats s = m.make_stats();
  s.substeps = substeps;
  s.dt = duration / substeps;
  s.min_dt = min_dt;
  s.active_node_steps = node_steps;
  s.reinitializations = reinits;
  m.finish_stats(s, control);
  return s;
}

ActiveFrameStats ActiveSurface::advance_substeps(int substeps, const RunControl& control) {
  active_detail::Engine& m = *impl_;
  if (substeps < 1) throw InvalidInput("substeps", "substeps must be >= 1");
  const double t0 = m.time;
  int reinits = 0;
  std::int64_t node_steps = 0;
  double min_dt = kInf;
  for (int i = 0; i < substeps; ++i) {
    const int before = m.steps_since_reinit;
    min_dt = std::min(min_dt, m.step(kInf, control));
    node_steps += m.last_node_steps;
    if (m.steps_since_reinit <= before) ++reinits;
  }
  ActiveFrameStats s = m.make_stats();
  s.substeps = substeps;
  s.dt = (m.time - t0) / substeps;
  s.min_dt = min_dt;
  s.active_node_steps = node_steps;
  s.reinitializations = reinits;
  m.finish_stats(s, control);
  return s;
}

ActiveFrameStats ActiveSurface::stats() const {
  const active_detail::Engine& m = *impl_;
  ActiveFrameStats s = m.make_stats();
  m.finish_stats(s, {});
  return s;
}

Mesh ActiveSurface::polygonize(const RunControl& control) const { return polygonize(impl_->opt.polygonizer, control); }

Mesh ActiveSurface::polygonize(Polygonizer polygonizer, const RunControl& control) const {
  if (polygonizer == Polygonizer::kTiles) return impl_->tiles_mesh(impl_->opt.normals, control);
  return impl_->cubes_mesh(impl_->opt.normals, control);
}

double ActiveSurface::potential(const Vec3& p) const { return impl_->trilinear(p, nullptr); }

}  // namespace surfacer
