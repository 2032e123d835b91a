#include "client/security.h"

#include <arpa/inet.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cstring>
#include <fstream>
#include <sstream>

#include "client/exit_codes.h"
#include "core/util/errors.h"
#include "core/util/format.h"
#include "wire/tls.h"

namespace surfacer::client {
namespace {

CliError usage(const std::string& message) { return CliError(ExitCode::kUsage, message); }

std::string read_flag_file(const std::string& flag, const std::filesystem::path& path) {
  std::error_code ec;
  if (std::filesystem::is_directory(path, ec)) throw usage(flag + " " + path.string() + ": is a directory, not a file");
  std::ifstream in(path, std::ios::binary);
  if (!in) throw usage(flag + " " + path.string() + ": cannot read the file: " + std::strerror(errno));
  std::ostringstream text;
  text << in.rdbuf();
  if (in.bad()) throw usage(flag + " " + path.string() + ": cannot read the file");
  return text.str();
}

std::string read_pem(const std::string& flag, const std::filesystem::path& path, bool key) {
  std::string text = read_flag_file(flag, path);
  const bool ok = key ? text.find("PRIVATE KEY-----") != std::string::npos
                      : text.find("-----BEGIN CERTIFICATE-----") != std::string::npos;
  if (!ok) {
    throw usage(flag + " " + path.string() + ": not a PEM " + (key ? "private key" : "certificate") + " (no " +
                (key ? "\"-----BEGIN ... PRIVATE KEY-----\"" : "\"-----BEGIN CERTIFICATE-----\"") + " line)");
  }
  return text;
}

// A token goes into an HTTP/2 header: printable ASCII without spaces.
void check_token(const std::string& token, const std::string& source) {
  if (token.empty()) throw usage(source + ": the token is empty");
  for (char c : token) {
    const auto u = static_cast<unsigned char>(c);
    if (u <= 0x20 || u >= 0x7f) {
      throw usage(source +
                  ": the token may only hold printable ASCII characters without spaces (one token, as "
                  "listed in the server's --tokens-file)");
    }
  }
}

class AuthInterceptor final : public grpc::experimental::Interceptor {
 public:
  explicit AuthInterceptor(std::string value) : value_(std::move(value)) {}
  void Intercept(grpc::experimental::InterceptorBatchMethods* methods) override {
    if (methods->QueryInterceptionHookPoint(grpc::experimental::InterceptionHookPoints::PRE_SEND_INITIAL_METADATA)) {
      methods->GetSendInitialMetadata()->insert({"authorization", value_});
    }
    methods->Proceed();
  }

 private:
  std::string value_;
};

class AuthInterceptorFactory final : public grpc::experimental::ClientInterceptorFactoryInterface {
 public:
  explicit AuthInterceptorFactory(std::string value) : value_(std::move(value)) {}
  grpc::experimental::Interceptor* CreateClientInterceptor(grpc::experimental::ClientRpcInfo*) override {
    return new AuthInterceptor(value_);
  }

 private:
  std::string value_;
};

// The host part of a gRPC target ("dns:///h:1", "ipv4:1.2.3.4:5", "[::1]:5", "h:5", "h").
std::string target_host(std::string target) {
  for (const char* prefix : {"ipv4:", "ipv6:"}) {
    if (target.rfind(prefix, 0) == 0) target = target.substr(std::strlen(prefix));
  }
  if (target.rfind("dns:", 0) == 0) {
    target = target.substr(4);
    if (target.rfind("//", 0) == 0) {  // dns://authority/host:port
      const std::size_t slash = target.find('/', 2);
      target = slash == std::string::npos ? "" : target.substr(slash + 1);
    }
  }
  if (!target.empty() && target.front() == '[') {
    const std::size_t close = target.find(']');
    return close == std::string::npos ? target : target.substr(1, close - 1);
  }
  if (std::count(target.begin(), target.end(), ':') > 1) return target;  // a bare IPv6 address
  return target.substr(0, target.find(':'));
}

}  // namespace

SecurityOptions load_security(const SecurityFlags& flags, const char* env_token, bool remote) {
  SecurityOptions s;
  if (flags.token && flags.token_file) throw usage("give either --token or --token-file, not both");
  const bool tls_flags = flags.tls || flags.tls_ca || flags.tls_cert || flags.tls_key || flags.tls_server_name;
  if (!remote) {
    const char* flag = flags.token             ? "--token"
                       : flags.token_file      ? "--token-file"
                       : flags.tls_ca          ? "--tls-ca"
                       : flags.tls_cert        ? "--tls-cert"
                       : flags.tls_key         ? "--tls-key"
                       : flags.tls_server_name ? "--tls-server-name"
                       : flags.tls             ? "--tls"
                       : flags.allow_insecure  ? "--allow-insecure"
                                               : nullptr;
    if (flag != nullptr) {
      throw usage(std::string(flag) +
                  " applies to a remote server; give --server HOST:PORT (or set $SURFACER_SERVER). The in-process "
                  "server (--local) needs neither TLS nor a token");
    }
    return s;  // $SURFACER_TOKEN is for remote servers only
  }

  if (flags.token) {
    s.token = *flags.token;
    s.token_source = "--token";
  } else if (flags.token_file) {
    s.token_source = "--token-file " + flags.token_file->string();
    const std::string text(trim(read_flag_file("--token-file", *flags.token_file)));
    if (text.empty()) throw usage(s.token_source + ": the file is empty; it should hold the token on one line");
    s.token = text;
  } else if (env_token != nullptr && *env_token != '\0') {
    s.token = std::string(trim(env_token));
    s.token_source = "$SURFACER_TOKEN";
  }
  if (s.token) check_token(*s.token, s.token_source);

  if (flags.tls_cert.has_value() != flags.tls_key.has_value()) {
    throw usage(flags.tls_cert ? "--tls-cert needs --tls-key FILE (the client certificate's private key)"
                               : "--tls-key needs --tls-cert FILE (the client certificate it belongs to)");
  }
  s.tls = tls_flags;
  if (flags.tls_server_name && !(flags.tls || flags.tls_ca || flags.tls_cert)) {
    throw usage("--tls-server-name applies to TLS connections: add --tls (system roots) or --tls-ca FILE");
  }
  if (flags.tls_server_name && flags.tls_server_name->empty()) {
    throw usage("--tls-server-name is empty; give the name the server's certificate carries, e.g. localhost");
  }
  // Checked here, not left to gRPC: it would report a bad pair only as an unusable channel.
  try {
    if (flags.tls_ca) {
      s.ca_pem = read_pem("--tls-ca", *flags.tls_ca, false);
      wire::check_tls_certificates(s.ca_pem, "--tls-ca " + flags.tls_ca->string());
    }
    if (flags.tls_cert) {
      s.cert_pem = read_pem("--tls-cert", *flags.tls_cert, false);
      s.key_pem = read_pem("--tls-key", *flags.tls_key, true);
      wire::check_tls_key_pair(s.cert_pem, s.key_pem, "--tls-cert " + flags.tls_cert->string(),
                               "--tls-key " + flags.tls_key->string());
    }
  } catch (const Error& e) {
    throw usage(e.what());
  }
  s.server_name = flags.tls_server_name;
  s.allow_insecure = flags.allow_insecure;
  return s;
}

bool is_loopback_target(const std::string& target) {
  if (target.rfind("unix:", 0) == 0 || target.rfind("unix-abstract:", 0) == 0) return true;
  std::string host = target_host(target);
  std::transform(host.begin(), host.end(), host.begin(), [](unsigned char c) { return std::tolower(c); });
  if (!host.empty() && host.back() == '.') host.pop_back();
  if (host == "localhost" || host == "ip6-localhost" || host == "ip6-loopback") return true;
  in_addr v4{};
  if (inet_pton(AF_INET, host.c_str(), &v4) == 1) return (ntohl(v4.s_addr) >> 24) == 127;
  in6_addr v6{};
  if (inet_pton(AF_INET6, host.c_str(), &v6) == 1) {
    if (IN6_IS_ADDR_LOOPBACK(&v6)) return true;
    return IN6_IS_ADDR_V4MAPPED(&v6) && v6.s6_addr[12] == 127;
  }
  return false;
}

void check_token_transport(const std::string& target, const SecurityOptions& security) {
  if (!security.token || security.tls || security.allow_insecure || is_loopback_target(target)) return;
  throw usage("refusing to send the bearer token (" + security.token_source + ") in plaintext to " + target +
              ", which is not a loopback address: use --tls (or --tls-ca FILE for a private CA), or "
              "--allow-insecure if the network is trusted");
}

std::shared_ptr<grpc::ChannelCredentials> channel_credentials(const SecurityOptions& security) {
  if (!security.tls) return grpc::InsecureChannelCredentials();
  grpc::SslCredentialsOptions ssl;
  ssl.pem_root_certs = security.ca_pem;  // empty: gRPC's default (system) roots
  ssl.pem_private_key = security.key_pem;
  ssl.pem_cert_chain = security.cert_pem;
  return grpc::SslCredentials(ssl);
}

void add_channel_arguments(const SecurityOptions& security, grpc::ChannelArguments& args) {
  if (security.tls && security.server_name) args.SetSslTargetNameOverride(*security.server_name);
}

std::string authorization_value(const std::string& token) { return "Bearer " + token; }

std::vector<std::unique_ptr<grpc::experimental::ClientInterceptorFactoryInterface>> auth_interceptors(
    const SecurityOptions& security) {
  std::vector<std::unique_ptr<grpc::experimental::ClientInterceptorFactoryInterface>> factories;
  if (security.token)
    factories.push_back(std::make_unique<AuthInterceptorFactory>(authorization_value(*security.token)));
  return factories;
}

}  // namespace surfacer::client
