// `surfacer submit` of a particle sequence (submit_with_inputs) against a real `surfacer-server` on a loopback port:
// the job is queued with the first frame and the others join it as they are uploaded, so frame 0 is done while the
// last frame is still being read; it returns only once the sequence is ended; its frames are byte for byte those of
// the same job sent to a server without open sequences (a proxy that hides ServerInfo.open_sequences), which still
// gets the whole sequence at submit; a frame that fails after the job started fails the job naming that frame, the
// frames before it kept.
#include <grpcpp/client_context.h>
#include <grpcpp/create_channel.h>
#include <grpcpp/security/credentials.h>
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <mutex>
#include <random>
#include <sstream>
#include <thread>

#include "client/commands.h"
#include "client/connection.h"
#include "client/job_spec.h"
#include "client/progress.h"
#include "client/upload.h"
#include "surfacer/v1/surfacer.grpc.pb.h"
#include "tests/support/files.h"
#include "tests/support/loopback_grpc.h"
#include "tests/support/process.h"
#include "tests/support/server_process.h"

namespace surfacer::client {
namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;
using namespace surfacer::testing;

constexpr int kFrames = 6;

// A jittered lattice ball of spacing 0.05 and radius 0.25 around (0.04 k, 0, 0): "x y z" lines.
std::string droplet(int k) {
  std::mt19937 rng(static_cast<unsigned>(40 + k));
  std::uniform_real_distribution<double> jitter(-0.005, 0.005);
  std::string text;
  char line[96];
  for (int z = -5; z <= 5; ++z) {
    for (int y = -5; y <= 5; ++y) {
      for (int x = -5; x <= 5; ++x) {
        if (x * x + y * y + z * z > 25) continue;
        std::snprintf(line, sizeof line, "%.6f %.6f %.6f\n", 0.05 * x + 0.04 * k + jitter(rng), 0.05 * y + jitter(rng),
                      0.05 * z + jitter(rng));
        text += line;
      }
    }
  }
  return text;
}

// A server as it was before open sequences: the real one behind, its ServerInfo without open_sequences and no
// AppendFrames. Records the specs submitted through it.
class OldServer final : public v1::Surfacer::Service {
 public:
  explicit OldServer(const std::string& address)
      : stub_(v1::Surfacer::NewStub(grpc::CreateChannel(address, grpc::InsecureChannelCredentials()))) {}

  grpc::Status GetServerInfo(grpc::ServerContext*, const v1::GetServerInfoRequest* request,
                             v1::ServerInfo* info) override {
    grpc::ClientContext context;
    const grpc::Status status = stub_->GetServerInfo(&context, *request, info);
    info->clear_open_sequences();
    return status;
  }
  grpc::Status Upload(grpc::ServerContext*, grpc::ServerReader<v1::UploadChunk>* reader,
                      v1::UploadResponse* response) override {
    grpc::ClientContext context;
    auto writer = stub_->Upload(&context, response);
    v1::UploadChunk chunk;
    while (reader->Read(&chunk)) {
      if (!writer->Write(chunk)) break;
    }
    writer->WritesDone();
    return writer->Finish();
  }
  grpc::Status SubmitJob(grpc::ServerContext*, const v1::SubmitJobRequest* request,
                         v1::SubmitJobResponse* response) override {
    {
      std::lock_guard lock(mutex_);
      submitted_.push_back(request->spec());
    }
    grpc::ClientContext context;
    return stub_->SubmitJob(&context, *request, response);
  }

  std::vector<v1::JobSpec> submitted() {
    std::lock_guard lock(mutex_);
    return submitted_;
  }

 private:
  std::unique_ptr<v1::Surfacer::Stub> stub_;
  std::mutex mutex_;
  std::vector<v1::JobSpec> submitted_;
};

class StreamedSubmit : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fresh_temp_dir(std::string("streamed_submit_") +
                          ::testing::UnitTest::GetInstance()->current_test_info()->name());
    server_ = std::make_unique<ServerProcess>(dir_ / "server", 2, std::vector<std::string>{"--drain-seconds", "1"});
    ASSERT_FALSE(server_->address().empty()) << server_->log();
    for (int k = 0; k < kFrames; ++k) write_file(dir_ / ("drop_" + std::to_string(k) + ".xyz"), droplet(k));
    watcher_ = connect(server_->address());
  }
  void TearDown() override {
    watcher_.reset();
    if (server_) {
      EXPECT_EQ(server_->stop(), 0) << server_->log();
    }
    if (!HasFailure()) fs::remove_all(dir_);
  }

  static std::unique_ptr<Connection> connect(const std::string& address) {
    ConnectOptions options;
    options.server = address;
    options.timeout_seconds = 10;
    return Connection::open(options);
  }

  // The sequence drop_0..5.xyz as `surfacer submit particles --r-inner 0.03 --name NAME` prepares it.
  PreparedJob prepared(const std::string& name) const {
    JobOptions job;
    job.particles.inputs = {(dir_ / "drop_{}.xyz").string()};
    job.spec.mutable_particles()->set_r_inner(0.03);
    job.name = name;
    return prepare_job(job);
  }

  // The running job named `name` on the real server with at least one frame done.
  bool first_frame_done(const std::string& name) {
    for (const v1::Job& job : list_jobs(*watcher_, {})) {
      if (job.name() == name && job.frames_done() >= 1) return true;
    }
    return false;
  }

  // Makes the upload read of frame `k` (its second read: the first is the check of every frame before the job is
  // queued) wait until the job named `name` has frame 0 done, at most 30 s; `seen` says whether it was.
  void wait_in_upload_of(PreparedJob& job, int k, const std::string& name, std::shared_ptr<std::atomic<bool>> seen) {
    PendingUpload& pending = job.uploads.at(static_cast<std::size_t>(k));
    auto reads = std::make_shared<int>(0);
    pending.read = [this, read = pending.read, reads, name, seen](v1::JobSpec& spec, const InputLimits& limits) {
      if (++*reads == 2) {
        const auto until = std::chrono::steady_clock::now() + 30s;
        while (!first_frame_done(name) && std::chrono::steady_clock::now() < until) std::this_thread::sleep_for(20ms);
        *seen = first_frame_done(name);
      }
      return read(spec, limits);
    };
  }

  // `surfacer watch ID -o DIR` against the real server.
  ProcessResult watch(const std::string& id, const fs::path& out) {
    const std::string tag = "watch-" + out.filename().string();
    return run_process({cli_binary().string(), "--server", server_->address(), "watch", id, "-o", out.string()},
                       dir_ / (tag + ".out"), dir_ / (tag + ".err"), 60s);
  }

  fs::path dir_;
  std::unique_ptr<ServerProcess> server_;
  std::unique_ptr<Connection> watcher_;
};

std::string frame_name(int k) {
  char name[32];
  std::snprintf(name, sizeof name, "frame_%04d.drc", k);
  return name;
}

TEST_F(StreamedSubmit, FirstFrameIsDoneBeforeTheLastUploadsAndFramesMatchAnOldServers) {
  auto connection = connect(server_->address());
  std::ostringstream err;
  ProgressDisplay progress(err, false);
  PreparedJob job = prepared("streamed");
  auto seen = std::make_shared<std::atomic<bool>>(false);
  wait_in_upload_of(job, kFrames - 1, "streamed", seen);
  const std::string id = submit_with_inputs(*connection, job, progress);
  EXPECT_TRUE(*seen) << "frame 0 was not done while frame " << kFrames - 1 << " was being read for its upload\n"
                     << err.str();
  // Returned once the sequence is ended: every frame is in the job, which needs no more.
  const v1::Job queued = get_job(*connection, id);
  EXPECT_EQ(queued.frames_total(), kFrames);
  EXPECT_NE(err.str().find("uploaded 6/6: particle frame 5"), std::string::npos) << err.str();
  const std::string log = server_->log();
  const std::size_t submitted = log.find("event=job_submitted job=" + id);
  ASSERT_NE(submitted, std::string::npos) << log;
  EXPECT_NE(log.substr(submitted, log.find('\n', submitted) - submitted).find("frames=1"), std::string::npos) << log;

  // The same job through a server without open sequences: every frame uploaded, then one closed submit.
  OldServer old(server_->address());
  LoopbackGrpcServer proxy({&old});
  ASSERT_TRUE(proxy.started());
  auto old_connection = connect(proxy.address());
  PreparedJob whole = prepared("whole");
  const std::string old_id = submit_with_inputs(*old_connection, whole, progress);
  ASSERT_EQ(old.submitted().size(), 1u);
  EXPECT_EQ(old.submitted()[0].particles().frames_size(), kFrames);
  EXPECT_FALSE(old.submitted()[0].particles().open());

  const ProcessResult a = watch(id, dir_ / "streamed");
  ASSERT_EQ(a.code, 0) << a;
  const ProcessResult b = watch(old_id, dir_ / "whole");
  ASSERT_EQ(b.code, 0) << b;
  for (int k = 0; k < kFrames; ++k) {
    const std::string streamed = read_file(dir_ / "streamed" / frame_name(k));
    EXPECT_FALSE(streamed.empty()) << frame_name(k);
    EXPECT_TRUE(streamed == read_file(dir_ / "whole" / frame_name(k))) << frame_name(k) << " differs";
  }
}

// A frame that turns bad after the check (the file rewritten with a NaN before its upload) fails the job with the
// reader's message naming the frame, the file and its line; submit throws naming the job, whose earlier frames stay.
TEST_F(StreamedSubmit, AFrameThatFailsAfterTheJobStartedFailsItNamingTheFrame) {
  auto connection = connect(server_->address());
  std::ostringstream err;
  ProgressDisplay progress(err, false);
  PreparedJob job = prepared("bad-frame");
  constexpr int kBad = 3;
  auto reads = std::make_shared<int>(0);
  PendingUpload& pending = job.uploads[kBad];
  const fs::path bad = dir_ / ("drop_" + std::to_string(kBad) + ".xyz");
  pending.read = [read = pending.read, reads, bad, this](v1::JobSpec& spec, const InputLimits& limits) {
    if (++*reads == 2) {
      // The frames before it are done first, so the test can tell they are kept.
      const auto until = std::chrono::steady_clock::now() + 30s;
      while (std::chrono::steady_clock::now() < until) {
        bool done = false;
        for (const v1::Job& j : list_jobs(*watcher_, {})) {
          done = done || (j.name() == "bad-frame" && j.frames_done() >= kBad);
        }
        if (done) break;
        std::this_thread::sleep_for(20ms);
      }
      write_file(bad, droplet(kBad) + "0.1 nan 0.2\n");
    }
    return read(spec, limits);
  };
  std::string message;
  try {
    submit_with_inputs(*connection, job, progress);
    ADD_FAILURE() << "submit succeeded with a bad frame";
  } catch (const CliError& e) {
    message = e.what();
    EXPECT_EQ(e.code(), ExitCode::kUsage) << message;
  }
  EXPECT_NE(message.find("particle frame 3 (" + bad.string() + ")"), std::string::npos) << message;
  EXPECT_NE(message.find("line "), std::string::npos) << message;
  const std::size_t at = message.find("; job ");
  ASSERT_NE(at, std::string::npos) << message;
  const std::string id = message.substr(at + 6, message.find(' ', at + 6) - at - 6);
  const ProcessResult w = watch(id, dir_ / "kept");
  EXPECT_EQ(w.code, 4) << w;
  EXPECT_NE(w.err.find("particle frame 3"), std::string::npos) << w;
  for (int k = 0; k < kBad; ++k) EXPECT_TRUE(fs::exists(dir_ / "kept" / frame_name(k))) << frame_name(k) << "\n" << w;
  EXPECT_FALSE(fs::exists(dir_ / "kept" / frame_name(kBad)));
}

}  // namespace
}  // namespace surfacer::client
