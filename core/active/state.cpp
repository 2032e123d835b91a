// Checkpoints of an active surface (core/active/active_surface.h: ActiveSurface::save_state / from_state).
//
// Layout (little-endian host order; a checkpoint is read back by the same build on the same machine class):
//   "SACT" u32 version
//   grid: f64 h, f64 band_width, u8 has_domain, f64 origin[3], i64 dom_hi[3]
//   run:  f64 time, area0, volume0, last_dt, last_max_dfdt, last_max_speed; i32 steps_since_reinit;
//         i64 last_node_steps; measures f64 area, volume, max_target_gradient, mean_abs_curvature, i64 crossings
//   u64 blocks; per block i32 coord[3]; then per block: 64 bytes "f == +1" bits, 64 bytes "f == -1" bits and the
//   other nodes' f as f32 in node order (most of a block outside the ramp is saturated, so this is about half the
//   raw 2 KB per block on the test shapes)
//   u64 FNV-1a of everything before it
#include <climits>
#include <cmath>
#include <cstring>
#include <string>
#include <string_view>
#include <type_traits>
#include <unordered_set>
#include <vector>

#include "core/active/active_surface.h"
#include "core/active/engine.h"
#include "core/util/errors.h"
#include "core/util/state_blob.h"

namespace surfacer {
namespace {

constexpr char kMagic[4] = {'S', 'A', 'C', 'T'};
constexpr std::uint32_t kVersion = 1;
constexpr int kMaskBytes = sparse::kBlockNodes / CHAR_BIT;

[[noreturn]] void bad_state(const std::string& why) {
  throw InvalidInput("state", "active surface checkpoint is not valid (" + why + "); start the run over");
}

}  // namespace

ActiveSurface::ActiveSurface(std::unique_ptr<active_detail::Engine> impl) : impl_(std::move(impl)) {}

std::string ActiveSurface::save_state() const {
  const active_detail::Engine& m = *impl_;
  const active_detail::NarrowBand& band = m.band;
  const active_detail::GridFrame& frame = band.frame();
  const active_detail::Stepper::Record run = m.stepper.record();
  const active_detail::MeasureControl& measures = m.motion.measures();
  const int nb = band.block_count();
  state_blob::Writer w(kMagic, kVersion);
  w.out.reserve(256 + static_cast<std::size_t>(nb) * (12 + 2 * kMaskBytes + 1024));
  w.put(frame.spacing());
  w.put(frame.band_width());
  w.put<std::uint8_t>(frame.has_domain() ? 1 : 0);
  for (int a = 0; a < 3; ++a) w.put(frame.origin()[a]);
  for (int a = 0; a < 3; ++a) w.put(frame.last_node(a));
  for (const double v : {run.time, measures.reference_area(), measures.reference_volume(), run.last_dt,
                         run.last_max_dfdt, run.last_max_speed}) {
    w.put(v);
  }
  w.put<std::int32_t>(run.steps_since_reinit);
  w.put(run.last_node_steps);
  const ActiveMeasures& lm = measures.last();
  for (const double v : {lm.area, lm.volume, lm.max_target_gradient, lm.mean_abs_curvature}) w.put(v);
  w.put(lm.crossings);
  w.put<std::uint64_t>(static_cast<std::uint64_t>(nb));
  for (int b = 0; b < nb; ++b) {
    for (const int c : band.grid().coord(b)) w.put<std::int32_t>(c);
  }
  for (int b = 0; b < nb; ++b) {
    const float* f = band.data(b, kChanF);
    unsigned char plus[kMaskBytes] = {}, minus[kMaskBytes] = {};
    for (int i = 0; i < sparse::kBlockNodes; ++i) {
      if (f[i] == 1.0f) plus[i >> 3] |= static_cast<unsigned char>(1u << (i & 7));
      if (f[i] == -1.0f) minus[i >> 3] |= static_cast<unsigned char>(1u << (i & 7));
    }
    w.out.append(reinterpret_cast<const char*>(plus), kMaskBytes);
    w.out.append(reinterpret_cast<const char*>(minus), kMaskBytes);
    for (int i = 0; i < sparse::kBlockNodes; ++i) {
      if (f[i] != 1.0f && f[i] != -1.0f) w.put(f[i]);
    }
  }
  return w.finish();
}

ActiveSurface ActiveSurface::from_state(std::string_view state, const ActiveSurfaceOptions& options,
                                        const RunControl& control) {
  auto impl = std::make_unique<active_detail::Engine>(options);  // validates the options
  active_detail::Engine& m = *impl;

  state_blob::Reader r(state, kMagic, "not an active surface checkpoint", bad_state);
  if (const auto version = r.version(); version != kVersion) {
    bad_state("version " + std::to_string(version) + ", this build reads version " + std::to_string(kVersion));
  }
  const double h = r.get<double>(), ramp = r.get<double>();
  const bool has_domain = r.get<std::uint8_t>() != 0;
  Vec3 origin;
  for (int a = 0; a < 3; ++a) origin[a] = r.get<double>();
  std::int64_t dom_hi[3];
  for (auto& d : dom_hi) d = r.get<std::int64_t>();
  const active_detail::GridFrame& frame = m.band.frame();
  if (h != frame.spacing() || ramp != frame.band_width() || has_domain != frame.has_domain() ||
      origin != frame.origin() ||
      (has_domain &&
       (dom_hi[0] != frame.last_node(0) || dom_hi[1] != frame.last_node(1) || dom_hi[2] != frame.last_node(2)))) {
    bad_state("saved with another grid (h, band_width or domain differ from the options)");
  }
  active_detail::Stepper::Record run;
  double area0 = 0.0, volume0 = 0.0;
  for (double* v : {&run.time, &area0, &volume0, &run.last_dt, &run.last_max_dfdt, &run.last_max_speed}) {
    *v = r.get<double>();
    if (!std::isfinite(*v)) bad_state("a non-finite run figure");
  }
  run.steps_since_reinit = r.get<std::int32_t>();
  if (run.steps_since_reinit < 0 || run.last_dt < 0.0) bad_state("run figures out of range");
  run.last_node_steps = r.get<std::int64_t>();
  ActiveMeasures lm;
  for (double* v : {&lm.area, &lm.volume, &lm.max_target_gradient, &lm.mean_abs_curvature}) *v = r.get<double>();
  lm.crossings = r.get<std::int64_t>();
  m.motion.measures().set_reference(area0, volume0);
  m.motion.measures().set_last(lm);

  const auto nb = r.get<std::uint64_t>();
  if (nb == 0 || nb > r.remaining() / (3 * sizeof(std::int32_t) + 2 * kMaskBytes)) {
    bad_state("block count " + std::to_string(nb));
  }
  if (static_cast<std::int64_t>(nb) > m.options.max_blocks) {
    throw ResourceLimit("max_blocks", "the checkpoint holds " + std::to_string(nb) + " blocks, more than max_blocks (" +
                                          std::to_string(m.options.max_blocks) + "); raise max_blocks");
  }
  std::vector<sparse::BlockCoord> coords(nb);
  std::unordered_set<std::uint64_t> seen;
  for (sparse::BlockCoord& c : coords) {
    for (auto& x : c) {
      x = r.get<std::int32_t>();
      if (x < -sparse::kCoordLimit || x >= sparse::kCoordLimit) bad_state("block coordinate out of range");
    }
    if (!seen.insert(sparse::pack_coord(c[0], c[1], c[2])).second) bad_state("a repeated block");
  }
  m.band.restore(
      coords,
      [&r](int, float* f) {
        const auto* plus = reinterpret_cast<const unsigned char*>(r.take(kMaskBytes));
        const auto* minus = reinterpret_cast<const unsigned char*>(r.take(kMaskBytes));
        for (int i = 0; i < sparse::kBlockNodes; ++i) {
          const bool p = (plus[i >> 3] >> (i & 7)) & 1u, n = (minus[i >> 3] >> (i & 7)) & 1u;
          if (p && n) bad_state("a node both +1 and -1");
          if (p || n) {
            f[i] = p ? 1.0f : -1.0f;
          } else {
            f[i] = r.get<float>();
            if (!(f[i] > -1.0f && f[i] < 1.0f)) bad_state("a potential value outside (-1, 1)");
          }
        }
      },
      control);
  if (r.remaining() != 0) bad_state(std::to_string(r.remaining()) + " trailing bytes");
  // The saved state followed a topology update, so this finds the same blocks and only rebuilds the active lists.
  m.band.update_topology(control);
  if (m.band.active_count() == 0) bad_state("no surface");
  m.stepper.restore(run);
  return ActiveSurface(std::move(impl));
}

}  // namespace surfacer
