// TLS and bearer tokens on the client side: the flags and their files, the plaintext-token refusal, and the
// `surfacer` binary and Connection against test-local gRPC servers with SslServerCredentials (server-only and
// mutual TLS), the default health service and a tiny Surfacer service that checks the authorization metadata.
#include "client/security.h"

#include <grpcpp/health_check_service_interface.h>
#include <grpcpp/security/server_credentials.h>
#include <gtest/gtest.h>

#include <mutex>
#include <sstream>

#include "client/cli.h"
#include "client/connection.h"
#include "client/health.h"
#include "tests/support/cli_parse.h"
#include "tests/support/files.h"
#include "tests/support/loopback_grpc.h"
#include "tests/support/process.h"
#include "tests/support/test_certs.h"

namespace surfacer::client {
namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;
using namespace surfacer::testing;

constexpr const char* kToken = "tok-3f9a.c0ffee_42";

// ListJobs answers OK only with "authorization: Bearer <kToken>"; every value seen is recorded.
class TokenCheckingService final : public v1::Surfacer::Service {
 public:
  grpc::Status ListJobs(grpc::ServerContext* context, const v1::ListJobsRequest*, v1::ListJobsResponse*) override {
    std::string value;
    int count = 0;
    const auto range = context->client_metadata().equal_range("authorization");
    for (auto it = range.first; it != range.second; ++it) {
      value.assign(it->second.data(), it->second.size());
      ++count;
    }
    {
      std::lock_guard lock(mutex_);
      seen_.push_back(count > 1 ? "<" + std::to_string(count) + " values>" : value);
    }
    if (count != 1 || value != std::string("Bearer ") + kToken) {
      return grpc::Status(grpc::StatusCode::UNAUTHENTICATED, "missing or unknown bearer token");
    }
    return grpc::Status::OK;
  }
  std::vector<std::string> seen() {
    std::lock_guard lock(mutex_);
    return seen_;
  }

 private:
  std::mutex mutex_;
  std::vector<std::string> seen_;
};

// A gRPC server on 127.0.0.1 with the default health service (SERVING) and the token-checking service.
class TestServer {
 public:
  explicit TestServer(std::shared_ptr<grpc::ServerCredentials> credentials) {
    grpc::EnableDefaultHealthCheckService(true);
    server_ = std::make_unique<LoopbackGrpcServer>(std::vector<grpc::Service*>{&service_}, std::move(credentials));
  }
  std::string address() const { return server_->address(); }
  int port() const { return server_->port(); }
  TokenCheckingService& service() { return service_; }

 private:
  TokenCheckingService service_;
  std::unique_ptr<LoopbackGrpcServer> server_;
};

std::shared_ptr<grpc::ServerCredentials> tls_server(const TestCerts& certs, bool require_client_cert) {
  grpc::SslServerCredentialsOptions options(require_client_cert
                                                ? GRPC_SSL_REQUEST_AND_REQUIRE_CLIENT_CERTIFICATE_AND_VERIFY
                                                : GRPC_SSL_DONT_REQUEST_CLIENT_CERTIFICATE);
  options.pem_root_certs = certs.ca_pem;  // the CA client certificates must chain to
  options.pem_key_cert_pairs.push_back({certs.server_key_pem, certs.server_cert_pem});
  return grpc::SslServerCredentials(options);
}

class SecurityTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    root_ = fresh_temp_dir("security");
    certs_ = new TestCerts(make_test_certs(root_ / "pki"));
    other_ = new TestCerts(make_test_certs(root_ / "other-pki"));
  }
  static void TearDownTestSuite() {
    delete certs_;
    delete other_;
    certs_ = other_ = nullptr;
    fs::remove_all(root_);
  }
  void SetUp() override { dir_ = current_test_dir(root_); }

  ProcessResult cli(std::vector<std::string> args, std::chrono::seconds timeout = 30s) {
    args.insert(args.begin(), cli_binary().string());
    const std::string tag = "cli" + std::to_string(counter_++);
    return run_process(args, dir_ / (tag + ".out"), dir_ / (tag + ".err"), timeout);
  }

  static std::string ca() { return (certs_->dir / "ca.pem").string(); }

  static fs::path root_;
  static TestCerts* certs_;
  static TestCerts* other_;
  fs::path dir_;
  int counter_ = 0;
};

fs::path SecurityTest::root_;
TestCerts* SecurityTest::certs_ = nullptr;
TestCerts* SecurityTest::other_ = nullptr;

TEST(TestCerts, MakesACaAServerCertForLocalhostAndAClientCertAndCachesPerDirectory) {
  const fs::path dir = fresh_temp_dir("certs");
  const TestCerts a = make_test_certs(dir);
  for (const char* name : {"ca.pem", "server.pem", "server.key", "client.pem", "client.key"}) {
    EXPECT_TRUE(fs::exists(dir / name)) << name;
  }
  EXPECT_EQ(a.dir, dir);
  EXPECT_NE(a.ca_pem.find("-----BEGIN CERTIFICATE-----"), std::string::npos);
  EXPECT_NE(a.server_key_pem.find("PRIVATE KEY-----"), std::string::npos);
  EXPECT_EQ(read_file(dir / "client.pem"), a.client_cert_pem);
  // The server certificate carries both names a test connects by.
  const std::string text_file = (dir / "server.txt").string();
  ASSERT_EQ(
      std::system(
          ("openssl x509 -in '" + (dir / "server.pem").string() + "' -noout -text > '" + text_file + "' 2>&1").c_str()),
      0);
  const std::string text = read_file(text_file);
  EXPECT_NE(text.find("DNS:localhost"), std::string::npos) << text;
  EXPECT_NE(text.find("IP Address:127.0.0.1"), std::string::npos) << text;
  // Both leaf certificates verify against the CA.
  for (const char* leaf : {"server.pem", "client.pem"}) {
    const std::string command =
        "openssl verify -CAfile '" + (dir / "ca.pem").string() + "' '" + (dir / leaf).string() + "' >/dev/null 2>&1";
    EXPECT_EQ(std::system(command.c_str()), 0) << leaf;
  }
  // Cached per directory; another directory gets another CA.
  EXPECT_EQ(make_test_certs(dir).ca_pem, a.ca_pem);
  const TestCerts b = make_test_certs(dir / "b");
  EXPECT_NE(b.ca_pem, a.ca_pem);
  fs::remove_all(dir);
}

TEST(Security, LoopbackTargets) {
  for (const char* t : {"localhost:50051", "LOCALHOST:1", "127.0.0.1:50051", "127.1.2.3:9", "[::1]:50051", "::1",
                        "dns:///localhost:50051", "ipv4:127.0.0.1:5", "unix:/tmp/s.sock", "localhost"}) {
    EXPECT_TRUE(is_loopback_target(t)) << t;
  }
  for (const char* t : {"10.0.0.1:50051", "example.com:443", "[2001:db8::1]:5", "dns:///surfacer.svc:50051",
                        "128.0.0.1:1", "localhost.example.com:1"}) {
    EXPECT_FALSE(is_loopback_target(t)) << t;
  }
}

TEST(Security, TokenInPlaintextOnlyToLoopbackUnlessAllowed) {
  SecurityOptions s;
  s.token = "abc";
  s.token_source = "--token";
  EXPECT_NO_THROW(check_token_transport("127.0.0.1:5", s));
  try {
    check_token_transport("10.1.2.3:50051", s);
    FAIL() << "a token in plaintext to 10.1.2.3 was allowed";
  } catch (const CliError& e) {
    EXPECT_EQ(e.code(), ExitCode::kUsage);
    EXPECT_NE(std::string(e.what()).find("--tls"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("10.1.2.3:50051"), std::string::npos) << e.what();
  }
  s.allow_insecure = true;
  EXPECT_NO_THROW(check_token_transport("10.1.2.3:50051", s));
  s.allow_insecure = false;
  s.tls = true;
  EXPECT_NO_THROW(check_token_transport("10.1.2.3:50051", s));
  SecurityOptions no_token;
  EXPECT_NO_THROW(check_token_transport("10.1.2.3:50051", no_token));
}

TEST_F(SecurityTest, FlagsReadTheirFilesAndBadFilesExitTwoNamingFlagAndFile) {
  write_file(dir_ / "token", "  file-token-1\n");
  auto p = parse_cli({"--server", "h:1", "--token-file", (dir_ / "token").string(), "--tls-ca", ca(), "--tls-cert",
                      (certs_->dir / "client.pem").string(), "--tls-key", (certs_->dir / "client.key").string(),
                      "--tls-server-name", "localhost", "list"});
  ASSERT_TRUE(std::holds_alternative<Invocation>(p.result)) << p.err;
  const SecurityOptions& s = std::get<Invocation>(p.result).connect.security;
  EXPECT_EQ(s.token, "file-token-1");
  EXPECT_TRUE(s.tls);
  EXPECT_EQ(s.ca_pem, certs_->ca_pem);
  EXPECT_EQ(s.cert_pem, certs_->client_cert_pem);
  EXPECT_EQ(s.key_pem, certs_->client_key_pem);
  EXPECT_EQ(s.server_name, "localhost");

  // $SURFACER_TOKEN, unless --token is given; ignored for the in-process server.
  p = parse_cli({"--server", "h:1", "list"}, nullptr, "env-token");
  EXPECT_EQ(std::get<Invocation>(p.result).connect.security.token, "env-token");
  p = parse_cli({"--server", "h:1", "--token", "flag-token", "list"}, nullptr, "env-token");
  EXPECT_EQ(std::get<Invocation>(p.result).connect.security.token, "flag-token");
  p = parse_cli({"list"}, nullptr, "env-token");
  ASSERT_TRUE(std::holds_alternative<Invocation>(p.result)) << p.err;
  EXPECT_FALSE(std::get<Invocation>(p.result).connect.security.token);
  p = parse_cli({"--server", "h:1", "--tls", "list"});
  EXPECT_TRUE(std::get<Invocation>(p.result).connect.security.tls);
  EXPECT_TRUE(std::get<Invocation>(p.result).connect.security.ca_pem.empty());  // system roots

  write_file(dir_ / "empty", "\n");
  write_file(dir_ / "not_pem", "hello");
  write_file(dir_ / "two_tokens", "a b\n");
  const std::string missing = (dir_ / "missing.pem").string();
  struct Case {
    std::vector<std::string> args;
    std::string flag;
    std::string file;
  };
  const std::vector<Case> cases = {
      {{"--tls-ca", missing}, "--tls-ca", missing},
      {{"--tls-ca", (dir_ / "not_pem").string()}, "--tls-ca", (dir_ / "not_pem").string()},
      {{"--tls-cert", missing, "--tls-key", (certs_->dir / "client.key").string()}, "--tls-cert", missing},
      {{"--tls-cert", (certs_->dir / "client.pem").string(), "--tls-key", (certs_->dir / "client.pem").string()},
       "--tls-key",
       (certs_->dir / "client.pem").string()},
      {{"--tls-cert", (certs_->dir / "client.pem").string()}, "--tls-key", ""},
      {{"--tls-cert", (certs_->dir / "client.pem").string(), "--tls-key", (certs_->dir / "server.key").string()},
       "does not match the certificate in --tls-cert",
       (certs_->dir / "server.key").string()},
      {{"--token-file", missing}, "--token-file", missing},
      {{"--token-file", (dir_ / "empty").string()}, "--token-file", (dir_ / "empty").string()},
      {{"--token-file", (dir_ / "two_tokens").string()}, "--token-file", (dir_ / "two_tokens").string()},
      {{"--tls-server-name", "localhost"}, "--tls", ""},
      {{"--token", "a", "--token-file", (dir_ / "empty").string()}, "--token", ""},
  };
  for (const Case& c : cases) {
    std::vector<std::string> args = {"--server", "h:1"};
    args.insert(args.end(), c.args.begin(), c.args.end());
    args.push_back("list");
    p = parse_cli(args);
    ASSERT_TRUE(std::holds_alternative<ExitCode>(p.result)) << c.args[0];
    EXPECT_EQ(std::get<ExitCode>(p.result), ExitCode::kUsage) << c.args[0];
    EXPECT_NE(p.err.find(c.flag), std::string::npos) << p.err;
    if (!c.file.empty()) {
      EXPECT_NE(p.err.find(c.file), std::string::npos) << p.err;
    }
  }
  // TLS flags without a remote server.
  p = parse_cli({"--tls-ca", ca(), "list"});
  ASSERT_TRUE(std::holds_alternative<ExitCode>(p.result));
  EXPECT_NE(p.err.find("--server"), std::string::npos) << p.err;
}

TEST_F(SecurityTest, HealthOverTlsWithTheRightCaByIpByNameAndWithANameOverride) {
  TestServer server(tls_server(*certs_, false));
  ASSERT_GT(server.port(), 0);
  ProcessResult r = cli({"--server", server.address(), "--tls-ca", ca(), "health"});
  EXPECT_EQ(r.code, 0) << r;
  EXPECT_EQ(r.out, "SERVING\n") << r;
  r = cli({"--server", "localhost:" + std::to_string(server.port()), "--tls-ca", ca(), "health"});
  EXPECT_EQ(r.code, 0) << r;
  r = cli({"--server", server.address(), "--tls-ca", ca(), "--tls-server-name", "localhost", "health"});
  EXPECT_EQ(r.code, 0) << r;
  // A name the certificate does not carry fails the handshake.
  r = cli({"--server", server.address(), "--tls-ca", ca(), "--tls-server-name", "other.example", "--timeout", "1",
           "health"});
  EXPECT_EQ(r.code, 3) << r;

  // The CLI's Connection, as every command uses it.
  ConnectOptions options;
  options.server = server.address();
  options.timeout_seconds = 5;
  options.security.tls = true;
  options.security.ca_pem = certs_->ca_pem;
  auto connection = Connection::open(options);
  EXPECT_EQ(check_health(connection->channel_ptr(), "", connection->unary_deadline()), HealthStatus::kServing);
  EXPECT_NE(connection->describe().find("TLS"), std::string::npos);
}

TEST_F(SecurityTest, WrongCaOrPlaintextAgainstTlsExitsThreeWithAMessage) {
  TestServer server(tls_server(*certs_, false));
  ProcessResult r =
      cli({"--server", server.address(), "--tls-ca", (other_->dir / "ca.pem").string(), "--timeout", "1", "health"});
  EXPECT_EQ(r.code, 3) << r;
  EXPECT_NE(r.err.find("surfacer: error: cannot reach a Surfacer server at " + server.address()), std::string::npos)
      << r;
  EXPECT_NE(r.err.find("--tls-ca"), std::string::npos) << r;
  r = cli({"--server", server.address(), "--timeout", "1", "health"});
  EXPECT_EQ(r.code, 3) << r;
  EXPECT_NE(r.err.find("--tls"), std::string::npos) << "should suggest TLS: " << r;
}

// A --tls-key that is not the --tls-cert's key used to exit 3 with "UNAVAILABLE: empty address list" after gRPC's
// own log lines: it is a usage error (exit 2) naming both flags, found before any connection, and gRPC's log lines
// never reach the user (unless -v).
TEST_F(SecurityTest, KeyOfAnotherCertificateExitsTwoNamingBothFlags) {
  TestServer server(tls_server(*certs_, true));
  const std::string cert = (certs_->dir / "client.pem").string(), key = (certs_->dir / "server.key").string();
  ProcessResult r = cli({"--server", server.address(), "--tls-ca", ca(), "--tls-cert", cert, "--tls-key", key,
                         "--timeout", "1", "health"});
  EXPECT_EQ(r.code, 2) << r;
  EXPECT_NE(r.err.find("surfacer: error: --tls-key " + key + " does not match the certificate in --tls-cert " + cert),
            std::string::npos)
      << r;
  EXPECT_EQ(r.err.find("ssl_transport_security"), std::string::npos) << r;
  // A CA file with a certificate OpenSSL cannot read.
  write_file(dir_ / "bad-ca.pem", "-----BEGIN CERTIFICATE-----\nAAAA\n-----END CERTIFICATE-----\n");
  r = cli({"--server", server.address(), "--tls-ca", (dir_ / "bad-ca.pem").string(), "health"});
  EXPECT_EQ(r.code, 2) << r;
  EXPECT_NE(r.err.find("--tls-ca " + (dir_ / "bad-ca.pem").string() + ": no certificate OpenSSL can read"),
            std::string::npos)
      << r;
}

TEST_F(SecurityTest, GrpcLogLinesReachTheUserOnlyWithVerbose) {
  TestServer server(tls_server(*certs_, false));
  const std::vector<std::string> wrong_ca = {
      "--server", server.address(), "--tls-ca", (other_->dir / "ca.pem").string(), "--timeout", "1", "health"};
  ProcessResult r = cli(wrong_ca);
  EXPECT_EQ(r.code, 3) << r;
  EXPECT_EQ(r.err.find("ssl_transport_security"), std::string::npos) << r;
  std::vector<std::string> verbose = {"-v"};
  verbose.insert(verbose.end(), wrong_ca.begin(), wrong_ca.end());
  r = cli(verbose);
  EXPECT_EQ(r.code, 3) << r;
  EXPECT_NE(r.err.find("surfacer: grpc: Handshake failed"), std::string::npos) << r;
}

TEST_F(SecurityTest, MutualTlsServerRejectsAClientWithoutACertificateAndAcceptsOneWithIt) {
  TestServer server(tls_server(*certs_, true));
  ProcessResult without = cli({"--server", server.address(), "--tls-ca", ca(), "--timeout", "1", "health"});
  EXPECT_EQ(without.code, 3) << without;
  EXPECT_EQ(without.out.find("SERVING"), std::string::npos) << without;
  // A client certificate from another CA is rejected too.
  ProcessResult foreign =
      cli({"--server", server.address(), "--tls-ca", ca(), "--tls-cert", (other_->dir / "client.pem").string(),
           "--tls-key", (other_->dir / "client.key").string(), "--timeout", "1", "health"});
  EXPECT_EQ(foreign.code, 3) << foreign;
  ProcessResult with =
      cli({"--server", server.address(), "--tls-ca", ca(), "--tls-cert", (certs_->dir / "client.pem").string(),
           "--tls-key", (certs_->dir / "client.key").string(), "health"});
  EXPECT_EQ(with.code, 0) << with;
  EXPECT_EQ(with.out, "SERVING\n") << with;
}

TEST_F(SecurityTest, EveryCallCarriesTheBearerTokenOverTls) {
  TestServer server(tls_server(*certs_, false));
  ProcessResult r = cli({"--server", server.address(), "--tls-ca", ca(), "--token", kToken, "list"});
  EXPECT_EQ(r.code, 0) << r;
  write_file(dir_ / "token", std::string(kToken) + "\n");
  r = cli({"--server", server.address(), "--tls-ca", ca(), "--token-file", (dir_ / "token").string(), "list"});
  EXPECT_EQ(r.code, 0) << r;
  ::setenv("SURFACER_TOKEN", kToken, 1);
  r = cli({"--server", server.address(), "--tls-ca", ca(), "list"});
  ::unsetenv("SURFACER_TOKEN");
  EXPECT_EQ(r.code, 0) << r;
  const auto seen = server.service().seen();
  ASSERT_EQ(seen.size(), 3u);
  for (const auto& value : seen) EXPECT_EQ(value, std::string("Bearer ") + kToken);

  // Without a token, or with a wrong one: UNAUTHENTICATED, exit 4, and the CLI says what to pass.
  r = cli({"--server", server.address(), "--tls-ca", ca(), "list"});
  EXPECT_EQ(r.code, 4) << r;
  EXPECT_NE(r.err.find("UNAUTHENTICATED"), std::string::npos) << r;
  EXPECT_NE(r.err.find("--token"), std::string::npos) << r;
  r = cli({"--server", server.address(), "--tls-ca", ca(), "--token", "wrong", "list"});
  EXPECT_EQ(r.code, 4) << r;
  EXPECT_EQ(server.service().seen().back(), "Bearer wrong");
}

TEST_F(SecurityTest, TokenInPlaintextGoesToLoopbackButNotElsewhere) {
  TestServer server(grpc::InsecureServerCredentials());
  ProcessResult r = cli({"--server", server.address(), "--token", kToken, "list"});
  EXPECT_EQ(r.code, 0) << r;
  ASSERT_FALSE(server.service().seen().empty());
  EXPECT_EQ(server.service().seen().back(), std::string("Bearer ") + kToken);

  // 192.0.2.1 (TEST-NET-1) is not loopback: refused before any connection attempt.
  r = cli({"--server", "192.0.2.1:50051", "--token", kToken, "--timeout", "1", "list"});
  EXPECT_EQ(r.code, 2) << r;
  EXPECT_NE(r.err.find("--tls"), std::string::npos) << r;
  EXPECT_NE(r.err.find("plaintext"), std::string::npos) << r;
  // --allow-insecure lets it try (and find nothing there).
  r = cli({"--server", "192.0.2.1:50051", "--token", kToken, "--allow-insecure", "--timeout", "1", "list"});
  EXPECT_EQ(r.code, 3) << r;
}

}  // namespace
}  // namespace surfacer::client
