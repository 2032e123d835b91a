// The motion of the active surface (core/active/motion.h): speed extension (paper §4.3), the stage rates (HJ-WENO
// upwinding of the normal speed and of the advection) and the stable sub-step. The choices are listed atop
// core/active/active_surface.cpp.
#include "core/active/motion.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "core/active/schemes.h"
#include "core/util/errors.h"
#include "core/util/parallel.h"

namespace surfacer::active_detail {
namespace {

using sparse::apron_at;
using sparse::apron_side;
using sparse::kBlockMask;
using sparse::kBlockNodes;
using sparse::kBlockSize;
using sparse::local_x;
using sparse::local_y;
using sparse::local_z;
using sparse::neighbor_slot;

constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

// Whether an active node of the block has no speed yet (NaN in `speed`).
bool speed_missing(const std::vector<std::uint16_t>& active, const float* speed) {
  bool missing = false;
  for (const std::uint16_t i : active) missing |= std::isnan(speed[i]);
  return missing;
}

}  // namespace

Motion::Motion(const ActiveSurfaceOptions& options)
    : alpha_(options.alpha),
      beta_(options.beta),
      gamma_(options.gamma),
      delta_(options.delta),
      max_curvature_(options.max_curvature),
      cfl_(options.cfl ? *options.cfl : 1.0) {}

void Motion::set_velocity(VelocityFn velocity) {
  separable_ = {};
  velocity_ = std::move(velocity);
}

void Motion::set_velocity(SeparableVelocity velocity, NarrowBand& band) {
  velocity_ = {};
  separable_ = std::move(velocity);
  if (velocity_cache_ < 0) {
    velocity_cache_ = band.add_channels(3, kNaN, NarrowBand::NewBlocks::kFill);
  } else {
    band.fill_channels(velocity_cache_, 3, kNaN);
  }
}

int Motion::prepare_rate_channel(NarrowBand& band) {
  if (!advect_controls()) return kChanSpeed;
  if (advect_rate_ < 0) advect_rate_ = band.add_channels(1, 0.0f, NarrowBand::NewBlocks::kParentSign);
  return advect_rate_;
}

// The normal speed over the active nodes (normal-speed modes): sampled where the surface crosses grid edges
// (tracking and tension at the crossings, plus the area and volume terms), then extended outward layer by layer.
void Motion::extend_speed(NarrowBand& band, const RunControl& control) {
  CrossingSpeed sampling;
  if (target_ && alpha_ > 0.0) sampling.target = target_.get();
  sampling.alpha = alpha_;
  sampling.beta = beta_;
  sampling.curvature = beta_ > 0.0 || gamma_ > 0.0;
  sampling.max_curvature = max_curvature_;
  const int nb = band.block_count();
  if (!sampling.target && !sampling.curvature) {
    // Volume control alone: the speed is the uniform volume term at every node (the crossings would carry 0 and the
    // extension would spread it unchanged), so only the measures are taken (ALGORITHMS §4, "Control terms on top of
    // advection").
    measures_.set_last(band.measure(control));
    uniform_control_ = advecting();
    fill_speed(band, static_cast<float>(measures_.speed(gamma_, delta_)));
    return;
  }
  uniform_control_ = false;
  measures_.set_last(band.measure(sampling, edge_speed_, control));
  const double gterm = measures_.speed(gamma_, delta_);
  // Level 0: mean over the crossed incident edges.
  const float gterm_f = static_cast<float>(gterm);
  parallel_for(nb, band.threads(), [&](int b) {
    float* s = band.data(b, kChanSpeed);
    std::fill_n(s, kBlockNodes, kNaN);
    for (const std::uint16_t i : band.active(b)) {
      const int x = local_x(i), y = local_y(i), z = local_z(i);
      const int lc[3] = {x, y, z};
      const int st[3] = {1, kBlockSize, sparse::kBlockRows};
      double sum = 0.0;
      int n = 0;
      for (int a = 0; a < 3; ++a) {
        // Edge (node, a) owned by this block.
        if (!edge_speed_[b].empty()) {
          const float e = edge_speed_[b][i * 3 + a];
          if (!std::isnan(e)) {
            sum += e;
            ++n;
          }
        }
        // Edge (node - e_a, a).
        int owner = b, j = i - st[a];
        if (lc[a] == 0) {
          const int off[3] = {a == 0 ? -1 : 0, a == 1 ? -1 : 0, a == 2 ? -1 : 0};
          owner = band.grid().neighbor(b, neighbor_slot(off[0], off[1], off[2]));
          j = i + kBlockMask * st[a];
        }
        if (owner >= 0 && !edge_speed_[owner].empty()) {
          const float e = edge_speed_[owner][j * 3 + a];
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
  const int layers = static_cast<int>(std::ceil((band.frame().band_width() + 2.0) * std::sqrt(3.0))) + 1;
  const float nan_fill = kNaN;
  for (int layer = 0; layer < layers; ++layer) {
    control.check();
    std::vector<char> changed(nb, 0);
    parallel_for(nb, band.threads(), [&](int b) {
      const float* s = band.data(b, kChanSpeed);
      float* out = band.data(b, kChanA);
      std::copy_n(s, kBlockNodes, out);
      if (!speed_missing(band.active(b), s)) return;
      constexpr int G = 1;
      constexpr std::ptrdiff_t S = apron_side<G>();
      float* ap = scratch(0, S * S * S);
      band.grid().gather<G>(b, kChanSpeed, ap, &nan_fill);
      for (const std::uint16_t i : band.active(b)) {
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
    band.swap_channels(kChanSpeed, kChanA);
    if (std::find(changed.begin(), changed.end(), 1) == changed.end()) break;
  }
  // Fallback: the speed at the node itself.
  parallel_for(nb, band.threads(), [&](int b) {
    float* s = band.data(b, kChanSpeed);
    if (!speed_missing(band.active(b), s)) return;
    constexpr int G = 1;
    constexpr std::ptrdiff_t S = apron_side<G>();
    float* ap = scratch(0, S * S * S);
    band.grid().gather<G>(b, kChanF, ap);
    const sparse::BlockCoord& c = band.grid().coord(b);
    for (const std::uint16_t i : band.active(b)) {
      if (!std::isnan(s[i])) continue;
      const int x = local_x(i), y = local_y(i), z = local_z(i);
      double v = gterm;
      if (target_ && alpha_ > 0.0) v += -alpha_ * target_->value(band.frame().node_position(c, x, y, z));
      if (beta_ > 0.0) {
        const double kmax = max_curvature_ * band.frame().inv_spacing();
        const double k = curvature(ap + apron_at<G>(x, y, z), 1, S, S * S, band.frame().inv_spacing());
        v -= beta_ * std::clamp(k, -kmax, kmax);
      }
      s[i] = static_cast<float>(v);
    }
  });
}

void Motion::stage_rate(NarrowBand& band, int b, int in_ch, double t_stage, float* rate, double* max_speed,
                        bool reverse) const {
  const bool advect = advecting();
  const float inv_h_f = static_cast<float>(band.frame().inv_spacing());
  constexpr std::size_t kApron = kApronSide;
  float* ap = scratch(1, kApron * kApron * kApron);
  band.grid().gather<3>(b, in_ch, ap);
  if (advect) {
    float* u = scratch(2, std::size_t{3} * kBlockNodes);
    std::fill_n(u, 3 * kBlockNodes, 0.0f);
    const sparse::BlockCoord& c = band.grid().coord(b);
    double ms = 0.0;
    if (separable_.spatial) {
      const double scale = (separable_.time_scale ? separable_.time_scale(t_stage) : 1.0) * (reverse ? -1.0 : 1.0);
      float* cache[3] = {band.data(b, velocity_cache_), band.data(b, velocity_cache_ + 1),
                         band.data(b, velocity_cache_ + 2)};
      for (const std::uint16_t i : band.active(b)) {
        if (std::isnan(cache[0][i])) {
          const Vec3 v = separable_.spatial(band.frame().node_position(c, local_x(i), local_y(i), local_z(i)));
          for (int a = 0; a < 3; ++a) cache[a][i] = static_cast<float>(v[a]);
        }
        const Vec3 v = scale * Vec3(cache[0][i], cache[1][i], cache[2][i]);
        for (int a = 0; a < 3; ++a) u[a * kBlockNodes + i] = static_cast<float>(v[a]);
        ms = std::max(ms, v.norm());
      }
    } else {
      for (const std::uint16_t i : band.active(b)) {
        Vec3 v = velocity_(band.frame().node_position(c, local_x(i), local_y(i), local_z(i)), t_stage);
        if (reverse) v = -v;
        u[i] = static_cast<float>(v.x());
        u[kBlockNodes + i] = static_cast<float>(v.y());
        u[2 * kBlockNodes + i] = static_cast<float>(v.z());
        ms = std::max(ms, v.norm());
      }
    }
    if (advect_controls()) {
      // The control terms' normal speed on top of the advection: df/dt = -u . grad f + s |grad f|, each term upwinded
      // on its own (one WENO pass for both), and the block's speed is the largest |u| + |s|.
      const float* speed = band.data(b, kChanSpeed);
      float* s = scratch(4, kBlockNodes);
      std::fill_n(s, kBlockNodes, 0.0f);
      ms = 0.0;
      for (const std::uint16_t i : band.active(b)) {
        s[i] = reverse ? -speed[i] : speed[i];
        const Vec3 ui(u[i], u[kBlockNodes + i], u[2 * kBlockNodes + i]);
        ms = std::max(ms, ui.norm() + std::abs(static_cast<double>(speed[i])));
      }
      advect_normal_rate_block(ap, u, u + kBlockNodes, u + std::ptrdiff_t{2} * kBlockNodes, s, inv_h_f, rate);
    } else {
      advect_rate_block(ap, u, u + kBlockNodes, u + std::ptrdiff_t{2} * kBlockNodes, inv_h_f, rate);
    }
    if (max_speed != nullptr) *max_speed = ms;
  } else {
    const float* speed = band.data(b, kChanSpeed);
    float* s = scratch(2, kBlockNodes);
    double ms = 0.0;
    for (int i = 0; i < kBlockNodes; ++i) s[i] = 0.0f;
    for (const std::uint16_t i : band.active(b)) {
      s[i] = speed[i];
      ms = std::max(ms, static_cast<double>(std::abs(speed[i])));
    }
    if (max_speed != nullptr) *max_speed = ms;
    normal_rate_block(ap, s, inv_h_f, rate);
  }
}

void Motion::fill_speed(NarrowBand& band, float speed) {
  parallel_for(band.block_count(), band.threads(), [&](int b) {
    float* s = band.data(b, kChanSpeed);
    std::fill_n(s, kBlockNodes, kNaN);
    for (const std::uint16_t i : band.active(b)) s[i] = speed;
  });
}

bool Motion::limit_control(double dt, NarrowBand& band) {
  if (!uniform_control_) return false;
  const ActiveMeasures& m = measures_.last();
  const double v0 = measures_.reference_volume();
  if (!(v0 > 0.0 && m.area > 0.0 && delta_ * m.area * dt > v0)) return false;
  // The speed that moves the whole volume deficit in dt (at most the controller's own speed).
  fill_speed(band, static_cast<float>((v0 - m.volume) / (m.area * dt)));
  return true;
}

double Motion::stable_dt(double vmax, double h) const {
  const bool advect = advecting();
  const double cfl = cfl_;
  double dt_stable = kInf;
  if (vmax > 0.0) dt_stable = cfl * h / vmax;
  if (!advect || advect_controls()) {
    if (beta_ > 0.0) dt_stable = std::min(dt_stable, cfl * h * h / (6.0 * beta_));
    // The controllers are stiff too: tracking relaxes the distance to the target at the rate alpha |grad g|, volume
    // control the volume at delta A / V0, area control the area at about gamma mean|kappa| A / A0; an explicit
    // step must stay below the inverse rates. (measures_.last() is the sub-step's own: extend_speed measured it.)
    const ActiveMeasures& m = measures_.last();
    if (target_ && alpha_ > 0.0 && m.max_target_gradient > 0.0) {
      dt_stable = std::min(dt_stable, cfl / (alpha_ * m.max_target_gradient));
    }
    // Volume control alone while advecting is limited in its gain instead (limit_control).
    if (!uniform_control_) dt_stable = std::min(dt_stable, measures_.stable_dt(gamma_, delta_, cfl));
  }
  return dt_stable;
}

}  // namespace surfacer::active_detail
