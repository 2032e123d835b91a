// Helpers for end-to-end tests with real processes: a child process with its output in files, and the paths of
// the `surfacer` and `surfacer-server` binaries of this build.
#pragma once

#include <fcntl.h>
#include <netinet/in.h>
#include <signal.h>
#include <spawn.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <memory>
#include <ostream>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

extern char** environ;

namespace surfacer::client::e2e {

namespace fs = std::filesystem;
using namespace std::chrono_literals;

inline const fs::path kSource = SURFACER_SOURCE_DIR;
inline const fs::path kBinary = SURFACER_BINARY_DIR;
inline const fs::path kCli = kBinary / "client" / "surfacer";
inline const fs::path kServer = kBinary / "server" / "surfacer-server";

inline std::string read_file(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

inline void write_file(const fs::path& path, const std::string& text) { std::ofstream(path, std::ios::binary) << text; }

// A child process with stdout/stderr redirected to files.
class Child {
 public:
  Child(const std::vector<std::string>& args, const fs::path& out, const fs::path& err, bool inherit_server_env) {
    std::vector<char*> argv;
    for (const auto& a : args) argv.push_back(const_cast<char*>(a.c_str()));
    argv.push_back(nullptr);
    std::vector<std::string> env_strings;
    for (char** e = environ; *e != nullptr; ++e) {
      if (!inherit_server_env && std::string(*e).rfind("SURFACER_SERVER=", 0) == 0) continue;
      env_strings.emplace_back(*e);
    }
    std::vector<char*> env;
    for (auto& e : env_strings) env.push_back(e.data());
    env.push_back(nullptr);
    posix_spawn_file_actions_t actions;
    posix_spawn_file_actions_init(&actions);
    posix_spawn_file_actions_addopen(&actions, 1, out.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    posix_spawn_file_actions_addopen(&actions, 2, err.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    posix_spawn_file_actions_addopen(&actions, 0, "/dev/null", O_RDONLY, 0);
    const int rc = posix_spawn(&pid_, args[0].c_str(), &actions, nullptr, argv.data(), env.data());
    posix_spawn_file_actions_destroy(&actions);
    if (rc != 0) pid_ = -1;
  }
  ~Child() {
    if (pid_ > 0 && !exited_) {
      ::kill(pid_, SIGKILL);
      ::waitpid(pid_, nullptr, 0);
    }
  }
  Child(const Child&) = delete;
  Child& operator=(const Child&) = delete;

  bool started() const { return pid_ > 0; }
  void signal(int sig) const {
    if (pid_ > 0 && !exited_) ::kill(pid_, sig);
  }
  // Exit code, 128+signal when killed, or -1 after `timeout` (the child is then killed).
  int wait(std::chrono::milliseconds timeout) {
    if (exited_) return code_;
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    while (true) {
      int status = 0;
      const pid_t r = ::waitpid(pid_, &status, WNOHANG);
      if (r == pid_) {
        exited_ = true;
        code_ = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
        return code_;
      }
      if (std::chrono::steady_clock::now() > deadline) {
        ::kill(pid_, SIGKILL);
        ::waitpid(pid_, nullptr, 0);
        exited_ = true;
        code_ = -1;
        return code_;
      }
      std::this_thread::sleep_for(10ms);
    }
  }

 private:
  pid_t pid_ = -1;
  bool exited_ = false;
  int code_ = -1;
};

struct Result {
  int code = -1;
  std::string out;
  std::string err;
};

inline std::ostream& operator<<(std::ostream& os, const Result& r) {
  return os << "exit " << r.code << "\n--- stdout\n" << r.out << "--- stderr\n" << r.err;
}

inline int free_port() {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  addr.sin_port = 0;
  ::bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr);
  socklen_t len = sizeof addr;
  ::getsockname(fd, reinterpret_cast<sockaddr*>(&addr), &len);
  const int port = ntohs(addr.sin_port);
  ::close(fd);
  return port;
}

// A `surfacer-server` child listening on 127.0.0.1 (port 0, read back from --port-file), SIGTERM on destruction.
class ServerProcess {
 public:
  ServerProcess(const fs::path& dir, int workers) : dir_(dir) {
    fs::create_directories(dir_);
    const fs::path port_file = dir_ / "port";
    child_ = std::make_unique<Child>(
        std::vector<std::string>{kServer.string(), "--listen", "127.0.0.1:0", "--port-file", port_file.string(),
                                 "--workers", std::to_string(workers), "--drain-seconds", "1"},
        dir_ / "server.out", dir_ / "server.err", false);
    if (!child_->started()) return;
    const auto deadline = std::chrono::steady_clock::now() + 20s;
    while (std::chrono::steady_clock::now() < deadline) {
      const std::string text = read_file(port_file);
      if (!text.empty() && text.back() == '\n') {
        address_ = "127.0.0.1:" + std::to_string(std::stoi(text));
        return;
      }
      std::this_thread::sleep_for(20ms);
    }
  }
  ~ServerProcess() { stop(); }
  ServerProcess(const ServerProcess&) = delete;
  ServerProcess& operator=(const ServerProcess&) = delete;

  // "127.0.0.1:PORT", or empty when the server did not start.
  const std::string& address() const { return address_; }
  std::string log() const { return read_file(dir_ / "server.err"); }
  // SIGKILL and wait (a crash: no drain, connections reset).
  void kill_now() {
    if (!child_) return;
    child_->signal(SIGKILL);
    code_ = child_->wait(10s);
    child_.reset();
  }
  // SIGTERM and wait: the exit code (0 for a clean drain), or -1 when it did not exit within 10 s.
  int stop() {
    if (!child_) return code_;
    child_->signal(SIGTERM);
    code_ = child_->wait(10s);
    child_.reset();
    return code_;
  }

 private:
  fs::path dir_;
  std::unique_ptr<Child> child_;
  std::string address_;
  int code_ = -1;
};

}  // namespace surfacer::client::e2e
