// TLS material as both ends load it (PEM files named by flags), checked with OpenSSL before gRPC sees it: gRPC
// reports a key that does not belong to its certificate only as an unusable listener or channel ("cannot listen",
// "empty address list") and logs the reason itself, so each side checks first and names the flags.
#pragma once

#include <string>
#include <string_view>

namespace surfacer::wire {

// Checks that `key_pem` holds an unencrypted private key and that it belongs to the first certificate of
// `cert_pem` (the leaf of the chain). `cert_source` and `key_source` name where they came from in messages, e.g.
// "--tls-cert server.pem". Throws InvalidInput (field "certificate" or "key") with a message that names both
// sources when they do not match.
void check_tls_key_pair(std::string_view cert_pem, std::string_view key_pem, const std::string& cert_source,
                        const std::string& key_source);

// Checks that `pem` holds one or more certificates and nothing OpenSSL cannot read (a CA bundle). Throws
// InvalidInput("certificate") naming `source`.
void check_tls_certificates(std::string_view pem, const std::string& source);

}  // namespace surfacer::wire
