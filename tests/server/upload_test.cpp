// Uploads that do not end well leave nothing behind: a stream the client cancels, one whose deadline passes, one
// with a message gRPC refuses, and one cancelled after its last chunk, in memory, on disk, in a tenant's quota and
// after a restart. Chunks over 1 MiB, and chunks out of their announced order, are refused as they arrive.
#include <gtest/gtest.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <thread>

#include "tests/server/test_client.h"
#include "tests/support/files.h"
#include "wire/protocol.h"

namespace surfacer::testing {
namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;

enum class End { kClose, kCancel, kCancelAfterLastChunk, kDeadline };

// An upload of `chunks` chunks of `chunk_bytes` (total_bytes not announced, so a cut stream looks complete), ended
// as `end` says. Returns the call's status; *id gets the upload id when it succeeded.
grpc::Status upload(v1::Surfacer::Stub& stub, int chunks, std::size_t chunk_bytes, End end, std::string* id = nullptr,
                    const std::string& token = "") {
  grpc::ClientContext context;
  if (!token.empty()) context.AddMetadata("authorization", "Bearer " + token);
  if (end == End::kDeadline) context.set_deadline(std::chrono::system_clock::now() + 500ms);
  v1::UploadResponse response;
  auto writer = stub.Upload(&context, &response);
  for (int c = 0; c < chunks; ++c) {
    v1::UploadChunk chunk;
    if (c == 0) chunk.set_name("aborted.bin");
    chunk.set_data(std::string(chunk_bytes, static_cast<char>('a' + c % 26)));
    if (!writer->Write(chunk)) break;
  }
  switch (end) {
    case End::kClose:
      writer->WritesDone();
      break;
    case End::kCancel:
      context.TryCancel();
      break;
    case End::kCancelAfterLastChunk:
      writer->WritesDone();
      context.TryCancel();
      break;
    case End::kDeadline:
      std::this_thread::sleep_for(1s);
      break;
  }
  const grpc::Status status = writer->Finish();
  if (id) *id = status.ok() ? response.upload_id() : "";
  return status;
}

double stored_bytes(server::SurfacerServer& server) {
  return metric_sample(server.metrics_text(), "surfacer_stored_bytes");
}

// Waits (up to 10 s) until the server holds `bytes` stored bytes: the server sees a cancel a moment after the client.
void expect_stored_bytes(server::SurfacerServer& server, double bytes) {
  const auto until = std::chrono::steady_clock::now() + 10s;
  while (stored_bytes(server) != bytes && std::chrono::steady_clock::now() < until) std::this_thread::sleep_for(10ms);
  EXPECT_EQ(stored_bytes(server), bytes);
}

std::size_t files_in(const fs::path& dir) {
  std::size_t n = 0;
  for ([[maybe_unused]] const auto& f : fs::directory_iterator(dir)) ++n;
  return n;
}

TEST(Uploads, CancelledAndTimedOutUploadsAreNotKept) {
  LoopbackServer s;
  const std::size_t mib = wire::kMaxChunkBytes;
  for (int i = 0; i < 20; ++i) EXPECT_FALSE(upload(*s.stub, 3, mib, End::kCancel).ok());
  for (int i = 0; i < 3; ++i) {
    EXPECT_EQ(upload(*s.stub, 2, mib, End::kDeadline).error_code(), grpc::StatusCode::DEADLINE_EXCEEDED);
  }
  // A message over gRPC's 4 MiB: gRPC refuses it, and the call with it.
  EXPECT_EQ(upload(*s.stub, 1, 5 * mib, End::kClose).error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
  expect_stored_bytes(*s.server, 0);
  // Cancelled right after the last chunk: every upload whose id reached the client is kept. One whose reply crossed
  // the cancel on the wire may be kept too (the server saw a complete call, the client dropped its reply): nothing
  // references it, and retention removes it like any unused upload.
  int kept = 0;
  for (int i = 0; i < 20; ++i) {
    std::string id;
    if (upload(*s.stub, 1, 1000, End::kCancelAfterLastChunk, &id).ok()) {
      EXPECT_FALSE(id.empty());
      ++kept;
    }
  }
  // A whole upload is kept.
  std::string id;
  ASSERT_TRUE(upload(*s.stub, 2, mib, End::kClose, &id).ok());
  const double stored = stored_bytes(*s.server);
  EXPECT_GE(stored, 1000.0 * kept + 2.0 * mib);
  EXPECT_LE(stored, 1000.0 * 20 + 2.0 * mib);
}

TEST(Uploads, AbortedUploadsUseNoQuotaAndLeaveNoFileOrRowAfterARestart) {
  const fs::path dir = fresh_temp_dir("uploads-aborted");
  const fs::path tokens = dir / "tokens";
  const std::string token = "dave-token-0123456789abcdef";
  std::ofstream(tokens) << token << " dave bytes=" << (6 << 20) << "\n";
  auto options = LoopbackServer::default_options();
  options.data_dir = (dir / "data").string();
  options.tokens_file = tokens.string();
  const std::size_t mib = wire::kMaxChunkBytes;
  {
    LoopbackServer s(options);
    // Five aborted 4 MiB uploads would fill the 6 MiB quota many times over if any were kept.
    for (int i = 0; i < 5; ++i) EXPECT_FALSE(upload(*s.stub, 4, mib, End::kCancel, nullptr, token).ok());
    EXPECT_EQ(upload(*s.stub, 1, 5 * mib, End::kClose, nullptr, token).error_code(),
              grpc::StatusCode::RESOURCE_EXHAUSTED);
    expect_stored_bytes(*s.server, 0);
    EXPECT_EQ(files_in(dir / "data" / "uploads"), 0u);
    std::string id;
    ASSERT_TRUE(upload(*s.stub, 5, mib, End::kClose, &id, token).ok()) << "the quota is still free";
    EXPECT_EQ(files_in(dir / "data" / "uploads"), 1u);
    EXPECT_FALSE(upload(*s.stub, 3, mib, End::kCancel, nullptr, token).ok());
  }
  LoopbackServer s(options);
  EXPECT_EQ(stored_bytes(*s.server), 5.0 * mib);
  EXPECT_EQ(files_in(dir / "data" / "uploads"), 1u);
}

// An upload of the given chunks (raw: every field as given); the call's status.
grpc::Status upload_chunks(v1::Surfacer::Stub& stub, const std::vector<v1::UploadChunk>& chunks) {
  grpc::ClientContext context;
  v1::UploadResponse response;
  auto writer = stub.Upload(&context, &response);
  for (const auto& chunk : chunks) {
    if (!writer->Write(chunk)) break;
  }
  writer->WritesDone();
  return writer->Finish();
}

v1::UploadChunk chunk(std::size_t bytes, std::optional<std::uint32_t> index = std::nullopt) {
  v1::UploadChunk c;
  c.set_data(std::string(bytes, 'x'));
  if (index) c.set_chunk_index(*index);
  return c;
}

TEST(Uploads, ChunksOverOneMiBOrOutOfOrderAreRefusedAsTheyArrive) {
  LoopbackServer s;
  const std::size_t mib = wire::kMaxChunkBytes;
  grpc::Status status = upload_chunks(*s.stub, {chunk(mib), chunk(mib + 1)});
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(status.error_message().find("chunk 1: data is 1048577 bytes; a chunk carries at most 1048576"),
            std::string::npos)
      << status.error_message();
  status = upload_chunks(*s.stub, {chunk(10, 0), chunk(10, 2), chunk(10, 1)});
  EXPECT_EQ(status.error_code(), grpc::StatusCode::DATA_LOSS);
  EXPECT_NE(status.error_message().find("chunk 1: chunk_index is 2"), std::string::npos) << status.error_message();
  status = upload_chunks(*s.stub, {chunk(10, 0), chunk(10)});
  EXPECT_EQ(status.error_code(), grpc::StatusCode::DATA_LOSS);
  EXPECT_NE(status.error_message().find("chunk 1: chunk_index is missing"), std::string::npos)
      << status.error_message();
  status = upload_chunks(*s.stub, {});
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(status.error_message().find("before its first chunk"), std::string::npos) << status.error_message();
  v1::UploadChunk named = chunk(1, 0);
  named.set_name(std::string(wire::kMaxNameBytes + 1, 'n'));
  status = upload_chunks(*s.stub, {named});
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(status.error_message().find("name is 1025 bytes; the limit is 1024"), std::string::npos);
  expect_stored_bytes(*s.server, 0);
  // In order, with or without indices, and a single empty chunk: accepted.
  EXPECT_TRUE(upload_chunks(*s.stub, {chunk(mib, 0), chunk(10, 1), chunk(0, 2)}).ok());
  EXPECT_TRUE(upload_chunks(*s.stub, {chunk(10), chunk(10)}).ok());
  EXPECT_TRUE(upload_chunks(*s.stub, {chunk(0)}).ok());
  expect_stored_bytes(*s.server, mib + 30.0);
}

}  // namespace
}  // namespace surfacer::testing
