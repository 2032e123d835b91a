// Throw-away TLS material for tests: a fresh CA, a server certificate for localhost / 127.0.0.1 and a client
// certificate (for mutual TLS), all made by the `openssl` command-line tool (scripts/setup.sh installs it).
#pragma once

#include <filesystem>
#include <string>

namespace surfacer::testing {

struct TestCerts {
  std::string ca_pem;           // self-signed CA certificate (CN "Surfacer Test CA ...")
  std::string server_cert_pem;  // signed by the CA; SAN DNS:localhost, IP:127.0.0.1; extendedKeyUsage serverAuth
  std::string server_key_pem;
  std::string client_cert_pem;  // signed by the CA; CN "surfacer-test-client"; extendedKeyUsage clientAuth
  std::string client_key_pem;
  std::filesystem::path dir;  // holds ca.pem, server.pem, server.key, client.pem, client.key (and ca.key)
};

// Makes the files in `dir` (created if needed) and returns their contents. Calls with the same directory in one
// process return the first result without running openssl again; another directory gets a new, unrelated CA
// (e.g. to test a client that trusts the wrong CA). Keys are ECDSA P-256; certificates are valid for 30 days.
// Throws std::runtime_error with openssl's output when a step fails (e.g. openssl is not installed).
TestCerts make_test_certs(const std::filesystem::path& dir);

}  // namespace surfacer::testing
