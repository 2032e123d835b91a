// The surfacer-server binary: listens on a real port, serves, and exits 0 on SIGTERM after draining.
#include <gtest/gtest.h>

#include <chrono>
#include <csignal>
#include <cstdint>
#include <filesystem>
#include <optional>
#include <thread>

#include "tests/server/test_client.h"
#include "tests/support/files.h"
#include "tests/support/process.h"
#include "tests/support/server_process.h"
#include "tests/support/test_certs.h"
#include "tests/support/test_meshes.h"

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

// A second SIGTERM during a drain cancels the job the drain waits for, and the process exits at once (it exits within
// 2 s of it in any case, even when a job does not stop).
TEST(ServerBinary, SecondSigtermEndsTheDrainAndExitsPromptly) {
  const auto dir = fresh_temp_dir("second_signal");
  const auto port_file = dir / "port";
  ChildProcess server({server_binary().string(), "--listen", "127.0.0.1:0", "--port-file", port_file.string(),
                       "--workers", "1", "--drain-seconds", "120"},
                      dir / "out", dir / "err");
  ASSERT_TRUE(server.started());
  std::string port;
  for (int i = 0; i < 1500 && (port.empty() || port.back() != '\n'); ++i) {
    std::this_thread::sleep_for(20ms);
    port = read_file(port_file);
  }
  ASSERT_FALSE(port.empty()) << read_file(dir / "err");
  auto stub = make_stub("127.0.0.1:" + std::to_string(std::stoi(port)));
  // Frames enough for a minute of work on one worker.
  const std::vector<v1::Scene> scenes(2000, scene_from_json(R"({"root": {"sphere": {"radius": 1}}})"));
  std::string id;
  ASSERT_TRUE(submit(*stub, isosurface_spec(scenes, 96), &id).ok());
  std::this_thread::sleep_for(300ms);
  server.signal(SIGTERM);
  std::this_thread::sleep_for(500ms);
  EXPECT_FALSE(server.poll().has_value()) << "the first signal should drain, not exit";
  const auto start = std::chrono::steady_clock::now();
  server.signal(SIGTERM);
  const int code = server.wait(10s);
  const auto elapsed = std::chrono::steady_clock::now() - start;
  EXPECT_TRUE(code == 0 || code == 2) << code << "\n" << read_file(dir / "err");
  EXPECT_LT(elapsed, 3s) << std::chrono::duration<double>(elapsed).count() << " s";
  EXPECT_NE(read_file(dir / "err").find("signal_again"), std::string::npos) << read_file(dir / "err");
  std::filesystem::remove_all(dir);
}

// A --tls-key that is not the --tls-cert's key used to end in "cannot listen on ... (address in use or not valid?)"
// after gRPC's own log lines; the server now says what is wrong, naming both flags, before gRPC sees the pair.
TEST(ServerBinary, TlsKeyOfAnotherCertificateIsNamedAtStartup) {
  const auto dir = fresh_temp_dir("tls_pair");
  const TestCerts certs = make_test_certs(dir / "pki");
  const std::string cert = (certs.dir / "server.pem").string(), key = (certs.dir / "client.key").string();
  ProcessResult r =
      run_process({server_binary().string(), "--listen", "127.0.0.1:0", "--tls-cert", cert, "--tls-key", key},
                  dir / "out", dir / "err", 30s);
  EXPECT_EQ(r.code, 1) << r;
  EXPECT_NE(r.err.find("--tls-key " + key + " does not match the certificate in --tls-cert " + cert), std::string::npos)
      << r;
  EXPECT_EQ(r.err.find("cannot listen"), std::string::npos) << r;
  EXPECT_EQ(r.err.find("ssl_transport_security"), std::string::npos) << r;
  // A client CA bundle OpenSSL cannot read is named too.
  write_file(dir / "bad-ca.pem", "-----BEGIN CERTIFICATE-----\nAAAA\n-----END CERTIFICATE-----\n");
  r = run_process({server_binary().string(), "--listen", "127.0.0.1:0", "--tls-cert", cert, "--tls-key",
                   (certs.dir / "server.key").string(), "--tls-client-ca", (dir / "bad-ca.pem").string()},
                  dir / "out", dir / "err", 30s);
  EXPECT_EQ(r.code, 1) << r;
  EXPECT_NE(r.err.find("--tls-client-ca " + (dir / "bad-ca.pem").string() + ": no certificate OpenSSL can read"),
            std::string::npos)
      << r;
  std::filesystem::remove_all(dir);
}

// A ~140-byte Draco start mesh whose header declares 200 M triangles made the server allocate 2.4 GB at once (4.8 GB
// peak RSS) before refusing it. The decoder now refuses it within its budget: the server stays small.
TEST(ServerBinary, DracoBombStartMeshIsRefusedWithoutTheMemory) {
  const auto dir = fresh_temp_dir("bomb");
  ServerProcess process(dir, 1);
  ASSERT_GT(process.port(), 0) << process.log();
  auto stub = make_stub(process.address());
  v1::JobSpec spec;
  auto* job = spec.mutable_optimize();
  *job->mutable_scene() = scene_from_json(R"({"root": {"sphere": {"radius": 1}}})");
  job->set_mesh_upload_id(upload(*stub, draco_bomb(200'000'000)));
  const grpc::Status status = submit(*stub, spec, nullptr);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(status.error_message().find("spec.optimize.mesh_upload_id"), std::string::npos) << status.error_message();
  EXPECT_NE(status.error_message().find("it declares far more elements than it holds"), std::string::npos)
      << status.error_message();
  const std::optional<std::uint64_t> peak = process.peak_rss_bytes();
  ASSERT_TRUE(peak.has_value());
  EXPECT_LT(*peak, std::uint64_t{256} << 20) << "peak RSS " << (*peak >> 20) << " MiB";
  // Under a tight --max-triangles the budget is the limit's: RESOURCE_EXHAUSTED naming the flag.
  ServerProcess tight(dir, 1, {"--max-triangles", "1000"});
  ASSERT_GT(tight.port(), 0) << tight.log();
  auto tight_stub = make_stub(tight.address());
  job->set_mesh_upload_id(upload(*tight_stub, draco_bomb(200'000'000)));
  const grpc::Status limited = submit(*tight_stub, spec, nullptr);
  EXPECT_EQ(limited.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
  EXPECT_NE(limited.error_message().find("--max-triangles"), std::string::npos) << limited.error_message();
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace surfacer::testing
