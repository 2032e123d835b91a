// JobWatcher against a scripted fake Surfacer service on a loopback port: reconnect after UNAVAILABLE from the
// smallest missing frame with duplicates skipped, integrity errors, missing frames, server errors.
#include "client/watch.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <functional>
#include <mutex>
#include <sstream>

#include "client/connection.h"
#include "client/frame_writer.h"
#include "client/progress.h"
#include "core/util/crc32.h"
#include "surfacer/v1/surfacer.grpc.pb.h"
#include "tests/support/files.h"
#include "tests/support/loopback_grpc.h"

namespace surfacer::client {
namespace {

namespace fs = std::filesystem;
using surfacer::testing::LoopbackGrpcServer;
using surfacer::testing::read_file;
using Writer = grpc::ServerWriter<v1::JobEvent>;
using Script = std::function<grpc::Status(int call, const v1::WatchJobRequest&, Writer*)>;

class FakeSurfacer final : public v1::Surfacer::Service {
 public:
  explicit FakeSurfacer(Script script) : script_(std::move(script)) {}
  grpc::Status WatchJob(grpc::ServerContext*, const v1::WatchJobRequest* request, Writer* writer) override {
    int call = 0;
    {
      std::lock_guard lock(mutex_);
      call = static_cast<int>(from_frames_.size());
      from_frames_.push_back(request->from_frame());
    }
    return script_(call, *request, writer);
  }
  std::vector<int> from_frames() {
    std::lock_guard lock(mutex_);
    return from_frames_;
  }

 private:
  Script script_;
  std::mutex mutex_;
  std::vector<int> from_frames_;
};

void send_state(Writer* w, v1::JobState state, int frames_total = 3) {
  v1::JobEvent e;
  e.mutable_state()->set_id("j-fake");
  e.mutable_state()->set_state(state);
  e.mutable_state()->set_frames_total(frames_total);
  w->Write(e);
}

std::string frame_bytes(int index) { return "frame bytes #" + std::to_string(index) + std::string(50, 'z'); }

// Sends frame `index` in 3 chunks; stops after `chunks` chunks (a frame cut short).
void send_frame(Writer* w, int index, int chunks = 3, bool corrupt = false) {
  const std::string bytes = frame_bytes(index);
  v1::JobEvent h;
  v1::FrameHeader* header = h.mutable_frame();
  header->set_frame_index(index);
  header->set_encoding(v1::MESH_ENCODING_DRACO);
  header->set_total_bytes(bytes.size());
  header->set_num_chunks(3);
  header->set_crc32(crc32_of(bytes));
  header->mutable_stats()->set_triangles(100 + index);
  w->Write(h);
  const std::size_t size = (bytes.size() + 2) / 3;
  for (int c = 0; c < chunks; ++c) {
    v1::JobEvent e;
    v1::FrameChunk* chunk = e.mutable_chunk();
    chunk->set_frame_index(index);
    chunk->set_chunk_index(c);
    chunk->set_data(bytes.substr(static_cast<std::size_t>(c) * size, size));
    chunk->set_crc32(crc32_of(chunk->data()) ^ (corrupt && c == 1 ? 1u : 0u));
    chunk->set_last(c == 2);
    w->Write(e);
  }
}

class WatchTest : public ::testing::Test {
 protected:
  void start(Script script) {
    service_ = std::make_unique<FakeSurfacer>(std::move(script));
    server_ = std::make_unique<LoopbackGrpcServer>(std::vector<grpc::Service*>{service_.get()});
    ASSERT_TRUE(server_->started());
    ConnectOptions options;
    options.server = server_->address();
    options.timeout_seconds = 5;
    connection_ = Connection::open(options);
    dir_ = fs::temp_directory_path() / ("surfacer_watch_test_" + std::to_string(::getpid()));
    fs::remove_all(dir_);
  }
  void TearDown() override {
    connection_.reset();
    server_.reset();
    fs::remove_all(dir_);
  }
  WatchResult watch(int from_frame = 0, ReconnectPolicy policy = fast_policy()) {
    FrameWriter writer(FrameOutputOptions{dir_, {}});
    ProgressDisplay progress(log_, false);
    JobWatcher watcher(*connection_, "j-fake", from_frame, writer, progress, policy);
    return watcher.run();
  }
  ExitCode watch_error(int from_frame = 0, ReconnectPolicy policy = fast_policy()) {
    try {
      watch(from_frame, policy);
    } catch (const CliError& e) {
      message_ = e.what();
      return e.code();
    }
    return ExitCode::kSuccess;
  }
  static ReconnectPolicy fast_policy() {
    return ReconnectPolicy{std::chrono::milliseconds(3000), std::chrono::milliseconds(20),
                           std::chrono::milliseconds(100)};
  }

  std::unique_ptr<FakeSurfacer> service_;
  std::unique_ptr<LoopbackGrpcServer> server_;
  std::unique_ptr<Connection> connection_;
  fs::path dir_;
  std::ostringstream log_;
  std::string message_;
};

TEST_F(WatchTest, ReconnectsFromSmallestMissingFrameAndSkipsDuplicates) {
  start([](int call, const v1::WatchJobRequest& request, Writer* w) {
    send_state(w, v1::JOB_STATE_RUNNING);
    if (call == 0) {
      EXPECT_EQ(request.from_frame(), 0);
      send_frame(w, 0);
      send_frame(w, 2);     // out of order: frames are computed in parallel
      send_frame(w, 1, 2);  // cut short by the "network"
      return grpc::Status(grpc::StatusCode::UNAVAILABLE, "connection reset");
    }
    for (int i = request.from_frame(); i < 3; ++i) send_frame(w, i);  // 2 again: a duplicate
    send_state(w, v1::JOB_STATE_SUCCEEDED);
    return grpc::Status::OK;
  });
  const WatchResult result = watch();
  EXPECT_EQ(result.job.state(), v1::JOB_STATE_SUCCEEDED);
  EXPECT_EQ(result.frames_written, 3);
  EXPECT_EQ(result.triangles, 100 + 101 + 102);
  EXPECT_EQ(service_->from_frames(), (std::vector<int>{0, 1}));
  for (int i = 0; i < 3; ++i) {
    EXPECT_EQ(read_file(dir_ / frame_file_name(i, FileFormat::kDrc)), frame_bytes(i));
  }
  EXPECT_NE(log_.str().find("reconnecting from frame 1"), std::string::npos) << log_.str();
}

TEST_F(WatchTest, FromFrameIsPassedAndRespected) {
  start([](int, const v1::WatchJobRequest& request, Writer* w) {
    send_state(w, v1::JOB_STATE_RUNNING);
    for (int i = request.from_frame(); i < 3; ++i) send_frame(w, i);
    send_state(w, v1::JOB_STATE_SUCCEEDED);
    return grpc::Status::OK;
  });
  const WatchResult result = watch(1);
  EXPECT_EQ(result.frames_written, 2);
  EXPECT_FALSE(fs::exists(dir_ / "frame_0000.drc"));
  EXPECT_TRUE(fs::exists(dir_ / "frame_0002.drc"));
}

TEST_F(WatchTest, CorruptChunkIsAnIntegrityError) {
  start([](int, const v1::WatchJobRequest&, Writer* w) {
    send_state(w, v1::JOB_STATE_RUNNING);
    send_frame(w, 0, 3, /*corrupt=*/true);
    send_state(w, v1::JOB_STATE_SUCCEEDED);
    return grpc::Status::OK;
  });
  EXPECT_EQ(watch_error(), ExitCode::kIntegrity);
  EXPECT_NE(message_.find("CRC-32"), std::string::npos) << message_;
  EXPECT_FALSE(fs::exists(dir_ / "frame_0000.drc"));
}

TEST_F(WatchTest, SucceededWithMissingFramesIsAnIntegrityError) {
  start([](int, const v1::WatchJobRequest&, Writer* w) {
    send_state(w, v1::JOB_STATE_RUNNING);
    send_frame(w, 0);
    send_state(w, v1::JOB_STATE_SUCCEEDED);
    return grpc::Status::OK;
  });
  EXPECT_EQ(watch_error(), ExitCode::kIntegrity);
  EXPECT_NE(message_.find("1, 2"), std::string::npos) << message_;
}

// Optimize snapshots and active frames: the job announces an upper bound and ends with what it emitted.
TEST_F(WatchTest, OpenEndedJobMayEndWithFewerFramesThanItsBound) {
  start([](int, const v1::WatchJobRequest&, Writer* w) {
    send_state(w, v1::JOB_STATE_RUNNING, 50);
    send_frame(w, 0);
    send_frame(w, 1);
    send_state(w, v1::JOB_STATE_SUCCEEDED, 2);
    return grpc::Status::OK;
  });
  const WatchResult result = watch();
  EXPECT_EQ(result.job.state(), v1::JOB_STATE_SUCCEEDED);
  EXPECT_EQ(result.frames_written, 2);
}

TEST_F(WatchTest, FrameBeforeFromFrameIsAProtocolError) {
  start([](int, const v1::WatchJobRequest&, Writer* w) {
    send_state(w, v1::JOB_STATE_RUNNING);
    send_frame(w, 0);
    return grpc::Status::OK;
  });
  EXPECT_EQ(watch_error(1), ExitCode::kIntegrity);
}

TEST_F(WatchTest, ServerErrorEndsTheWatch) {
  start([](int, const v1::WatchJobRequest&, Writer*) {
    return grpc::Status(grpc::StatusCode::NOT_FOUND, "no job j-fake");
  });
  EXPECT_EQ(watch_error(), ExitCode::kJobFailed);
  EXPECT_NE(message_.find("NOT_FOUND: no job j-fake"), std::string::npos) << message_;
}

TEST_F(WatchTest, GivesUpAfterTheReconnectBudget) {
  start([](int, const v1::WatchJobRequest&, Writer*) { return grpc::Status(grpc::StatusCode::UNAVAILABLE, "down"); });
  const auto t0 = std::chrono::steady_clock::now();
  EXPECT_EQ(watch_error(0, ReconnectPolicy{std::chrono::milliseconds(600), std::chrono::milliseconds(50),
                                           std::chrono::milliseconds(200)}),
            ExitCode::kUnreachable);
  EXPECT_LT(std::chrono::steady_clock::now() - t0, std::chrono::seconds(3));
  EXPECT_NE(message_.find("surfacer watch j-fake --from-frame 0"), std::string::npos) << message_;
  EXPECT_GE(service_->from_frames().size(), 2u);
}

TEST_F(WatchTest, TerminalStatesAreReported) {
  start([](int, const v1::WatchJobRequest&, Writer* w) {
    send_state(w, v1::JOB_STATE_CANCELLED);
    return grpc::Status::OK;
  });
  EXPECT_EQ(watch().job.state(), v1::JOB_STATE_CANCELLED);
}

}  // namespace
}  // namespace surfacer::client
