// The surfacer-server binary: listens on a real port, serves, and exits 0 on SIGTERM after draining.
#include <gtest/gtest.h>

#include <chrono>
#include <filesystem>
#include <thread>

#include "tests/server/test_client.h"
#include "tests/support/files.h"
#include "tests/support/server_process.h"

namespace surfacer::testing {
namespace {

using namespace std::chrono_literals;

TEST(ServerBinary, ServesOnARealPortAndExitsZeroOnSigterm) {
  const auto dir = fresh_temp_dir("bin");
  ServerProcess process(dir, 2);
  ASSERT_GT(process.port(), 0) << process.log();
  auto stub = make_stub(process.address());
  std::string id;
  ASSERT_TRUE(submit(*stub,
                     isosurface_spec({scene_from_json(R"({"root": {"torus": {"majorRadius": 1,
      "minorRadius": 0.3}}})")},
                                     48),
                     &id)
                  .ok());
  const auto result = watch_job(*stub, id);
  EXPECT_EQ(result.states.back(), v1::JOB_STATE_SUCCEEDED);
  EXPECT_EQ(result.frames.size(), 1u);
  // A job still running at SIGTERM is drained, then the process exits 0.
  ASSERT_TRUE(
      submit(*stub, isosurface_spec({scene_from_json(R"({"root": {"sphere": {"radius": 1}}})")}, 96), &id).ok());
  WatchResult watched;
  std::thread watcher([&] { watched = watch_job(*stub, id); });
  std::this_thread::sleep_for(50ms);
  EXPECT_EQ(process.stop(30s), 0);
  watcher.join();
  ASSERT_FALSE(watched.states.empty());
  EXPECT_EQ(watched.states.back(), v1::JOB_STATE_SUCCEEDED);
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace surfacer::testing
