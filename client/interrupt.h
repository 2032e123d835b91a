// Ctrl-C handling for `run`: while an InterruptHandler lives, SIGINT and SIGTERM no longer kill the process;
// each one calls `on_signal(n)` (n = 1 for the first, 2 for the second, ...) on a helper thread, where blocking
// work such as a CancelJob call is fine. The previous handlers are restored on destruction.
#pragma once

#include <csignal>
#include <functional>
#include <thread>

namespace surfacer::client {

class InterruptHandler {
 public:
  explicit InterruptHandler(std::function<void(int count)> on_signal);
  ~InterruptHandler();

  InterruptHandler(const InterruptHandler&) = delete;
  InterruptHandler& operator=(const InterruptHandler&) = delete;

 private:
  void loop();

  std::function<void(int)> on_signal_;
  int pipe_[2] = {-1, -1};
  struct sigaction old_int_ {};
  struct sigaction old_term_ {};
  std::thread thread_;
};

}  // namespace surfacer::client
