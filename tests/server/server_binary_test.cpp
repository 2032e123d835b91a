// The surfacer-server binary: listens on a real port, serves, and exits 0 on SIGTERM after draining.
#include <gtest/gtest.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <thread>

#include "tests/server/test_client.h"

extern char** environ;

namespace surfacer::testing {
namespace {

using namespace std::chrono_literals;

struct SigtermServer {
  pid_t pid = -1;
  int port = 0;

  explicit SigtermServer(const std::filesystem::path& dir) {
    const std::string port_file = (dir / "port").string();
    std::vector<std::string> args = {SURFACER_BINARY_DIR "/server/surfacer-server", "--listen", "127.0.0.1:0",
                                     "--port-file", port_file, "--workers", "2"};
    std::vector<char*> argv;
    for (auto& a : args) argv.push_back(a.data());
    argv.push_back(nullptr);
    EXPECT_EQ(posix_spawn(&pid, argv[0], nullptr, nullptr, argv.data(), environ), 0);
    const auto until = std::chrono::steady_clock::now() + 20s;
    while (std::chrono::steady_clock::now() < until) {
      std::ifstream in(port_file);
      if (in >> port && port > 0) break;
      std::this_thread::sleep_for(20ms);
    }
  }
  // Exit status, or -1 if it did not exit normally within the time.
  int stop(int sig, std::chrono::seconds within) {
    kill(pid, sig);
    const auto until = std::chrono::steady_clock::now() + within;
    int status = 0;
    while (std::chrono::steady_clock::now() < until) {
      if (waitpid(pid, &status, WNOHANG) == pid) {
        pid = -1;
        return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
      }
      std::this_thread::sleep_for(10ms);
    }
    return -1;
  }
  ~SigtermServer() {
    if (pid > 0) {
      kill(pid, SIGKILL);
      waitpid(pid, nullptr, 0);
    }
  }
};

TEST(ServerBinary, ServesOnARealPortAndExitsZeroOnSigterm) {
  const auto dir = std::filesystem::temp_directory_path() / ("surfacer-bin-" + std::to_string(getpid()));
  std::filesystem::create_directories(dir);
  SigtermServer process(dir);
  ASSERT_GT(process.port, 0);
  auto channel = grpc::CreateChannel("127.0.0.1:" + std::to_string(process.port), grpc::InsecureChannelCredentials());
  auto stub = v1::Surfacer::NewStub(channel);
  std::string id;
  ASSERT_TRUE(submit(*stub, isosurface_spec({scene_from_json(R"({"root": {"torus": {"majorRadius": 1,
      "minorRadius": 0.3}}})")}, 48), &id).ok());
  const auto result = watch_job(*stub, id);
  EXPECT_EQ(result.states.back(), v1::JOB_STATE_SUCCEEDED);
  EXPECT_EQ(result.frames.size(), 1u);
  // A job still running at SIGTERM is drained, then the process exits 0.
  ASSERT_TRUE(submit(*stub, isosurface_spec({scene_from_json(R"({"root": {"sphere": {"radius": 1}}})")}, 96), &id)
                  .ok());
  WatchResult watched;
  std::thread watcher([&] { watched = watch_job(*stub, id); });
  std::this_thread::sleep_for(50ms);
  EXPECT_EQ(process.stop(SIGTERM, 30s), 0);
  watcher.join();
  ASSERT_FALSE(watched.states.empty());
  EXPECT_EQ(watched.states.back(), v1::JOB_STATE_SUCCEEDED);
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace surfacer::testing
