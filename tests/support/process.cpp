#include "tests/support/process.h"

#include <errno.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <signal.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <fstream>
#include <thread>

#include "tests/support/files.h"

extern char** environ;

namespace surfacer::testing {

namespace fs = std::filesystem;

fs::path cli_binary() { return fs::path(SURFACER_BINARY_DIR) / "client" / "surfacer"; }
fs::path server_binary() { return fs::path(SURFACER_BINARY_DIR) / "server" / "surfacer-server"; }

namespace {

int exit_code(int status) { return WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status); }

}  // namespace

ChildProcess::ChildProcess(const std::vector<std::string>& args, const fs::path& out, const fs::path& err,
                           std::optional<std::uint64_t> file_size_limit)
    : out_(out), err_(err) {
  if (args.empty()) return;
  // Everything the child needs is made before fork(): between fork and exec it makes only async-signal-safe calls.
  std::vector<std::string> arg_strings = args;
  std::vector<char*> argv;
  for (auto& a : arg_strings) argv.push_back(a.data());
  argv.push_back(nullptr);
  std::vector<std::string> env_strings;
  for (char** e = environ; *e != nullptr; ++e) {
    if (std::string_view(*e).starts_with("SURFACER_SERVER=")) continue;
    env_strings.emplace_back(*e);
  }
  std::vector<char*> envp;
  for (auto& e : env_strings) envp.push_back(e.data());
  envp.push_back(nullptr);
  const std::string out_name = out.string(), err_name = err.string();
  const rlimit limit{file_size_limit.value_or(RLIM_INFINITY), file_size_limit.value_or(RLIM_INFINITY)};
  // The child reports a failure to set up or exec through this pipe; a successful exec closes it unwritten.
  int report[2];
  if (::pipe2(report, O_CLOEXEC) != 0) return;
  const pid_t pid = ::fork();
  if (pid == 0) {
    const int in_fd = ::open("/dev/null", O_RDONLY | O_CLOEXEC);
    const int out_fd = ::open(out_name.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
    const int err_fd = ::open(err_name.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
    if (in_fd >= 0 && out_fd >= 0 && err_fd >= 0 && ::dup2(in_fd, 0) == 0 && ::dup2(out_fd, 1) == 1 &&
        ::dup2(err_fd, 2) == 2) {
      if (file_size_limit) {
        ::signal(SIGXFSZ, SIG_IGN);  // writes past the limit fail with EFBIG instead of killing the process
        ::setrlimit(RLIMIT_FSIZE, &limit);
      }
      ::execve(argv[0], argv.data(), envp.data());
    }
    const int error = errno;
    [[maybe_unused]] const auto written = ::write(report[1], &error, sizeof error);
    ::_exit(127);
  }
  ::close(report[1]);
  if (pid < 0) {
    ::close(report[0]);
    return;
  }
  int error = 0;
  ssize_t n = 0;
  do {
    n = ::read(report[0], &error, sizeof error);
  } while (n < 0 && errno == EINTR);
  ::close(report[0]);
  if (n > 0) {
    ::waitpid(pid, nullptr, 0);
    return;
  }
  pid_ = pid;
}

ChildProcess::~ChildProcess() {
  if (pid_ > 0 && !exited_) {
    ::kill(pid_, SIGKILL);
    ::waitpid(pid_, nullptr, 0);
  }
}

void ChildProcess::signal(int sig) const {
  if (pid_ > 0 && !exited_) ::kill(pid_, sig);
}

namespace {
// A "Key:   12345 kB" line of /proc/PID/status, in bytes.
std::optional<std::uint64_t> status_kb_field(pid_t pid, const std::string& key) {
  std::ifstream status("/proc/" + std::to_string(pid) + "/status");
  std::string line;
  while (std::getline(status, line)) {
    if (line.rfind(key, 0) == 0) return std::stoull(line.substr(key.size())) * 1024;
  }
  return std::nullopt;
}
}  // namespace

std::optional<std::uint64_t> ChildProcess::peak_rss_bytes() const {
  if (pid_ <= 0) return std::nullopt;
  if (exited_) return peak_rss_;
  return status_kb_field(pid_, "VmHWM:");
}

std::optional<std::uint64_t> ChildProcess::resident_bytes() const {
  if (pid_ <= 0 || exited_) return std::nullopt;
  return status_kb_field(pid_, "VmRSS:");
}

std::optional<int> ChildProcess::poll() {
  if (pid_ <= 0) return -1;
  if (!exited_) {
    int status = 0;
    rusage usage{};
    if (::wait4(pid_, &status, WNOHANG, &usage) != pid_) return std::nullopt;
    exited_ = true;
    code_ = exit_code(status);
    peak_rss_ = static_cast<std::uint64_t>(usage.ru_maxrss) * 1024;
  }
  return code_;
}

int ChildProcess::wait(std::chrono::milliseconds timeout) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  while (true) {
    if (const std::optional<int> code = poll()) return *code;
    if (std::chrono::steady_clock::now() > deadline) {
      ::kill(pid_, SIGKILL);
      ::waitpid(pid_, nullptr, 0);
      exited_ = true;
      code_ = -1;
      return code_;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
}

std::ostream& operator<<(std::ostream& os, const ProcessResult& r) {
  return os << "exit " << r.code << "\n--- stdout\n" << r.out << "--- stderr\n" << r.err;
}

ProcessResult finish(ChildProcess& child, std::chrono::milliseconds timeout) {
  ProcessResult r;
  r.code = child.wait(timeout);
  r.peak_rss_bytes = child.peak_rss_bytes().value_or(0);
  r.out = read_file(child.out_path());
  r.err = read_file(child.err_path());
  return r;
}

ProcessResult run_process(const std::vector<std::string>& args, const fs::path& out, const fs::path& err,
                          std::chrono::milliseconds timeout) {
  ChildProcess child(args, out, err);
  return finish(child, timeout);
}

int free_port() {
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

}  // namespace surfacer::testing
