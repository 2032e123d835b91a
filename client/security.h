// TLS and bearer tokens on the client side: the flags (--tls, --tls-ca, --tls-cert/--tls-key, --tls-server-name,
// --token, --token-file, $SURFACER_TOKEN, --allow-insecure) turned into SecurityOptions, the channel credentials
// they give, and the interceptor that puts "authorization: Bearer <token>" on every call of a channel.
#pragma once

#include <grpcpp/security/credentials.h>
#include <grpcpp/support/channel_arguments.h>
#include <grpcpp/support/client_interceptor.h>

#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "client/options.h"

namespace surfacer::client {

// The security flags as parsed (paths, not contents yet).
struct SecurityFlags {
  std::optional<std::string> token;
  std::optional<std::filesystem::path> token_file;
  bool tls = false;
  std::optional<std::filesystem::path> tls_ca;
  std::optional<std::filesystem::path> tls_cert;
  std::optional<std::filesystem::path> tls_key;
  std::optional<std::string> tls_server_name;
  bool allow_insecure = false;
};

// Reads the files the flags name and checks them: a missing or unreadable file, a file that is not PEM of the
// expected kind (or that OpenSSL cannot read), a --tls-key that does not match its --tls-cert, an empty token file, a
// token with spaces or control characters, --tls-cert without --tls-key (or the reverse), --tls-server-name without
// TLS. `env_token` is $SURFACER_TOKEN (may be null), used when neither
// --token nor --token-file is given. `remote` is false for the in-process server: TLS and token flags are then
// an error (there is no network), while $SURFACER_TOKEN is ignored. Throws CliError(kUsage) naming the flag and
// the file.
SecurityOptions load_security(const SecurityFlags& flags, const char* env_token, bool remote);

// True when a gRPC target stays on this machine: localhost, 127.0.0.0/8, ::1 (with or without a port, "ipv4:",
// "ipv6:" or "dns:///" prefix), or a unix: socket.
bool is_loopback_target(const std::string& target);

// Refuses to send a bearer token in plaintext to a host that is not loopback unless --allow-insecure: throws
// CliError(kUsage) saying to use --tls (or --tls-ca FILE).
void check_token_transport(const std::string& target, const SecurityOptions& security);

// SSL credentials (roots: --tls-ca or the system's; the client certificate for mutual TLS) or insecure ones.
std::shared_ptr<grpc::ChannelCredentials> channel_credentials(const SecurityOptions& security);
// Channel arguments of `security` (the TLS target name override) added to `args`.
void add_channel_arguments(const SecurityOptions& security, grpc::ChannelArguments& args);

// "Bearer <token>".
std::string authorization_value(const std::string& token);

// Interceptor factories for CreateCustomChannelWithInterceptors: one that adds the authorization metadata to every
// call when a token is set, none otherwise.
std::vector<std::unique_ptr<grpc::experimental::ClientInterceptorFactoryInterface>> auth_interceptors(
    const SecurityOptions& security);

}  // namespace surfacer::client
