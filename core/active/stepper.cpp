// The time stepping of the active surface (core/active/stepper.h): TVD-RK3 (Shu & Osher 1988) with the stage rates of
// Motion, the sub-step's size, and the topology and reinitialization after each sub-step. The choices are listed atop
// core/active/active_surface.cpp.
#include "core/active/stepper.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include "core/active/schemes.h"
#include "core/util/parallel.h"

namespace surfacer::active_detail {
namespace {

using sparse::kBlockNodes;
using sparse::local_x;
using sparse::local_y;
using sparse::local_z;

constexpr int kMaxCflRetries = 8;  // shorter retries of an advecting step that breaks the CFL bound

}  // namespace

Stepper::Record Stepper::record() const {
  Record r;
  r.time = time_;
  r.last_dt = last_dt_;
  r.last_max_dfdt = last_max_dfdt_;
  r.last_max_speed = last_max_speed_;
  r.steps_since_reinit = steps_since_reinit_;
  r.last_node_steps = last_node_steps_;
  return r;
}

void Stepper::restore(const Record& record) {
  time_ = record.time;
  last_dt_ = record.last_dt;
  last_max_dfdt_ = record.last_max_dfdt;
  last_max_speed_ = record.last_max_speed;
  steps_since_reinit_ = record.steps_since_reinit;
  last_node_steps_ = record.last_node_steps;
  restored_ = true;
}

// TVD-RK3 from the stage-1 rates (kChanA, or rate_channel when advecting), into kChanA: Shu-Osher's three
// stages, the result clamped to [-1, 1] and cut by the domain wall. An advecting step whose stage-2 speed breaks the
// CFL bound is retried shorter (at most kMaxCflRetries times) when may_retry. From t_start forward, or backward in
// time when reverse (error compensation). Returns the dt taken.
double Stepper::runge_kutta(double dt, int rate_channel, double t_start, bool reverse, bool may_retry, NarrowBand& band,
                            const Motion& motion, const RunControl& control) {
  const double dir = reverse ? -1.0 : 1.0;
  const bool advect = motion.advecting();
  const int nb = band.block_count();
  const double cfl = motion.cfl();
  std::vector<double> block_max_speed(nb, 0.0);
  for (int attempt = 0;; ++attempt) {
    const float dt_f = static_cast<float>(dt);
    if (advect) {
      parallel_for(nb, band.threads(), [&](int b) {
        const float* f = band.data(b, kChanF);
        const float* rate = band.data(b, rate_channel);
        float* out = band.data(b, kChanA);
        std::copy_n(f, kBlockNodes, out);
        for (const std::uint16_t i : band.active(b)) out[i] = f[i] + dt_f * rate[i];
      });
    } else {
      parallel_for(nb, band.threads(), [&](int b) {
        const float* f = band.data(b, kChanF);
        float* out = band.data(b, kChanA);
        for (const std::uint16_t i : band.active(b)) out[i] = f[i] + dt_f * out[i];
      });
    }
    // Stage 2: B = 3/4 f + 1/4 (A + dt L(A)).
    control.check();
    std::fill(block_max_speed.begin(), block_max_speed.end(), 0.0);
    parallel_for(nb, band.threads(), [&](int b) {
      const float* f = band.data(b, kChanF);
      const float* in = band.data(b, kChanA);
      float* out = band.data(b, kChanB);
      std::copy_n(f, kBlockNodes, out);
      if (band.active(b).empty()) return;
      float* rate = scratch(3, kBlockNodes);
      motion.stage_rate(band, b, kChanA, t_start + dir * dt, rate, &block_max_speed[b], reverse);
      for (const std::uint16_t i : band.active(b)) out[i] = 0.75f * f[i] + 0.25f * (in[i] + dt_f * rate[i]);
    });
    if (advect) {
      // No block left (the surface vanished under the grid's resolution): no speed at all.
      const double v2 = nb == 0 ? 0.0 : *std::max_element(block_max_speed.begin(), block_max_speed.end());
      if (may_retry && v2 * dt > band.frame().spacing() &&
          attempt < kMaxCflRetries) {  // beyond the CFL limit of 1 at t + dt: retry with the larger speed
        dt = std::min(dt, cfl * band.frame().spacing() / v2);
        continue;
      }
    }
    // Stage 3: A = 1/3 f + 2/3 (B + dt L(B)), clamped; then A becomes f.
    control.check();
    parallel_for(nb, band.threads(), [&](int b) {
      const float* f = band.data(b, kChanF);
      const float* in = band.data(b, kChanB);
      float* out = band.data(b, kChanA);
      std::copy_n(f, kBlockNodes, out);
      if (band.active(b).empty()) return;
      float* rate = scratch(3, kBlockNodes);
      motion.stage_rate(band, b, kChanB, t_start + dir * 0.5 * dt, rate, nullptr, reverse);
      const sparse::BlockCoord& c = band.grid().coord(b);
      const GridFrame& frame = band.frame();
      for (const std::uint16_t i : band.active(b)) {
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

// BFECC (Dupont & Liu 2003) on the forward result in kChanA (f1 = A(f0)): back from f1 to t (A run backward in
// time, f2 = A_back(f1)), then forward again from the corrected f0 + (f0 - f2) / 2 (clamped to [-1, 1]) into kChanA,
// over the same active nodes and dt. The error of A is to first order the same both ways, so it cancels.
void Stepper::compensate(double dt, int rate_channel, NarrowBand& band, const Motion& motion,
                         const RunControl& control) {
  const int nb = band.block_count();
  if (keep_channel_ < 0) keep_channel_ = band.add_channels(1, 0.0f, NarrowBand::NewBlocks::kFill);
  const int keep = keep_channel_;
  parallel_for(nb, band.threads(), [&](int b) { std::copy_n(band.data(b, kChanF), kBlockNodes, band.data(b, keep)); });
  band.swap_channels(kChanF, kChanA);  // f1 in F
  stage_one_rates(time_ + dt, true, rate_channel, band, motion, control);
  runge_kutta(dt, rate_channel, time_ + dt, true, false, band, motion, control);  // f2 in A
  parallel_for(nb, band.threads(), [&](int b) {
    const float* f0 = band.data(b, keep);
    const float* back = band.data(b, kChanA);
    float* out = band.data(b, kChanF);
    std::copy_n(f0, kBlockNodes, out);
    for (const std::uint16_t i : band.active(b)) out[i] = std::clamp(f0[i] + 0.5f * (f0[i] - back[i]), -1.0f, 1.0f);
  });
  stage_one_rates(time_, false, rate_channel, band, motion, control);
  runge_kutta(dt, rate_channel, time_, false, false, band, motion, control);
}

void Stepper::stage_one_rates(double t, bool reverse, int rate_channel, NarrowBand& band, const Motion& motion,
                              const RunControl& control, double* max_speed, double* max_rate) const {
  control.check();
  parallel_for(band.block_count(), band.threads(), [&](int b) {
    const float* f = band.data(b, kChanF);
    float* out = band.data(b, rate_channel);
    std::copy_n(f, kBlockNodes, out);
    if (band.active(b).empty()) return;
    float* rate = scratch(3, kBlockNodes);
    motion.stage_rate(band, b, kChanF, t, rate, max_speed != nullptr ? &max_speed[b] : nullptr, reverse);
    double mr = 0.0;
    for (const std::uint16_t i : band.active(b)) {
      out[i] = rate[i];
      mr = std::max(mr, static_cast<double>(std::abs(rate[i])));
    }
    if (max_rate != nullptr) max_rate[b] = mr;
  });
}

Stepper::SubStep Stepper::step(double dt_limit, NarrowBand& band, Motion& motion, const RunControl& control) {
  control.check();
  const bool advect = motion.advecting();
  const int nb = band.block_count();
  const double cfl = motion.cfl();
  const int advect_rate_channel = motion.prepare_rate_channel(band);
  if (!advect || motion.advect_controls()) motion.extend_speed(band, control);

  // Runge-Kutta stages. stage_rate computes L(in) = df/dt for the 512 nodes of a block (dense, vectorized WENO);
  // only active nodes keep it. Stage outputs equal f at inactive nodes.
  std::vector<double> block_max_rate(nb, 0.0), block_max_speed(nb, 0.0);
  // Stage 1: L(f) (into A in normal-speed modes; when advecting into Speed, free unless it holds the control speed,
  // else into the extra channel, so that a rejected step can restart from it), with the maxima for the time step.
  const int rate_ch = advect ? advect_rate_channel : kChanA;
  double vmax = 0.0, rmax = 0.0;
  auto stage_one = [&] {
    stage_one_rates(time_, false, rate_ch, band, motion, control, block_max_speed.data(), block_max_rate.data());
    vmax = 0.0;
    rmax = 0.0;
    for (int b = 0; b < nb; ++b) {
      vmax = std::max(vmax, block_max_speed[b]);
      rmax = std::max(rmax, block_max_rate[b]);
    }
    last_max_speed_ = vmax;
    last_max_dfdt_ = rmax;
  };
  stage_one();
  double dt_stable = motion.stable_dt(vmax, band.frame().spacing());
  // A time-dependent velocity may grow within the step: at most double the previous step, and the stages reject
  // the step when the velocity they see breaks the CFL bound.
  if (advect && last_dt_ > 0.0) dt_stable = std::min(dt_stable, 2.0 * last_dt_);
  double dt = std::min(dt_limit, dt_stable);
  if (!std::isfinite(dt)) dt = cfl * band.frame().spacing();  // nothing moves: any step leaves f unchanged
  // A volume control that would overshoot in dt moves the deficit exactly instead: stage 1 again with its speed (no
  // faster than before, so dt keeps within the CFL bound).
  if (advect && motion.limit_control(dt, band)) stage_one();

  dt = runge_kutta(dt, rate_ch, time_, false, true, band, motion, control);
  if (advect && compensate_) compensate(dt, rate_ch, band, motion, control);
  last_dt_ = dt;
  restored_ = false;
  last_node_steps_ = band.active_count();
  band.swap_channels(kChanF, kChanA);
  time_ += dt;

  band.update_topology(control);
  SubStep done;
  done.dt = dt;
  done.node_steps = last_node_steps_;
  ++steps_since_reinit_;
  if (steps_since_reinit_ >= reinit_interval_) {
    band.reinitialize(control);
    steps_since_reinit_ = 0;
    band.update_topology(control);
    done.reinitialized = true;
  }
  return done;
}

}  // namespace surfacer::active_detail
