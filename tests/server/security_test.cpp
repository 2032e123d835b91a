// Security: bearer tokens (each job and upload belongs to its tenant; others see NOT_FOUND), per-tenant quotas,
// plain text refused off loopback, TLS and mutual TLS on a real port.
#include <gtest/gtest.h>
#include <unistd.h>

#include <atomic>
#include <filesystem>
#include <fstream>
#include <thread>
#include <vector>

#include "server/upload_assembler.h"
#include "tests/server/test_client.h"

namespace surfacer::testing {
namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;

const std::string kAlice = "alice-token-0123456789abcdef";
const std::string kBob = "bob-token-0123456789abcdef";
const std::string kCarol = "carol-token-0123456789abcdef";

fs::path tokens_file() {
  const fs::path path = fs::temp_directory_path() / ("surfacer-tokens-" + std::to_string(getpid()));
  std::ofstream(path) << "# token tenant quotas\n"
                      << kAlice << " alice running=1\n"
                      << kBob << " bob\n"
                      << kCarol << " carol bytes=4000\n";
  return path;
}

server::ServerOptions secured() {
  auto o = LoopbackServer::default_options();
  o.tokens_file = tokens_file().string();
  return o;
}

v1::JobSpec small_job(int cells = 24) {
  return isosurface_spec({scene_from_json(R"({"root": {"sphere": {"radius": 1}}})")}, cells);
}

template <class Req, class Resp, class Call>
grpc::Status unary(Call call, const Req& req, Resp* resp, const std::string& token) {
  grpc::ClientContext ctx;
  if (!token.empty()) ctx.AddMetadata("authorization", "Bearer " + token);
  return call(&ctx, req, resp);
}

grpc::Status get_job(v1::Surfacer::Stub& stub, const std::string& id, const std::string& token, v1::Job* job) {
  v1::GetJobRequest req;
  req.set_job_id(id);
  return unary([&](grpc::ClientContext* c, const v1::GetJobRequest& r, v1::Job* j) { return stub.GetJob(c, r, j); },
               req, job, token);
}

grpc::Status cancel_job(v1::Surfacer::Stub& stub, const std::string& id, const std::string& token) {
  v1::CancelJobRequest req;
  req.set_job_id(id);
  v1::Job job;
  return unary(
      [&](grpc::ClientContext* c, const v1::CancelJobRequest& r, v1::Job* j) { return stub.CancelJob(c, r, j); }, req,
      &job, token);
}

std::vector<std::string> list_ids(v1::Surfacer::Stub& stub, const std::string& token) {
  v1::ListJobsRequest req;
  v1::ListJobsResponse resp;
  EXPECT_TRUE(unary([&](grpc::ClientContext* c, const v1::ListJobsRequest& r,
                        v1::ListJobsResponse* o) { return stub.ListJobs(c, r, o); },
                    req, &resp, token)
                  .ok());
  std::vector<std::string> ids;
  for (const auto& j : resp.jobs()) ids.push_back(j.id());
  return ids;
}

grpc::Status upload(v1::Surfacer::Stub& stub, const std::string& bytes, const std::string& token, std::string* id) {
  grpc::ClientContext ctx;
  if (!token.empty()) ctx.AddMetadata("authorization", "Bearer " + token);
  v1::UploadResponse resp;
  auto writer = stub.Upload(&ctx, &resp);
  v1::UploadChunk chunk;
  chunk.set_name("grid.bin");
  chunk.set_total_bytes(bytes.size());
  chunk.set_data(bytes);
  writer->Write(chunk);
  writer->WritesDone();
  const auto status = writer->Finish();
  if (id) *id = resp.upload_id();
  return status;
}

TEST(Security, EveryRpcNeedsAKnownToken) {
  LoopbackServer s(secured());
  std::string id;
  auto status = submit(*s.stub, small_job(), &id);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::UNAUTHENTICATED);
  EXPECT_NE(status.error_message().find("Bearer"), std::string::npos) << status.error_message();
  status = submit(*s.stub, small_job(), &id, "not-a-known-token-at-all");
  EXPECT_EQ(status.error_code(), grpc::StatusCode::UNAUTHENTICATED);
  EXPECT_EQ(upload(*s.stub, "abc", "", nullptr).error_code(), grpc::StatusCode::UNAUTHENTICATED);
  EXPECT_EQ(watch_job(*s.stub, "j-0000000000000000").status.error_code(), grpc::StatusCode::UNAUTHENTICATED);
  v1::ServerInfo info;
  EXPECT_EQ(unary([&](grpc::ClientContext* c, const v1::GetServerInfoRequest& r,
                      v1::ServerInfo* o) { return s.stub->GetServerInfo(c, r, o); },
                  v1::GetServerInfoRequest(), &info, "")
                .error_code(),
            grpc::StatusCode::UNAUTHENTICATED);
  ASSERT_TRUE(submit(*s.stub, small_job(), &id, kBob).ok());
  // The upload limit a tenant is told is what its stored-bytes quota leaves.
  EXPECT_TRUE(unary([&](grpc::ClientContext* c, const v1::GetServerInfoRequest& r,
                        v1::ServerInfo* o) { return s.stub->GetServerInfo(c, r, o); },
                    v1::GetServerInfoRequest(), &info, kCarol)
                  .ok());
  EXPECT_EQ(info.limits().max_upload_bytes(), 4000);
}

TEST(Security, AnotherTenantCanNeitherWatchListNorCancelAJob) {
  LoopbackServer s(secured());
  std::string id;
  ASSERT_TRUE(submit(*s.stub, small_job(64), &id, kBob).ok());
  v1::Job job;
  EXPECT_EQ(get_job(*s.stub, id, kAlice, &job).error_code(), grpc::StatusCode::NOT_FOUND);
  EXPECT_EQ(cancel_job(*s.stub, id, kAlice).error_code(), grpc::StatusCode::NOT_FOUND);
  EXPECT_EQ(watch_job(*s.stub, id, 0, kAlice).status.error_code(), grpc::StatusCode::NOT_FOUND);
  EXPECT_TRUE(list_ids(*s.stub, kAlice).empty());
  // The owner still can, and its job was not touched.
  const auto r = watch_job(*s.stub, id, 0, kBob);
  EXPECT_EQ(r.final_job.state(), v1::JOB_STATE_SUCCEEDED);
  EXPECT_EQ(list_ids(*s.stub, kBob), std::vector<std::string>{id});
  // Uploads belong to their tenant too.
  std::string upload_id;
  ASSERT_TRUE(upload(*s.stub, std::string(64, '\0'), kBob, &upload_id).ok());
  auto spec = small_job();
  auto* grid = spec.mutable_isosurface()->mutable_scenes(0)->mutable_root()->mutable_grid();
  grid->set_upload_id(upload_id);
  const auto status = submit(*s.stub, spec, &id, kAlice);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(status.error_message().find("no upload"), std::string::npos) << status.error_message();
}

// The running= quota holds under concurrent submits: it is checked where the job is added, atomically with it.
TEST(Security, RunningQuotaHoldsUnderConcurrentSubmits) {
  LoopbackServer s(secured());
  // Many scenes: checking the spec at submit takes long enough for the submits to overlap.
  const std::vector<v1::Scene> scenes(
      400, scene_from_json(R"({"root": {"torus": {"major_radius": 1, "minor_radius": 0.2}}})"));
  const v1::JobSpec spec = isosurface_spec(scenes, 64);
  for (int round = 0; round < 5; ++round) {
    constexpr int kClients = 24;
    std::vector<std::string> ids(kClients);
    std::vector<grpc::StatusCode> codes(kClients, grpc::StatusCode::UNKNOWN);
    std::atomic<int> ready{0};
    std::vector<std::thread> clients;
    for (int c = 0; c < kClients; ++c) {
      clients.emplace_back([&, c] {
        ++ready;
        while (ready.load() < kClients) std::this_thread::yield();
        codes[c] = submit(*s.stub, spec, &ids[c], kAlice).error_code();
      });
    }
    for (auto& t : clients) t.join();
    int accepted = 0;
    for (int c = 0; c < kClients; ++c) {
      if (codes[c] == grpc::StatusCode::OK) {
        ++accepted;
        cancel_job(*s.stub, ids[c], kAlice);
        watch_job(*s.stub, ids[c], 0, kAlice);
      } else {
        EXPECT_EQ(codes[c], grpc::StatusCode::RESOURCE_EXHAUSTED) << "round " << round;
      }
    }
    EXPECT_EQ(accepted, 1) << "round " << round << ": alice's running=1 let " << accepted << " jobs in";
  }
}

TEST(Security, QuotasOnRunningJobsAndStoredBytes) {
  LoopbackServer s(secured());
  // alice: one queued-or-running job at a time.
  std::string first, second;
  ASSERT_TRUE(submit(*s.stub, small_job(400), &first, kAlice).ok());
  const auto status = submit(*s.stub, small_job(), &second, kAlice);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
  EXPECT_NE(status.error_message().find("running="), std::string::npos) << status.error_message();
  EXPECT_TRUE(submit(*s.stub, small_job(), &second, kBob).ok()) << "quotas are per tenant";
  cancel_job(*s.stub, first, kAlice);
  watch_job(*s.stub, first, 0, kAlice);
  EXPECT_TRUE(submit(*s.stub, small_job(), &second, kAlice).ok()) << "a finished job frees its slot";
  // carol: 4000 stored bytes. A bigger upload is refused, naming the quota.
  auto up = upload(*s.stub, std::string(5000, 'x'), kCarol, nullptr);
  EXPECT_EQ(up.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
  EXPECT_NE(up.error_message().find("bytes="), std::string::npos) << up.error_message();
  // A job whose frames outgrow the quota fails with RESOURCE_EXHAUSTED naming it.
  std::string id;
  ASSERT_TRUE(submit(*s.stub, small_job(64), &id, kCarol).ok());
  const auto r = watch_job(*s.stub, id, 0, kCarol);
  EXPECT_EQ(r.final_job.state(), v1::JOB_STATE_FAILED);
  EXPECT_EQ(r.final_job.error().code(), static_cast<int>(grpc::StatusCode::RESOURCE_EXHAUSTED));
  EXPECT_NE(r.final_job.error().message().find("quota"), std::string::npos) << r.final_job.error().message();
}

TEST(Security, PlainTextOffLoopbackIsRefusedUnlessAllowed) {
  auto o = LoopbackServer::default_options();
  o.listen = "0.0.0.0:0";
  try {
    server::SurfacerServer::start(o);
    ADD_FAILURE() << "plain text on 0.0.0.0 was accepted";
  } catch (const std::exception& e) {
    EXPECT_NE(std::string(e.what()).find("--allow-insecure"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("--tls-cert"), std::string::npos) << e.what();
  }
  o.allow_insecure = true;
  auto server = server::SurfacerServer::start(o);
  EXPECT_GT(server->port(), 0);
  // A malformed tokens file names the line.
  const fs::path bad = fs::temp_directory_path() / ("surfacer-bad-tokens-" + std::to_string(getpid()));
  std::ofstream(bad) << kAlice << " alice\nshort bob\n";
  auto o2 = LoopbackServer::default_options();
  o2.tokens_file = bad.string();
  try {
    server::SurfacerServer::start(o2);
    ADD_FAILURE() << "a short token was accepted";
  } catch (const std::exception& e) {
    EXPECT_NE(std::string(e.what()).find(":2"), std::string::npos) << e.what();
  }
}

TEST(UploadAssembler, ChecksSizesChecksumsAndOrder) {
  server::UploadAssembler a(10);
  v1::UploadChunk c;
  c.set_total_bytes(8);
  c.set_data("abcd");
  EXPECT_TRUE(a.add(c).ok());
  c.Clear();
  c.set_data("efghijk");  // past the announced 8 bytes
  EXPECT_EQ(a.add(c).error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
  EXPECT_FALSE(a.finish().ok());
  EXPECT_EQ(a.take(), nullptr);

  server::UploadAssembler b(100);
  c.Clear();
  c.set_data("hello");
  c.set_crc32(12345);
  EXPECT_EQ(b.add(c).error_code(), grpc::StatusCode::DATA_LOSS);

  server::UploadAssembler d(100);
  c.Clear();
  c.set_total_bytes(10);
  c.set_data("hello");
  EXPECT_TRUE(d.add(c).ok());
  EXPECT_EQ(d.finish().error_code(), grpc::StatusCode::DATA_LOSS);  // 5 of 10 bytes

  // A first chunk announcing a huge upload allocates nothing like it up front.
  server::UploadAssembler big(std::int64_t{1} << 40);
  c.Clear();
  c.set_total_bytes(std::uint64_t{1} << 40);
  c.set_data("x");
  EXPECT_TRUE(big.add(c).ok());
  EXPECT_EQ(big.bytes(), 1u);

  server::UploadAssembler e(100);
  c.Clear();
  c.set_data("hello");
  EXPECT_TRUE(e.add(c).ok());
  EXPECT_TRUE(e.finish().ok());
  auto blob = e.take();
  ASSERT_NE(blob, nullptr);
  EXPECT_EQ(blob->bytes, "hello");
}

}  // namespace
}  // namespace surfacer::testing
