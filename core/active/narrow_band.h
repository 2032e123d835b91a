// The narrow band of the active surface (core/active/active_surface.h; docs/ALGORITHMS.md §4, "Narrow band"): the
// sparse block grid holding the potential and its working channels, where it lies (GridFrame), which blocks hold the
// band, which nodes are active, and the allocation and release of blocks as the surface moves. Also what is read off
// the potential alone: reinitialization, the trilinear potential, the measures and the meshes of its surface.
// Internal to core/active. The block set changes only through init(), restore() and update_topology(); the parts
// that evolve the potential (Motion, Stepper) read and write the blocks' channels.
#pragma once

#include <algorithm>
#include <cstdint>
#include <functional>
#include <optional>
#include <span>
#include <vector>

#include "core/active/active_surface.h"
#include "core/active/grid_frame.h"
#include "core/active/measure_control.h"
#include "core/active/sparse_grid.h"

namespace surfacer {

// Channels of every block.
enum ActiveChannel : int {
  kChanF = 0,      // the potential f
  kChanA = 1,      // Runge-Kutta stage / reinitialization scratch
  kChanB = 2,      // Runge-Kutta stage / frozen potential during reinitialization
  kChanSpeed = 3,  // extended normal speed (NaN: not assigned) / reinitialization distance estimates
  kChanCount = 4,
};

namespace active_detail {

// The normal speed sampled at the surface's crossed grid edges (NarrowBand::measure): the tracking term
// -alpha g (g evaluated once per crossing) and the tension term -beta kappa (kappa clamped to +-max_curvature / h at
// both ends of the edge and interpolated to the crossing).
struct CrossingSpeed {
  const Field* target = nullptr;  // g, or nullptr for no tracking term
  double alpha = 0.0;
  double beta = 0.0;
  bool curvature = false;      // evaluate kappa (the tension term, and the mean |kappa| of the measures)
  double max_curvature = 0.0;  // units of 1/h
};

class NarrowBand {
 public:
  // An empty band on the grid of `options` (validated by the caller).
  explicit NarrowBand(const ActiveSurfaceOptions& options);

  const GridFrame& frame() const { return frame_; }
  // Worker threads of the band's passes (options.threads resolved).
  int threads() const { return threads_; }
  const sparse::SparseBlockGrid& grid() const { return grid_; }
  int block_count() const { return grid_.block_count(); }
  float* data(int block, int channel) { return grid_.data(block, channel); }
  const float* data(int block, int channel) const { return grid_.data(block, channel); }
  void swap_channels(int a, int b) { grid_.swap_channels(a, b); }
  // What a channel holds in a block allocated later: `fill` again, or the sign of the parent band block (as the
  // potential).
  enum class NewBlocks { kFill, kParentSign };
  // Appends `count` channels to every block, filled with `fill`, and returns the first.
  int add_channels(int count, float fill, NewBlocks new_blocks);
  // Sets channels [first, first + count) of every block to `fill`.
  void fill_channels(int first, int count, float fill);

  // Local indices of the active nodes of `block` (the band and its 6-neighbours, inside the domain), ascending.
  const std::vector<std::uint16_t>& active(int block) const { return active_[block]; }
  // Whether `block` has a band block among the offsets {0, 1}^3 (it then may own crossed cubes).
  bool owns_cubes(int block) const;
  std::int64_t active_count() const;
  std::size_t memory_bytes() const { return grid_.memory_bytes(); }

  // --- The initial shape (narrow_band.cpp) ---
  // The blocks [lo, hi] per axis that cover `region`, with one block of margin, clipped to the domain's wall blocks;
  // throws ResourceLimit("h") when they leave the grid's block coordinates.
  void covering_blocks(const Aabb& region, std::int64_t lo[3], std::int64_t hi[3]) const;
  // The box init() scans for the initial shape: its bounds padded by the band, clipped to the domain (or the domain
  // when it has none). Throws InvalidInput("domain") for an unbounded shape without a domain, ("initial_shape") for
  // one outside it.
  Aabb initial_region(const std::optional<Aabb>& shape_bounds) const;
  // The blocks covering initial_region(): the first per axis (lo), their counts (dims), and their number (returned).
  // Throws ResourceLimit("domain") above 2^24 blocks, and what covering_blocks throws.
  std::int64_t initial_blocks(const std::optional<Aabb>& shape_bounds, std::int64_t lo[3], std::int64_t dims[3]) const;
  // The clamped potential of the normalized `shape` on the blocks around its surface, reinitialized, with its
  // topology. Throws InvalidInput("initial_shape") when it has no surface in the domain, ResourceLimit("max_blocks"),
  // Cancelled, and what initial_blocks throws.
  void init(const Field& shape, const RunControl& control);
  // The blocks `coords` (in order, distinct, within the block coordinate limit: the caller checks), their potential
  // written by read_potential(block, f) (called in block order; it may throw). Only on an empty band. The caller runs
  // update_topology() next. Throws Cancelled.
  void restore(std::span<const sparse::BlockCoord> coords,
               const std::function<void(int block, float* f)>& read_potential, const RunControl& control);

  // --- Topology and reinitialization (narrow_band.cpp) ---
  // Band flags, then blocks allocated around band blocks and released away from them, then the active lists.
  // Throws ResourceLimit("max_blocks") (the band then keeps its blocks), Cancelled.
  void update_topology(const RunControl& control);
  // Reinitialization of the potential to the clamped distance profile (Russo & Smereka 2000; the choices atop
  // active_surface.cpp). Uses channels A, B and Speed as scratch. The caller runs update_topology() next. Throws
  // Cancelled.
  void reinitialize(const RunControl& control);

  // --- Measures and meshes of the surface f = 0 (surface_mesh.cpp) ---
  // Area and volume of the Marching Cubes surface on the grid.
  ActiveMeasures measure(const RunControl& control) const;
  // The same, and `edges` filled per block (band blocks; empty for the others) with the speed at every crossed edge
  // owned by the block, per (node, axis), NaN where the edge is not crossed; the measures then carry the largest
  // |grad g| and the mean |kappa| at the crossings.
  ActiveMeasures measure(const CrossingSpeed& speed, std::vector<std::vector<float>>& edges,
                         const RunControl& control) const;
  // Area, volume, components and memory of the current surface into stats.
  void surface_stats(ActiveFrameStats& stats, const RunControl& control) const;
  Mesh cubes_mesh(bool normals, const RunControl& control) const;
  Mesh tiles_mesh(bool normals, const RunControl& control) const;
  // Trilinear f at p (and its gradient); nodes of missing blocks take the sign of their saturated region.
  double trilinear(const Vec3& p, Vec3* gradient) const;

 private:
  double missing_sign(std::int64_t gx, std::int64_t gy, std::int64_t gz) const;
  // f = min(f, wall potential) over block `block`'s channel (GridFrame::wall_potential). Inline, as the topology's
  // allocation loop wants it (measured: out of line it costs that loop about a third more instructions).
  void apply_wall(int block, int channel) {
    const sparse::BlockCoord& c = grid_.coord(block);
    if (!frame_.near_wall(c)) return;
    float* f = grid_.data(block, channel);
    for (int z = 0; z < sparse::kBlockSize; ++z)
      for (int y = 0; y < sparse::kBlockSize; ++y)
        for (int x = 0; x < sparse::kBlockSize; ++x)
          f[sparse::local_index(x, y, z)] =
              std::min(f[sparse::local_index(x, y, z)], frame_.wall_potential(c, x, y, z));
  }
  ActiveMeasures measure(const CrossingSpeed* speed, std::vector<std::vector<float>>* edges,
                         const RunControl& control) const;

  GridFrame frame_;  // spacing, origin, ramp, domain and wall
  std::optional<Aabb> domain_;
  int threads_ = 1;
  int tiles_threads_ = 0;  // options.threads as given, for Marching Tiles
  std::int64_t max_blocks_ = 0;
  double vertex_margin_ = 0.0;

  sparse::SparseBlockGrid grid_{kChanCount};
  std::vector<std::vector<std::uint16_t>> active_;  // per block: local indices of active nodes, ascending
  std::vector<char> band_;  // per block: holds a band node (|f| < 1 or a sign change to a 6-neighbour)
  int max_block_x_ = 0;     // largest block x coordinate (updated with the topology)
  struct ChannelFill {
    int first, count;
    float fill;
  };
  std::vector<ChannelFill> new_block_fills_;  // channels whose new blocks get a fixed value
};

}  // namespace active_detail
}  // namespace surfacer
