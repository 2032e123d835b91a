// The CLI against a `surfacer-server` child at the edges of what the protocol allows: `list` follows ListJobs pages,
// a scene nested past the depth limit is refused before connecting with the server's own message, and particle
// files that inflate past what the server accepts are refused early, naming the file (exit 2), and a spec too large
// for one request is refused saying how to split it.
#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>

#include <chrono>
#include <filesystem>
#include <set>
#include <string>

#include "surfacer/v1/surfacer.grpc.pb.h"
#include "tests/support/cli_server_test.h"
#include "tests/support/files.h"
#include "tests/support/process.h"
#include "tests/support/server_process.h"
#include "wire/protocol.h"
#include "wire/request_limits.h"

namespace surfacer::client {
namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;
using namespace surfacer::testing;

class CliLimitsEndToEnd : public CliServerTest<CliLimitsEndToEnd> {
 public:
  static constexpr const char* kName = "cli_limits_e2e";
  static std::vector<std::string> server_flags() {
    return {"--drain-seconds", "1", "--max-particles", "1000", "--max-queued-jobs", "1000"};
  }
};

// `levels` transforms around a sphere, as scene JSON.
std::string nested_scene_json(int levels) {
  std::string node = R"({"sphere": {"radius": 1}})";
  for (int i = 0; i < levels; ++i) node = R"({"transform": {"translate": {"x": 0.01}, "child": )" + node + "}}";
  return R"({"root": )" + node + "}";
}

TEST_F(CliLimitsEndToEnd, ListFollowsEveryPage) {
  auto stub = v1::Surfacer::NewStub(grpc::CreateChannel(server_->address(), grpc::InsecureChannelCredentials()));
  std::set<std::string> ids;
  const int jobs = wire::kDefaultListPageSize * 2 + 30;
  for (int i = 0; i < jobs; ++i) {
    grpc::ClientContext context;
    v1::SubmitJobRequest request;
    request.mutable_spec()->set_name("paged-" + std::to_string(i));
    auto* iso = request.mutable_spec()->mutable_isosurface();
    iso->add_scenes()->mutable_root()->mutable_sphere()->set_radius(1);
    iso->set_cells(4);
    v1::SubmitJobResponse response;
    ASSERT_TRUE(stub->SubmitJob(&context, request, &response).ok());
    ids.insert(response.job_id());
  }
  const ProcessResult r = cli({"list"});
  ASSERT_EQ(r.code, 0) << r;
  for (const std::string& id : ids) EXPECT_NE(r.out.find(id), std::string::npos) << id;
}

TEST_F(CliLimitsEndToEnd, ASceneNestedPastTheLimitIsRefusedWithTheServersMessage) {
  // Deep enough for the JSON parser to take it, and too deep for it: the same message either way, exit 2.
  for (int levels : {wire::kMaxSceneDepth + 1, 200}) {
    const fs::path scene = dir_ / ("deep" + std::to_string(levels) + ".json");
    write_file(scene, nested_scene_json(levels));
    const ProcessResult r = cli({"run", "isosurface", "--scene", scene.string(), "-o", (dir_ / "out").string()});
    EXPECT_EQ(r.code, 2) << r;
    EXPECT_NE(r.err.find(scene.string()), std::string::npos) << r;
    EXPECT_NE(r.err.find(wire::scene_too_deep()), std::string::npos) << r;
  }
  // At the limit it runs.
  const fs::path scene = dir_ / "at_limit.json";
  write_file(scene, nested_scene_json(wire::kMaxSceneDepth - 1));
  const ProcessResult r =
      cli({"run", "isosurface", "--scene", scene.string(), "--cells", "16", "-o", (dir_ / "ok").string()});
  EXPECT_EQ(r.code, 0) << r;
}

TEST_F(CliLimitsEndToEnd, ANameOverTheLimitIsRefusedBeforeConnecting) {
  const fs::path scene = dir_ / "sphere.json";
  write_file(scene, nested_scene_json(0));
  const ProcessResult r =
      cli({"submit", "isosurface", "--scene", scene.string(), "--name", std::string(wire::kMaxNameBytes + 1, 'n')});
  EXPECT_EQ(r.code, 2) << r;
  EXPECT_NE(r.err.find("spec.name is 1025 bytes; the limit is 1024 bytes"), std::string::npos) << r;
  EXPECT_NE(r.err.find("--name"), std::string::npos) << r;
}

TEST_F(CliLimitsEndToEnd, TooManyInlineScenesAreRefusedWithTheFrameLimitNeverGrpcsOwnMessage) {
  // 260000 scenes fit in one request and meet the server's frame limit; more pass gRPC's message limit, where the
  // server could only answer with gRPC's "larger than max": the client says what is large and how to split it.
  for (int scenes : {260000, 300000, 600000}) {
    std::string json = R"({"isosurface": {"cells": 8, "scenes": [)";
    for (int i = 0; i < scenes; ++i) json += std::string(i == 0 ? "" : ",") + R"({"root": {"sphere": {"radius": 1}}})";
    json += "]}}";
    const fs::path spec = dir_ / "many_scenes.json";
    write_file(spec, json);
    const ProcessResult r = cli({"run", "--spec", spec.string(), "-o", (dir_ / "many").string()});
    EXPECT_EQ(r.code, 4) << r;
    EXPECT_EQ(r.err.find("larger than max"), std::string::npos) << r;
    const std::string expected =
        scenes == 260000 ? "spec.isosurface.scenes asks for 260000 frames, over the server's limit of 100000"
                         : std::to_string(scenes) + " scenes, over the " + std::to_string(wire::kMaxMessageBytes) +
                               " a request may carry: split it into several jobs (the server takes at most 100000";
    EXPECT_NE(r.err.find(expected), std::string::npos) << r;
  }
}

// `args` run under a 1.5 GB address-space limit: a CLI that inflated a bomb whole would fail to allocate.
std::vector<std::string> with_memory_limit(std::vector<std::string> args) {
  args.insert(args.begin(), {"/bin/sh", "-c", "ulimit -v 1500000 && exec \"$@\"", "sh"});
  return args;
}

TEST_F(CliLimitsEndToEnd, ParticleFilesPastWhatTheServerTakesAreRefusedEarlyNamingTheFile) {
  // 2 GiB of zeros in 32 gzip members (about 2 MB): the server takes 1000 particles (12 kB of .bin, read with 64 kB
  // for headers).
  const std::string member = gzip(std::string(std::size_t{64} << 20, '\0'));
  std::string bomb;
  for (int i = 0; i < 32; ++i) bomb += member;
  const fs::path bombs = dir_ / "bombs.bin.gz";
  write_file(bombs, bomb);
  const fs::path bin = dir_ / "bomb.bin.gz";  // 64 MiB in 64 kB
  write_file(bin, member);
  // 1500 particles, as text.
  std::string text;
  for (int i = 0; i < 1500; ++i) text += std::to_string(i * 0.001) + " 0 0\n";
  const fs::path many = dir_ / "many.xyz";
  write_file(many, text);
  const fs::path many_gz = dir_ / "many.xyz.gz";
  write_file(many_gz, gzip(text));
  for (const auto& [file, what] :
       std::vector<std::pair<fs::path, std::string>>{{bombs, "cannot inflate to 77536 bytes or less (the limit)"},
                                                     {bin, "its gzip data inflates to more than 77536 bytes"},
                                                     {many, "1500 particles, more than 1000"},
                                                     {many_gz, "1500 particles, more than 1000"}}) {
    const auto start = std::chrono::steady_clock::now();
    const std::vector<std::string> args = {cli_binary().string(),
                                           "--server",
                                           server_->address(),
                                           "run",
                                           "particles",
                                           "--input",
                                           file.string(),
                                           "--r-inner",
                                           "0.01",
                                           "-o",
                                           (dir_ / "out").string()};
    const ProcessResult r = run_process(with_memory_limit(args), dir_ / "bomb.out", dir_ / "bomb.err", 60s);
    EXPECT_EQ(r.code, 2) << r;
    EXPECT_NE(r.err.find(file.string()), std::string::npos) << r;
    EXPECT_NE(r.err.find(what), std::string::npos) << r;
    EXPECT_NE(r.err.find("--max-particles"), std::string::npos) << r;
    EXPECT_LT(std::chrono::steady_clock::now() - start, 10s) << file;
  }
  // Within the limits, gzip text runs.
  const fs::path few = dir_ / "few.xyz.gz";
  write_file(
      few, gzip(text.substr(0, text.find('\n', 0) + 1)
                    .append("0.05 0 0\n0 0.05 0\n0 0 0.05\n0.05 0.05 0\n0.05 0 0.05\n0 0.05 0.05\n0.05 0.05 0.05\n")));
  const ProcessResult r =
      cli({"run", "particles", "--input", few.string(), "--r-inner", "0.04", "-o", (dir_ / "few").string()});
  EXPECT_EQ(r.code, 0) << r;
  // None of the refused files queued a job.
  const ProcessResult list = cli({"list"});
  EXPECT_EQ(list.out.find("bomb"), std::string::npos) << list;
  EXPECT_EQ(list.out.find("many"), std::string::npos) << list;
}

}  // namespace
}  // namespace surfacer::client
