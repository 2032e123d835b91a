#include "tests/support/server_process.h"

#include <signal.h>

#include <atomic>
#include <thread>

#include "tests/support/files.h"

namespace surfacer::testing {

namespace fs = std::filesystem;

ServerProcess::ServerProcess(const fs::path& dir, int workers, const std::vector<std::string>& flags,
                             std::optional<std::uint64_t> file_size_limit) {
  static std::atomic<int> counter{0};
  const std::string n = std::to_string(++counter);
  fs::create_directories(dir);
  const fs::path port_file = dir / ("port" + n);
  fs::remove(port_file);
  log_ = dir / ("server" + n + ".log");
  std::vector<std::string> args = {server_binary().string(), "--listen",  "127.0.0.1:0",          "--port-file",
                                   port_file.string(),       "--workers", std::to_string(workers)};
  args.insert(args.end(), flags.begin(), flags.end());
  child_ = std::make_unique<ChildProcess>(args, dir / ("server" + n + ".out"), log_, file_size_limit);
  if (!child_->started()) return;
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(30);
  while (std::chrono::steady_clock::now() < deadline && !child_->poll()) {
    const std::string text = read_file(port_file);
    if (!text.empty() && text.back() == '\n') {
      port_ = std::stoi(text);
      address_ = "127.0.0.1:" + std::to_string(port_);
      return;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
}

ServerProcess::~ServerProcess() { kill_now(); }

std::string ServerProcess::log() const { return read_file(log_); }

std::optional<std::uint64_t> ServerProcess::peak_rss_bytes() const {
  return child_ ? child_->peak_rss_bytes() : std::nullopt;
}

std::optional<std::uint64_t> ServerProcess::resident_bytes() const {
  return child_ ? child_->resident_bytes() : std::nullopt;
}

void ServerProcess::kill_now() {
  if (!child_) return;
  child_->signal(SIGKILL);
  code_ = child_->wait(std::chrono::seconds(10));
  child_.reset();
}

int ServerProcess::stop(std::chrono::seconds within) {
  if (!child_) return code_;
  child_->signal(SIGTERM);
  code_ = child_->wait(within);
  child_.reset();
  return code_;
}

}  // namespace surfacer::testing
