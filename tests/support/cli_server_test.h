// A test fixture for the `surfacer` CLI against one `surfacer-server` child shared by the suite: the server starts
// before the suite's first test (in <temp>/<Suite::kName>/server, with Suite::server_flags()) and must stop cleanly
// on SIGTERM after its last; each test runs the CLI in a directory of its own. A suite derives from
// CliServerTest<Suite> and gives kName, server_flags() and, when it needs input files, write_inputs(root).
#pragma once

#include <gtest/gtest.h>

#include <chrono>
#include <filesystem>
#include <string>
#include <vector>

#include "tests/support/files.h"
#include "tests/support/process.h"
#include "tests/support/server_process.h"

namespace surfacer::testing {

template <class Suite>
class CliServerTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    root_ = fresh_temp_dir(Suite::kName);
    Suite::write_inputs(root_);
    server_ = new ServerProcess(root_ / "server", 2, Suite::server_flags());
    ASSERT_FALSE(server_->address().empty()) << "surfacer-server did not start:\n" << server_->log();
  }
  static void TearDownTestSuite() {
    if (server_ != nullptr) {
      EXPECT_EQ(server_->stop(), 0) << server_->log();
      delete server_;
      server_ = nullptr;
    }
    std::filesystem::remove_all(root_);
  }
  static void write_inputs(const std::filesystem::path&) {}

  void SetUp() override {
    ASSERT_NE(server_, nullptr);
    dir_ = current_test_dir(root_);
  }

  // `surfacer --server ADDRESS ARGS...`, its output in this test's directory.
  ProcessResult cli(std::vector<std::string> args, std::chrono::seconds timeout = std::chrono::seconds(60)) {
    args.insert(args.begin(), {cli_binary().string(), "--server", server_->address()});
    const std::string tag = "cli" + std::to_string(counter_++);
    return run_process(args, dir_ / (tag + ".out"), dir_ / (tag + ".err"), timeout);
  }

  static inline std::filesystem::path root_;
  static inline ServerProcess* server_ = nullptr;
  std::filesystem::path dir_;
  int counter_ = 0;
};

}  // namespace surfacer::testing
