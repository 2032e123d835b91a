// The chunked uploader: against a recording fake service on a loopback port (chunk sizes, name/total_bytes on the
// first chunk only, a CRC-32 on every chunk, the answer checked) and against the real in-process server (the
// server's byte count and CRC-32 match; uploaded particle frames and grids are accepted by job specs).
#include "client/upload.h"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <mutex>
#include <random>
#include <sstream>

#include "client/connection.h"
#include "client/exit_codes.h"
#include "client/job_spec.h"
#include "client/progress.h"
#include "core/util/crc32.h"
#include "server/options.h"
#include "surfacer/v1/surfacer.grpc.pb.h"
#include "tests/support/files.h"
#include "tests/support/loopback_grpc.h"

namespace surfacer::client {
namespace {

namespace fs = std::filesystem;
using surfacer::testing::fresh_temp_dir;
using surfacer::testing::LoopbackGrpcServer;
using surfacer::testing::write_file;

enum class Answer { kCorrect, kWrongCrc, kShortCount, kNoId, kRefuse };

// Records every chunk; answers as told.
class RecordingSurfacer final : public v1::Surfacer::Service {
 public:
  Answer answer = Answer::kCorrect;

  grpc::Status Upload(grpc::ServerContext*, grpc::ServerReader<v1::UploadChunk>* reader,
                      v1::UploadResponse* response) override {
    std::lock_guard lock(mutex_);
    chunks_.clear();
    std::string all;
    v1::UploadChunk chunk;
    while (reader->Read(&chunk)) {
      chunks_.push_back(chunk);
      all += chunk.data();
    }
    if (answer == Answer::kRefuse) {
      return grpc::Status(grpc::StatusCode::RESOURCE_EXHAUSTED, "upload too large; raise --max-upload-bytes");
    }
    response->set_upload_id(answer == Answer::kNoId ? "" : "u-fake");
    response->set_bytes(all.size() - (answer == Answer::kShortCount ? 1 : 0));
    response->set_crc32(crc32_of(all) ^ (answer == Answer::kWrongCrc ? 0x10u : 0u));
    return grpc::Status::OK;
  }

  std::vector<v1::UploadChunk> chunks() {
    std::lock_guard lock(mutex_);
    return chunks_;
  }

 private:
  std::mutex mutex_;
  std::vector<v1::UploadChunk> chunks_;
};

std::string random_bytes(std::size_t n, unsigned seed) {
  std::mt19937 rng(seed);
  std::string bytes(n, '\0');
  for (auto& c : bytes) c = static_cast<char>(rng() & 0xff);
  return bytes;
}

class FakeUploadTest : public ::testing::Test {
 protected:
  void SetUp() override {
    server_ = std::make_unique<LoopbackGrpcServer>(std::vector<grpc::Service*>{&service_});
    ASSERT_TRUE(server_->started());
    ConnectOptions options;
    options.server = server_->address();
    options.timeout_seconds = 5;
    connection_ = Connection::open(options);
  }
  void TearDown() override {
    connection_.reset();
    server_.reset();
  }
  ExitCode error_of(const std::function<void()>& f) {
    try {
      f();
    } catch (const CliError& e) {
      message_ = e.what();
      return e.code();
    }
    return ExitCode::kSuccess;
  }

  RecordingSurfacer service_;
  std::unique_ptr<LoopbackGrpcServer> server_;
  std::unique_ptr<Connection> connection_;
  std::string message_;
};

TEST_F(FakeUploadTest, ChunksOfAtMostOneMiBEachWithItsCrc) {
  const std::string bytes = random_bytes((std::size_t{5} << 19) + 7, 1);  // 2.5 MiB + 7
  const UploadResult result = upload_bytes(connection_->stub(), "frame_0001.bgeo", bytes);
  EXPECT_EQ(result.upload_id, "u-fake");
  EXPECT_EQ(result.bytes, bytes.size());
  EXPECT_EQ(result.crc32, crc32_of(bytes));

  const auto chunks = service_.chunks();
  ASSERT_EQ(chunks.size(), 3u);
  std::string joined;
  for (std::size_t i = 0; i < chunks.size(); ++i) {
    const auto& c = chunks[i];
    EXPECT_LE(c.data().size(), kMaxChunkBytes) << i;
    EXPECT_GT(c.data().size(), 0u) << i;
    ASSERT_TRUE(c.has_crc32()) << i;
    EXPECT_EQ(c.crc32(), crc32_of(c.data())) << i;
    ASSERT_TRUE(c.has_chunk_index()) << i;
    EXPECT_EQ(c.chunk_index(), i);
    EXPECT_EQ(c.name(), i == 0 ? "frame_0001.bgeo" : "") << i;
    EXPECT_EQ(c.total_bytes(), i == 0 ? bytes.size() : 0u) << i;
    joined += c.data();
  }
  EXPECT_EQ(chunks[0].data().size(), kMaxChunkBytes);
  EXPECT_EQ(chunks[1].data().size(), kMaxChunkBytes);
  EXPECT_EQ(joined, bytes);
}

TEST_F(FakeUploadTest, SmallerChunksAndEmptyAndFileUploads) {
  const std::string bytes = random_bytes(10'000, 2);
  UploadSettings small;
  small.chunk_bytes = 4096;
  upload_bytes(connection_->stub(), "small", bytes, small);
  auto chunks = service_.chunks();
  ASSERT_EQ(chunks.size(), 3u);
  EXPECT_EQ(chunks[2].data().size(), 10'000u - 2 * 4096u);

  // An empty upload still sends one chunk, with the name.
  upload_bytes(connection_->stub(), "empty", "");
  chunks = service_.chunks();
  ASSERT_EQ(chunks.size(), 1u);
  EXPECT_EQ(chunks[0].name(), "empty");
  EXPECT_TRUE(chunks[0].data().empty());

  // Files are streamed with the same chunking.
  const fs::path dir = fresh_temp_dir("upload_fake_file");
  const std::string file_bytes = random_bytes((std::size_t{1} << 20) + 1, 3);
  write_file(dir / "grid.raw", file_bytes);
  const UploadResult result = upload_file(connection_->stub(), "grid.raw", dir / "grid.raw");
  EXPECT_EQ(result.crc32, crc32_of(file_bytes));
  chunks = service_.chunks();
  ASSERT_EQ(chunks.size(), 2u);
  EXPECT_EQ(chunks[0].total_bytes(), file_bytes.size());
  EXPECT_EQ(chunks[0].data() + chunks[1].data(), file_bytes);
  EXPECT_EQ(error_of([&] { upload_file(connection_->stub(), "x", dir / "missing.raw"); }), ExitCode::kUsage);
  EXPECT_NE(message_.find("missing.raw"), std::string::npos) << message_;
  fs::remove_all(dir);

  UploadSettings too_big;
  too_big.chunk_bytes = kMaxChunkBytes + 1;
  EXPECT_EQ(error_of([&] { upload_bytes(connection_->stub(), "x", bytes, too_big); }), ExitCode::kInternal);
}

TEST_F(FakeUploadTest, AnswerThatDoesNotMatchIsAnIntegrityError) {
  const std::string bytes = random_bytes(5000, 4);
  service_.answer = Answer::kWrongCrc;
  EXPECT_EQ(error_of([&] { upload_bytes(connection_->stub(), "p.xyz", bytes); }), ExitCode::kIntegrity);
  EXPECT_NE(message_.find("p.xyz"), std::string::npos) << message_;
  EXPECT_NE(message_.find("CRC-32"), std::string::npos) << message_;
  service_.answer = Answer::kShortCount;
  EXPECT_EQ(error_of([&] { upload_bytes(connection_->stub(), "p.xyz", bytes); }), ExitCode::kIntegrity);
  EXPECT_NE(message_.find("4999 bytes"), std::string::npos) << message_;
  service_.answer = Answer::kNoId;
  EXPECT_EQ(error_of([&] { upload_bytes(connection_->stub(), "p.xyz", bytes); }), ExitCode::kIntegrity);
}

TEST_F(FakeUploadTest, RefusalIsTheServersMessageAndStopCancels) {
  service_.answer = Answer::kRefuse;
  EXPECT_EQ(error_of([&] { upload_bytes(connection_->stub(), "big.bin", random_bytes(100, 5)); }),
            ExitCode::kJobFailed);
  EXPECT_NE(message_.find("uploading big.bin: RESOURCE_EXHAUSTED"), std::string::npos) << message_;
  EXPECT_NE(message_.find("--max-upload-bytes"), std::string::npos) << message_;

  service_.answer = Answer::kCorrect;
  std::atomic<bool> stop{true};
  UploadSettings settings;
  settings.stop = &stop;
  EXPECT_EQ(error_of([&] { upload_bytes(connection_->stub(), "big.bin", random_bytes(100, 5), settings); }),
            ExitCode::kCancelled);
}

// The real server, in process (what `surfacer --local` runs).
// A server that predates GetServerInfo (the fake does not implement it): no limits are known, nothing fails.
TEST_F(FakeUploadTest, AServerThatCannotTellItsLimitsGivesNone) {
  const InputLimits limits = input_limits(*connection_);
  EXPECT_EQ(limits.max_particles, InputLimits{}.max_particles);
  EXPECT_EQ(limits.max_upload_bytes, InputLimits{}.max_upload_bytes);
}

class LocalUploadTest : public ::testing::Test {
 protected:
  void SetUp() override {
    ConnectOptions options;
    options.workers = 1;
    connection_ = Connection::open(options);
  }
  std::unique_ptr<Connection> connection_;
};

TEST_F(LocalUploadTest, TheInProcessServerTellsItsLimits) {
  const InputLimits limits = input_limits(*connection_);
  EXPECT_EQ(limits.max_particles, server::Limits{}.max_particles);
  EXPECT_EQ(limits.max_upload_bytes, server::Limits{}.max_upload_bytes);
}

TEST_F(LocalUploadTest, ServerCountsAndCrcMatch) {
  const std::string bytes = random_bytes((std::size_t{3} << 20) + 123, 6);
  const UploadResult result = upload_bytes(connection_->stub(), "blob.bin", bytes);
  EXPECT_EQ(result.upload_id.rfind("u-", 0), 0u) << result.upload_id;
  EXPECT_EQ(result.bytes, bytes.size());
  EXPECT_EQ(result.crc32, crc32_of(bytes));
  const UploadResult empty = upload_bytes(connection_->stub(), "nothing", "");
  EXPECT_EQ(empty.bytes, 0u);
  EXPECT_NE(empty.upload_id, result.upload_id);
}

// An uploaded float32 grid file is referenced by a job: the server accepts exactly the bytes the grid needs.
TEST_F(LocalUploadTest, UploadedFileFeedsAJob) {
  const fs::path dir = fresh_temp_dir("upload_local_grid");
  const int n = 12;
  std::string bytes;
  for (int k = 0; k < n; ++k) {
    for (int j = 0; j < n; ++j) {
      for (int i = 0; i < n; ++i) {
        const float x = -1.1f + 2.2f * i / (n - 1), y = -1.1f + 2.2f * j / (n - 1), z = -1.1f + 2.2f * k / (n - 1);
        const float d = std::sqrt(x * x + y * y + z * z) - 0.8f;
        bytes.append(reinterpret_cast<const char*>(&d), 4);
      }
    }
  }
  write_file(dir / "sphere.raw", bytes);
  const UploadResult result = upload_file(connection_->stub(), "sphere.raw", dir / "sphere.raw");
  EXPECT_EQ(result.bytes, bytes.size());

  auto submit = [&](int nx) {
    v1::SubmitJobRequest request;
    v1::SampledGrid* grid = request.mutable_spec()->mutable_isosurface()->add_scenes()->mutable_root()->mutable_grid();
    grid->mutable_origin()->set_x(-1.1);
    grid->mutable_origin()->set_y(-1.1);
    grid->mutable_origin()->set_z(-1.1);
    grid->mutable_spacing()->set_x(2.2 / (n - 1));
    grid->mutable_spacing()->set_y(2.2 / (n - 1));
    grid->mutable_spacing()->set_z(2.2 / (n - 1));
    grid->set_nx(nx);
    grid->set_ny(n);
    grid->set_nz(n);
    grid->set_upload_id(result.upload_id);
    request.mutable_spec()->mutable_isosurface()->set_cells(16);
    grpc::ClientContext context;
    v1::SubmitJobResponse response;
    return connection_->stub().SubmitJob(&context, request, &response);
  };
  const grpc::Status ok = submit(n);
  EXPECT_TRUE(ok.ok()) << ok.error_message();
  EXPECT_FALSE(submit(n + 1).ok());  // a grid the upload's bytes do not fill is refused
  fs::remove_all(dir);
}

TEST_F(LocalUploadTest, PendingParticleFramesAreUploadedInOrder) {
  const fs::path dir = fresh_temp_dir("upload_local_frames");
  write_file(dir / "drop_0.xyz", "0 0 0\n0.1 0 0\n");
  write_file(dir / "drop_1.xyz", "0 0 0 0.05\n0.1 0 0 0.05\n0.2 0 0 0.05\n");
  JobOptions options;
  options.spec.mutable_particles()->set_r_inner(0.05);
  options.particles.inputs = {(dir / "drop_{}.xyz").string()};
  PreparedJob prepared = prepare_job(options);
  std::ostringstream log;
  ProgressDisplay progress(log, false);
  const UploadSummary summary = upload_inputs(*connection_, prepared.spec, prepared.uploads, progress);
  EXPECT_EQ(summary.uploads, 2);
  EXPECT_EQ(summary.bytes, 2u * 12 + 3u * 16);
  EXPECT_EQ(summary.particles, (std::map<int, std::int64_t>{{0, 2}, {1, 3}}));
  const auto& frames = prepared.spec.particles().frames();
  ASSERT_EQ(frames.size(), 2);
  EXPECT_EQ(frames[0].upload_id().rfind("u-", 0), 0u);
  EXPECT_EQ(frames[1].upload_id().rfind("u-", 0), 0u);
  EXPECT_NE(frames[0].upload_id(), frames[1].upload_id());
  EXPECT_FALSE(frames[0].with_radius());
  EXPECT_TRUE(frames[1].with_radius());
  EXPECT_NE(log.str().find("uploaded 2/2: particle frame 1"), std::string::npos) << log.str();
  EXPECT_NE(log.str().find("3 particles with radii"), std::string::npos) << log.str();

  // A bad frame stops the uploads with a usage error naming the file and line; nothing after it is read.
  write_file(dir / "drop_1.xyz", "0 0 0\n0.1 zero 0\n");
  prepared = prepare_job(options);
  try {
    upload_inputs(*connection_, prepared.spec, prepared.uploads, progress);
    ADD_FAILURE() << "a bad frame was uploaded";
  } catch (const CliError& e) {
    EXPECT_EQ(e.code(), ExitCode::kUsage);
    EXPECT_NE(std::string(e.what()).find("drop_1.xyz"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("line 2"), std::string::npos) << e.what();
  }
  EXPECT_FALSE(prepared.spec.particles().frames(0).upload_id().empty());
  EXPECT_TRUE(prepared.spec.particles().frames(1).upload_id().empty());
  fs::remove_all(dir);
}

}  // namespace
}  // namespace surfacer::client
