#include "client/progress.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <ostream>

#include "client/json_output.h"

namespace surfacer::client {
namespace {

std::string percent(double fraction) {
  char buf[16];
  std::snprintf(buf, sizeof buf, "%3d%%", static_cast<int>(std::floor(std::clamp(fraction, 0.0, 1.0) * 100.0)));
  return buf;
}

double seconds_since(std::chrono::steady_clock::time_point start) {
  return std::round(std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count() * 1000.0) / 1000.0;
}

}  // namespace

std::string frame_summary(const ReceivedFrame& frame, int frames_total) {
  const v1::FrameStats& s = frame.stats;
  std::string text = "frame " + std::to_string(frame.index);
  if (frames_total > 0) {
    text += '/';
    text += std::to_string(frames_total);
  }
  text += ": " + std::to_string(s.triangles()) + " triangles, ";
  if (s.check().closed()) {
    text += "closed";
  } else {
    text += "open (" + std::to_string(s.check().boundary_edges()) + " boundary edges)";
  }
  if (!(s.check().edge_manifold() && s.check().vertex_manifold())) text += ", non-manifold";
  // Job-specific figures worth a glance: the optimize snapshot's iteration and errors, particles, volume.
  char buf[64];
  if (s.iteration() != 0) text += ", iteration " + std::to_string(s.iteration());
  for (const char* key : {"particles", "e_d", "e_n", "volume"}) {
    const auto it = s.metrics().find(key);
    if (it == s.metrics().end()) continue;
    std::snprintf(buf, sizeof buf, ", %s %.4g", key, it->second);
    text += buf;
  }
  double seconds = 0;
  for (const auto& t : s.timings()) seconds += t.seconds();
  std::snprintf(buf, sizeof buf, ", %.2f s", seconds);
  return text + buf;
}

ProgressMode progress_mode(ProgressFormat format, bool tty) {
  if (format == ProgressFormat::kJson) return ProgressMode::kJson;
  return tty ? ProgressMode::kBar : ProgressMode::kLines;
}

ProgressDisplay::ProgressDisplay(std::ostream& err, ProgressMode mode)
    : err_(err), tty_(mode == ProgressMode::kBar), json_(mode == ProgressMode::kJson) {}

ProgressDisplay::~ProgressDisplay() { clear(); }

void ProgressDisplay::clear() {
  std::lock_guard lock(mutex_);
  clear_locked();
}

void ProgressDisplay::clear_locked() {
  if (bar_shown_) {
    err_ << "\r\033[K" << std::flush;
    bar_shown_ = false;
  }
}

void ProgressDisplay::line(std::string_view text) {
  std::lock_guard lock(mutex_);
  line_locked(text);
}

void ProgressDisplay::line_locked(std::string_view text) {
  if (json_) {
    err_ << message_event_json(text, seconds_since(started_)) << "\n" << std::flush;
    return;
  }
  const bool redraw = bar_shown_;
  clear_locked();
  err_ << text << "\n" << std::flush;
  if (redraw) draw(true);
}

void ProgressDisplay::on_state(const v1::Job& job) {
  std::lock_guard lock(mutex_);
  if (job.frames_total() > 0) frames_total_ = job.frames_total();
  frames_done_ = std::max(frames_done_, job.frames_done());
  job_id_ = job.id();
  if (job.state() != state_) {
    state_ = job.state();
    if (json_) {
      err_ << state_event_json(job, seconds_since(started_)) << "\n" << std::flush;
      return;
    }
    if (state_ == v1::JOB_STATE_QUEUED || state_ == v1::JOB_STATE_RUNNING) {
      line_locked("job " + job.id() + ": " + state_name(state_));
    }
  }
}

void ProgressDisplay::on_progress(const v1::Progress& progress) {
  std::lock_guard lock(mutex_);
  last_ = progress;
  if (progress.frames_total() > 0) frames_total_ = progress.frames_total();
  frames_done_ = std::max(frames_done_, progress.frames_done());
  eta_seconds_ = eta_.update(progress.fraction(), std::chrono::steady_clock::now());
  if (json_) {
    err_ << progress_event_json(job_id_, progress, frames_done_, frames_total_, eta_seconds_, seconds_since(started_))
         << "\n"
         << std::flush;
    return;
  }
  draw(false);
}

void ProgressDisplay::on_frame(const ReceivedFrame& frame, int frames_total, std::string_view note) {
  std::lock_guard lock(mutex_);
  const int total = frames_total > 0 ? frames_total : frames_total_;
  if (json_) {
    err_ << frame_event_json(job_id_, frame, total, seconds_since(started_)) << "\n" << std::flush;
    return;
  }
  line_locked(frame_summary(frame, total) + std::string(note));
}

void ProgressDisplay::draw(bool force) {
  const auto now = std::chrono::steady_clock::now();
  const auto interval = tty_ ? std::chrono::milliseconds(100) : std::chrono::milliseconds(1000);
  if (!force && now - last_draw_ < interval) return;
  if (!tty_ && force) return;  // plain mode: no redraw after message lines
  last_draw_ = now;
  const double fraction = std::clamp(last_.fraction(), 0.0, 1.0);
  std::string text = percent(fraction);
  if (!last_.stage().empty()) text += "  " + last_.stage();
  text += "  frame " + std::to_string(last_.frame_index());
  if (frames_total_ > 0) {
    text += '/';
    text += std::to_string(frames_total_);
  }
  text += "  (" + std::to_string(frames_done_) + " done)";
  if (eta_seconds_ && fraction < 1.0) {
    char eta[32];
    std::snprintf(eta, sizeof eta, "  ETA %.0f s", std::ceil(*eta_seconds_));
    text += eta;
  }
  if (tty_) {
    constexpr int kWidth = 24;
    const int filled = static_cast<int>(std::round(fraction * kWidth));
    std::string bar(1, '[');
    bar.append(static_cast<std::size_t>(filled), '#');
    bar.append(static_cast<std::size_t>(kWidth - filled), '-');
    bar += "] ";
    err_ << "\r\033[K" << bar << text << std::flush;
    bar_shown_ = true;
  } else {
    err_ << "progress: " << text << "\n" << std::flush;
  }
}

}  // namespace surfacer::client
