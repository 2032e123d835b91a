// The server's memory bounds, through a real loopback port: WatchJob streams that never read hold a chunk each, not
// a frame; finished uploads with a durable store live on disk, not in RAM; uploads left idle are ended; uploads and
// watch streams draw from the memory budget (--memory-budget) and are refused beyond it. Memory is read from
// /proc/<pid>/status of a surfacer-server process.
#include <gtest/gtest.h>

#include <chrono>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "core/util/errors.h"
#include "server/memory_budget.h"
#include "tests/server/test_client.h"
#include "tests/support/files.h"
#include "tests/support/server_process.h"

namespace surfacer {
namespace {

using testing::LoopbackServer;
using testing::isosurface_spec;
using testing::scene_from_json;
using testing::submit;
using testing::watch_job;

constexpr std::int64_t kMiB = std::int64_t{1} << 20;

// A gyroid sheet clipped to a sphere, PLY (uncompressed): one frame of about 6 MB x (cells / 32)^2.
v1::JobSpec big_raw_frame(int cells) {
  v1::JobSpec spec = isosurface_spec({scene_from_json(R"({"root": {"intersection": {"children": [
      {"gyroid": {"period": 0.25, "thickness": 0.05}}, {"sphere": {"radius": 1.0}}]}}})")},
                                     cells);
  spec.mutable_output()->set_encoding(v1::MESH_ENCODING_PLY);
  return spec;
}

// Uploads `bytes` (1 MiB chunks); returns the call's status.
grpc::Status try_upload(v1::Surfacer::Stub& stub, const std::string& bytes, v1::UploadResponse* response = nullptr) {
  grpc::ClientContext context;
  v1::UploadResponse reply;
  auto writer = stub.Upload(&context, &reply);
  for (std::size_t offset = 0; offset < bytes.size(); offset += kMiB) {
    v1::UploadChunk chunk;
    if (offset == 0) chunk.set_total_bytes(bytes.size());
    chunk.set_data(bytes.substr(offset, kMiB));
    if (!writer->Write(chunk)) break;
  }
  writer->WritesDone();
  const grpc::Status status = writer->Finish();
  if (response) *response = reply;
  return status;
}

TEST(MemoryBudget, ReservesReleasesAndRefusesNamingTheFlag) {
  server::MemoryBudget budget(10 * kMiB);
  {
    server::MemoryReservation a = budget.reserve(6 * kMiB, "test A");
    EXPECT_EQ(budget.used(), 6 * kMiB);
    try {
      server::MemoryReservation b = budget.reserve(5 * kMiB, "test B");
      ADD_FAILURE() << "a reservation past the budget was granted";
    } catch (const Error& e) {
      EXPECT_EQ(e.kind(), ErrorKind::kResourceLimit);
      EXPECT_NE(std::string(e.what()).find("test B"), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("--memory-budget"), std::string::npos) << e.what();
    }
    EXPECT_EQ(budget.used(), 6 * kMiB);
    a.grow_to(9 * kMiB, "test A");
    EXPECT_EQ(budget.used(), 9 * kMiB);
    EXPECT_THROW(a.grow_to(11 * kMiB, "test A"), Error);
    EXPECT_EQ(a.bytes(), 9 * kMiB);
    server::MemoryReservation moved = std::move(a);
    EXPECT_EQ(budget.used(), 9 * kMiB);
  }
  EXPECT_EQ(budget.used(), 0);
}

TEST(MemoryBudget, ParsesSizes) {
  std::int64_t bytes = 0;
  EXPECT_TRUE(server::parse_byte_size("6G", bytes));
  EXPECT_EQ(bytes, std::int64_t{6} << 30);
  EXPECT_TRUE(server::parse_byte_size("512M", bytes));
  EXPECT_EQ(bytes, 512 * kMiB);
  EXPECT_TRUE(server::parse_byte_size("512MiB", bytes));
  EXPECT_EQ(bytes, 512 * kMiB);
  EXPECT_TRUE(server::parse_byte_size("1048576", bytes));
  EXPECT_EQ(bytes, kMiB);
  EXPECT_TRUE(server::parse_byte_size("2t", bytes));
  EXPECT_EQ(bytes, std::int64_t{2} << 40);
  for (const char* bad : {"", "G", "0", "-1G", "1.5G", "6X", "6GG", "iB", "99999999999T"}) {
    EXPECT_FALSE(server::parse_byte_size(bad, bytes)) << bad;
  }
}

// The surfacer-server binary with a data directory; its resident memory is read from /proc/<pid>/status.
std::int64_t server_resident(const testing::ServerProcess& server) {
  const auto bytes = server.resident_bytes();
  EXPECT_TRUE(bytes.has_value()) << "the server is not running:\n" << server.log();
  return static_cast<std::int64_t>(bytes.value_or(0));
}

// 16 streams that never read one stored frame of about 50 MB: each held its own copy of the frame (server RSS
// +16 x the frame, 800 MB); now each holds a chunk or two.
TEST(MemoryBounds, WatchStreamsThatNeverReadHoldAChunkNotTheFrame) {
  const auto dir = testing::fresh_temp_dir("memory-watch");
  testing::ServerProcess server(dir, 2, {"--data-dir", (dir / "data").string()});
  ASSERT_NE(server.port(), 0) << server.log();
  auto stub = testing::make_stub(server.address());
  std::string id;
  ASSERT_TRUE(submit(*stub, big_raw_frame(90), &id).ok());
  const auto first = watch_job(*stub, id);
  ASSERT_EQ(first.final_job.state(), v1::JOB_STATE_SUCCEEDED) << first.status.error_message();
  ASSERT_EQ(first.frames.size(), 1u);
  const auto frame_bytes = static_cast<std::int64_t>(first.frames.begin()->second.bytes.size());
  ASSERT_GT(frame_bytes, 20 * kMiB) << "the test needs a frame of tens of MB";

  const std::int64_t before = server_resident(server);
  constexpr int kStreams = 16;
  std::vector<std::unique_ptr<grpc::ClientContext>> contexts;
  std::vector<std::unique_ptr<grpc::ClientReader<v1::JobEvent>>> readers;
  v1::WatchJobRequest request;
  request.set_job_id(id);
  for (int i = 0; i < kStreams; ++i) {
    contexts.push_back(std::make_unique<grpc::ClientContext>());
    readers.push_back(stub->WatchJob(contexts.back().get(), request));
  }
  std::this_thread::sleep_for(std::chrono::milliseconds(1500));  // the server reads as far as the streams let it
  const std::int64_t grown = server_resident(server) - before;
  for (auto& context : contexts) context->TryCancel();
  for (auto& reader : readers) reader->Finish();
  // Now: a few MiB per stream (a chunk, gRPC's copy of it and its window).
  EXPECT_LT(grown, kStreams * 6 * kMiB) << "server RSS grew by " << grown / kMiB << " MiB for " << kStreams
                                        << " streams of one " << frame_bytes / kMiB << " MiB frame";
  std::printf("frame %lld MiB, %d never-read streams: server RSS +%lld MiB\n",
              static_cast<long long>(frame_bytes / kMiB), kStreams, static_cast<long long>(grown / kMiB));
}

TEST(MemoryBounds, WatchStreamsPerJobAreCapped) {
  auto options = LoopbackServer::default_options();
  options.max_watchers_per_job = 2;
  LoopbackServer s(options);
  std::string id;
  // A frame larger than gRPC's windows, so that a stream that is not read stays open on the server.
  ASSERT_TRUE(submit(*s.stub, big_raw_frame(40), &id).ok());
  ASSERT_EQ(watch_job(*s.stub, id).final_job.state(), v1::JOB_STATE_SUCCEEDED);
  v1::WatchJobRequest request;
  request.set_job_id(id);
  grpc::ClientContext c1, c2;
  auto r1 = s.stub->WatchJob(&c1, request);
  auto r2 = s.stub->WatchJob(&c2, request);
  v1::JobEvent event;
  ASSERT_TRUE(r1->Read(&event));  // both streams are open on the server once each has sent an event
  ASSERT_TRUE(r2->Read(&event));
  const auto third = watch_job(*s.stub, id);
  EXPECT_EQ(third.status.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
  EXPECT_NE(third.status.error_message().find("--max-watchers-per-job"), std::string::npos)
      << third.status.error_message();
  while (r1->Read(&event)) {
  }
  EXPECT_TRUE(r1->Finish().ok());
  // The finished stream gave its slot back.
  bool watched = false;
  for (int attempt = 0; attempt < 50 && !watched; ++attempt) {
    watched = watch_job(*s.stub, id).status.ok();
    if (!watched) std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  EXPECT_TRUE(watched);
  c2.TryCancel();
  r2->Finish();
}

// Four 64 MiB uploads to a server with a data directory: each stayed in RAM (server RSS +256 MiB); now each is on
// disk only.
TEST(MemoryBounds, FinishedUploadsWithADataDirLiveOnDisk) {
  const auto dir = testing::fresh_temp_dir("memory-uploads");
  testing::ServerProcess server(dir, 1, {"--data-dir", (dir / "data").string()});
  ASSERT_NE(server.port(), 0) << server.log();
  auto stub = testing::make_stub(server.address());
  ASSERT_TRUE(try_upload(*stub, std::string(kMiB, 'w')).ok());  // warm-up: channel and threads
  const std::int64_t before = server_resident(server);
  const std::string bytes(64 * kMiB, 'u');
  for (int i = 0; i < 4; ++i) {
    v1::UploadResponse response;
    const grpc::Status status = try_upload(*stub, bytes, &response);
    ASSERT_TRUE(status.ok()) << status.error_message();
    EXPECT_EQ(response.bytes(), bytes.size());
  }
  const std::int64_t grown = server_resident(server) - before;
  EXPECT_LT(grown, 128 * kMiB) << "server RSS grew by " << grown / kMiB << " MiB after 4 uploads of 64 MiB";
  std::printf("4 uploads of 64 MiB with --data-dir: server RSS +%lld MiB\n", static_cast<long long>(grown / kMiB));
}

// Uploads being received, and uploads kept in memory without a store, draw from the budget; a refusal names it, and
// frees what it held.
TEST(MemoryBounds, UploadsDrawFromTheMemoryBudget) {
  auto options = LoopbackServer::default_options();
  options.limits.memory_budget_bytes = 16 * kMiB;
  LoopbackServer s(options);
  const grpc::Status big = try_upload(*s.stub, std::string(24 * kMiB, 'b'));
  EXPECT_EQ(big.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
  EXPECT_NE(big.error_message().find("--memory-budget"), std::string::npos) << big.error_message();
  // Memory only: a kept upload holds its bytes, so a second that does not fit beside it is refused.
  EXPECT_TRUE(try_upload(*s.stub, std::string(8 * kMiB, 'a')).ok());
  EXPECT_EQ(try_upload(*s.stub, std::string(10 * kMiB, 'c')).error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
  EXPECT_TRUE(try_upload(*s.stub, std::string(4 * kMiB, 'd')).ok());

  // With a data directory, finished uploads are on disk and hold nothing.
  auto durable = LoopbackServer::default_options();
  durable.limits.memory_budget_bytes = 16 * kMiB;
  durable.data_dir = testing::fresh_temp_dir("memory-budget-uploads").string();
  LoopbackServer d(durable);
  for (int i = 0; i < 3; ++i) EXPECT_TRUE(try_upload(*d.stub, std::string(10 * kMiB, 'e')).ok()) << i;
}

TEST(MemoryBounds, IdleUploadsAreEndedNamingTheFlag) {
  auto options = LoopbackServer::default_options();
  options.upload_idle_timeout = std::chrono::milliseconds(300);
  LoopbackServer s(options);
  grpc::ClientContext context;
  v1::UploadResponse response;
  auto writer = s.stub->Upload(&context, &response);
  v1::UploadChunk chunk;
  chunk.set_data(std::string(kMiB, 'i'));
  ASSERT_TRUE(writer->Write(chunk));
  std::this_thread::sleep_for(std::chrono::milliseconds(1200));
  writer->Write(chunk);  // the client continues after the timeout
  writer->WritesDone();
  const grpc::Status status = writer->Finish();
  EXPECT_EQ(status.error_code(), grpc::StatusCode::DEADLINE_EXCEEDED) << status.error_message();
  EXPECT_NE(status.error_message().find("--upload-idle-timeout"), std::string::npos) << status.error_message();
  // An upload that keeps sending is not idle, however long it takes.
  grpc::ClientContext steady_context;
  auto steady = s.stub->Upload(&steady_context, &response);
  for (int i = 0; i < 8; ++i) {
    ASSERT_TRUE(steady->Write(chunk));
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  steady->WritesDone();
  const grpc::Status steady_status = steady->Finish();
  EXPECT_TRUE(steady_status.ok()) << steady_status.error_message();
}

}  // namespace
}  // namespace surfacer
