// The engine behind ActiveSurface (core/active/active_surface.h): its working state and steps. Internal to core/active:
// shared by active_surface.cpp (topology, reinitialization, stepping), surface_mesh.cpp (polygonization and
// measures) and state.cpp (checkpoints); ActiveSurface holds one privately. Its parts with state of their own:
// GridFrame (where the grid lies, the domain wall) and MeasureControl (area and volume control).
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <optional>
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

struct Engine {
  ActiveSurfaceOptions opt;
  int threads = 1;
  GridFrame frame;  // spacing, origin, ramp, domain and wall (set by configure())

  sparse::SparseBlockGrid grid{kChanCount};
  std::vector<std::vector<std::uint16_t>> active;  // per block: local indices of active nodes, ascending
  std::vector<char> band;                          // per block: holds a band node (|f| < 1 or at a sign change)
  std::vector<std::vector<float>> edge_speed;      // per block (band blocks): speed per (node, axis), NaN: none

  FieldPtr target;
  VelocityFn velocity;          // general advection velocity, called per active node per stage
  SeparableVelocity separable;  // or u = time_scale(t) spatial(x), spatial cached per node
  int velocity_cache = -1;      // first of the 3 channels caching spatial(x) (NaN: not evaluated), or -1
  bool advecting() const { return static_cast<bool>(velocity) || static_cast<bool>(separable.spatial); }
  void clear_velocity_cache();
  // Advecting with a normal speed on top (alpha with a target, beta, gamma or delta > 0): the extended normal speed
  // of those terms is then in kChanSpeed, as in the normal-speed modes, and the stage-1 rate in the extra channel
  // `advect_rate` (added on first use).
  bool advect_controls() const {
    return advecting() && ((target && opt.alpha > 0.0) || opt.beta > 0.0 || opt.gamma > 0.0 || opt.delta > 0.0);
  }
  int advect_rate = -1;
  // Where an advecting step keeps its stage-1 rate (a rejected step restarts from it).
  int advect_rate_channel() const { return advect_controls() ? advect_rate : static_cast<int>(kChanSpeed); }
  double time = 0.0;
  MeasureControl measures;  // A0, V0 and the last measures (area and volume control)
  int steps_since_reinit = 0;

  // Last sub-step.
  double last_dt = 0.0;
  std::int64_t last_node_steps = 0;  // active nodes updated
  double last_max_dfdt = 0.0;
  double last_max_speed = 0.0;

  // Restored from a checkpoint and not stepped since: set_velocity() then keeps last_dt (the saved run's velocity
  // is assumed), so the next step is bounded as in the uninterrupted run.
  bool restored = false;

  // --- engine (active_surface.cpp) ---
  // Validates opt and derives the grid geometry (h, ramp, origin, domain) from it.
  void configure();
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
  void init(const Field& shape, const RunControl& control);
  void update_topology(const RunControl& control);
  void reinitialize(const RunControl& control);
  // One sub-step of at most dt_limit (infinity: the CFL step). Returns the dt taken.
  double step(double dt_limit, const RunControl& control);
  // The stages of step(): the extended normal speed (kChanSpeed; normal-speed modes and advect_controls()), the rate
  // df/dt of one block from channel in_ch at time t_stage (with the block's largest speed, |u| + |s| when both
  // act), and the stable sub-step for speed vmax.
  void extend_speed(const RunControl& control);
  void stage_rate(int b, int in_ch, double t_stage, float* rate, double* max_speed);
  double stable_dt(double vmax) const;
  double runge_kutta(double dt, const RunControl& control);

  // --- measures and meshes (surface_mesh.cpp) ---
  // Area and volume of the Marching Cubes surface on the grid. When `edges` is given, also fills it (per block) with
  // the tracking and tension speed at every crossed edge owned by the block (the surface sample points), evaluating
  // the target once per crossing.
  ActiveMeasures measure(std::vector<std::vector<float>>* edges, const RunControl& control) const;
  // Measures, components and memory of the current surface into s.
  void finish_stats(ActiveFrameStats& s, const RunControl& control) const;
  Mesh cubes_mesh(bool normals, const RunControl& control) const;
  Mesh tiles_mesh(bool normals, const RunControl& control) const;
  ActiveFrameStats make_stats() const;

  // Trilinear f at p (and its gradient); nodes of missing blocks take the sign of their saturated region.
  double trilinear(const Vec3& p, Vec3* gradient) const;
  double missing_sign(std::int64_t gx, std::int64_t gy, std::int64_t gz) const;
  int max_block_x = 0;  // largest block x coordinate (updated with the topology)

  // --- helpers ---
  // f = min(f, wall potential) over block `block`'s channel (GridFrame::wall_potential).
  void apply_wall(int block, int channel) {
    const sparse::BlockCoord& c = grid.coord(block);
    if (!frame.near_wall(c)) return;
    float* f = grid.data(block, channel);
    for (int z = 0; z < sparse::kBlockSize; ++z)
      for (int y = 0; y < sparse::kBlockSize; ++y)
        for (int x = 0; x < sparse::kBlockSize; ++x)
          f[sparse::local_index(x, y, z)] = std::min(f[sparse::local_index(x, y, z)], frame.wall_potential(c, x, y, z));
  }

  // Whether block `b` has a band block among the offsets {0, 1}^3 (it then may own crossed cubes).
  bool owns_cubes(int b) const;
  std::int64_t active_count() const;
};

}  // namespace active_detail
}  // namespace surfacer
