// The surfacer-server binary: listens on a real port, serves, and exits 0 on SIGTERM after draining.
#include <gtest/gtest.h>

#include <chrono>
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
