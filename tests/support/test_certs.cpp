#include "tests/support/test_certs.h"

#include <unistd.h>

#include <cstdlib>
#include <map>
#include <mutex>
#include <random>
#include <stdexcept>
#include <vector>

#include "tests/support/files.h"

namespace surfacer::testing {
namespace {

namespace fs = std::filesystem;

std::string quote(const std::string& arg) {
  std::string out = "'";
  for (char c : arg) {
    if (c == '\'') {
      out += "'\\''";
    } else {
      out += c;
    }
  }
  return out + "'";
}

// Runs openssl with `args` in `dir`; throws with its output when it fails.
void openssl(const fs::path& dir, const std::vector<std::string>& args) {
  std::string command = "cd " + quote(dir.string()) + " && openssl";
  for (const auto& a : args) (command += ' ') += quote(a);
  const fs::path log = dir / "openssl.log";
  command += " >" + quote(log.string()) + " 2>&1";
  const int rc = std::system(command.c_str());
  if (rc != 0) {
    throw std::runtime_error("make_test_certs: `" + command + "` failed (status " + std::to_string(rc) +
                             "; is openssl installed? scripts/setup.sh installs it):\n" + read_file(log));
  }
}

std::string random_serial() {
  std::random_device device;
  std::mt19937_64 rng((static_cast<std::uint64_t>(device()) << 32) ^ device());
  char buf[32];
  std::snprintf(buf, sizeof buf, "0x%016llx", static_cast<unsigned long long>(rng() >> 1));
  return buf;
}

// A key and certificate signed by the CA in `dir`, with the extensions in `extensions` (openssl x509 -extfile).
void make_signed(const fs::path& dir, const std::string& name, const std::string& subject,
                 const std::string& extensions) {
  write_file(dir / (name + ".ext"), extensions);
  openssl(dir, {"req", "-new", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes", "-keyout",
                name + ".key", "-out", name + ".csr", "-subj", subject});
  openssl(dir, {"x509", "-req", "-in", name + ".csr", "-CA", "ca.pem", "-CAkey", "ca.key", "-set_serial",
                random_serial(), "-days", "30", "-sha256", "-extfile", name + ".ext", "-out", name + ".pem"});
}

TestCerts generate(const fs::path& dir) {
  fs::create_directories(dir);
  const std::string tag = std::to_string(::getpid()) + "-" + random_serial();
  openssl(dir, {"req",
                "-x509",
                "-new",
                "-newkey",
                "ec",
                "-pkeyopt",
                "ec_paramgen_curve:prime256v1",
                "-nodes",
                "-keyout",
                "ca.key",
                "-out",
                "ca.pem",
                "-days",
                "30",
                "-sha256",
                "-subj",
                "/CN=Surfacer Test CA " + tag,
                "-addext",
                "basicConstraints=critical,CA:TRUE",
                "-addext",
                "keyUsage=critical,keyCertSign,cRLSign"});
  make_signed(dir, "server", "/CN=localhost",
              "basicConstraints=CA:FALSE\n"
              "keyUsage=critical,digitalSignature,keyEncipherment\n"
              "extendedKeyUsage=serverAuth\n"
              "subjectAltName=DNS:localhost,IP:127.0.0.1\n");
  make_signed(dir, "client", "/CN=surfacer-test-client",
              "basicConstraints=CA:FALSE\n"
              "keyUsage=critical,digitalSignature,keyEncipherment\n"
              "extendedKeyUsage=clientAuth\n");
  TestCerts certs;
  certs.dir = dir;
  certs.ca_pem = read_file(dir / "ca.pem");
  certs.server_cert_pem = read_file(dir / "server.pem");
  certs.server_key_pem = read_file(dir / "server.key");
  certs.client_cert_pem = read_file(dir / "client.pem");
  certs.client_key_pem = read_file(dir / "client.key");
  for (const char* name : {"server.csr", "client.csr", "server.ext", "client.ext", "openssl.log"}) {
    std::error_code ec;
    fs::remove(dir / name, ec);
  }
  return certs;
}

}  // namespace

TestCerts make_test_certs(const std::filesystem::path& dir) {
  static std::mutex mutex;
  static std::map<std::string, TestCerts> made;
  std::lock_guard lock(mutex);
  std::error_code ec;
  fs::create_directories(dir, ec);
  const std::string key = fs::weakly_canonical(dir, ec).string();
  const auto it = made.find(key);
  if (it != made.end() && fs::exists(dir / "ca.pem")) return it->second;
  TestCerts certs = generate(dir);
  made[key] = certs;
  return certs;
}

}  // namespace surfacer::testing
