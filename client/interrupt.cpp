#include "client/interrupt.h"

#include <fcntl.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <stdexcept>

namespace surfacer::client {
namespace {

std::atomic<int> g_signal_fd{-1};

constexpr char kSignalByte = 's';
constexpr char kStopByte = 'q';

extern "C" void on_signal_handler(int) {
  const int saved = errno;
  const int fd = g_signal_fd.load();
  if (fd >= 0) {
    const char byte = kSignalByte;
    [[maybe_unused]] ssize_t n = ::write(fd, &byte, 1);  // async-signal-safe
  }
  errno = saved;
}

}  // namespace

InterruptHandler::InterruptHandler(std::function<void(int)> on_signal) : on_signal_(std::move(on_signal)) {
  if (::pipe2(pipe_, O_CLOEXEC) != 0) throw std::runtime_error("pipe2 failed");
  g_signal_fd.store(pipe_[1]);
  struct sigaction action {};
  action.sa_handler = on_signal_handler;
  sigemptyset(&action.sa_mask);
  action.sa_flags = SA_RESTART;
  sigaction(SIGINT, &action, &old_int_);
  sigaction(SIGTERM, &action, &old_term_);
  thread_ = std::thread([this] { loop(); });
}

InterruptHandler::~InterruptHandler() {
  sigaction(SIGINT, &old_int_, nullptr);
  sigaction(SIGTERM, &old_term_, nullptr);
  const char byte = kStopByte;
  [[maybe_unused]] ssize_t n = ::write(pipe_[1], &byte, 1);
  if (thread_.joinable()) thread_.join();
  g_signal_fd.store(-1);
  ::close(pipe_[0]);
  ::close(pipe_[1]);
}

void InterruptHandler::loop() {
  int count = 0;
  while (true) {
    char byte = 0;
    const ssize_t n = ::read(pipe_[0], &byte, 1);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0 || byte == kStopByte) return;
    on_signal_(++count);
  }
}

}  // namespace surfacer::client
