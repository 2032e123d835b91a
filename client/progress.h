// Progress on stderr while a job is watched. On a terminal: one bar redrawn in place (stage, frame i/n, percent).
// Otherwise: plain lines, progress at most once a second. Both: one line per finished frame
// ("frame 3/10: 124512 triangles, closed, 0.21 s") and state changes. With ProgressMode::kJson, every one of these is
// a JSON object on a line of its own instead (client/json_output.h lists them). Thread-safe (the Ctrl-C handler
// prints too).
#pragma once

#include <chrono>
#include <iosfwd>
#include <mutex>
#include <optional>
#include <string>
#include <string_view>

#include "client/eta.h"
#include "client/frame_assembler.h"
#include "client/job_state.h"  // state_name, which the state lines print
#include "client/options.h"
#include "surfacer/v1/surfacer.pb.h"

namespace surfacer::client {

enum class ProgressMode { kLines, kBar, kJson };

// --progress: JSON when asked, else the bar on a terminal and lines otherwise.
ProgressMode progress_mode(ProgressFormat format, bool tty);

class ProgressDisplay {
 public:
  ProgressDisplay(std::ostream& err, bool tty)
      : ProgressDisplay(err, tty ? ProgressMode::kBar : ProgressMode::kLines) {}
  ProgressDisplay(std::ostream& err, ProgressMode mode);
  ~ProgressDisplay();  // clears the bar

  ProgressDisplay(const ProgressDisplay&) = delete;
  ProgressDisplay& operator=(const ProgressDisplay&) = delete;

  void on_state(const v1::Job& job);
  void on_progress(const v1::Progress& progress);
  // `frames_total` > 0 overrides the total learnt from the job (scale-out writes frames of several sub-jobs);
  // `note` is appended to the text line.
  void on_frame(const ReceivedFrame& frame, int frames_total = 0, std::string_view note = {});
  // A message line (the bar is cleared first and redrawn after).
  void line(std::string_view text);
  // Removes the bar (before the summary).
  void clear();

 private:
  void draw(bool force);
  void clear_locked();
  void line_locked(std::string_view text);

  std::mutex mutex_;

  std::ostream& err_;
  bool tty_;
  bool json_;
  std::chrono::steady_clock::time_point started_ = std::chrono::steady_clock::now();
  std::string job_id_;
  EtaEstimator eta_;
  std::optional<double> eta_seconds_;
  bool bar_shown_ = false;
  v1::Progress last_;
  int frames_total_ = 0;
  int frames_done_ = 0;
  v1::JobState state_ = v1::JOB_STATE_UNSPECIFIED;
  std::chrono::steady_clock::time_point last_draw_{};
};

// "frame 3/10: 124512 triangles, closed, 0.21 s"; with the iteration and a few metrics when the frame has them:
// "frame 2: 8312 triangles, closed, iteration 10, e_d 1.2e-07, e_n 0.0031, 0.05 s".
std::string frame_summary(const ReceivedFrame& frame, int frames_total);

}  // namespace surfacer::client
