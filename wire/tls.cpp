#include "wire/tls.h"

#include <openssl/err.h>
#include <openssl/pem.h>
#include <openssl/x509.h>

#include <memory>

#include "core/util/errors.h"

namespace surfacer::wire {
namespace {

struct OpenSslFree {
  void operator()(BIO* p) const { BIO_free(p); }
  void operator()(X509* p) const { X509_free(p); }
  void operator()(EVP_PKEY* p) const { EVP_PKEY_free(p); }
};
template <class T>
using OpenSslPtr = std::unique_ptr<T, OpenSslFree>;

OpenSslPtr<BIO> memory_bio(std::string_view pem) {
  OpenSslPtr<BIO> bio(BIO_new_mem_buf(pem.data(), static_cast<int>(pem.size())));
  if (!bio) throw Internal("OpenSSL could not allocate a memory BIO");
  return bio;
}

// OpenSSL's reason for the failure (the first error queued: the later ones wrap it), and its error queue emptied (it
// is per thread and would leak into gRPC's).
std::string openssl_reason() {
  const unsigned long code = ERR_peek_error();
  std::string reason = code != 0 ? ERR_reason_error_string(code) != nullptr ? ERR_reason_error_string(code) : "unknown"
                                 : "no PEM block of that kind";
  ERR_clear_error();
  return reason;
}

// An encrypted key would make OpenSSL prompt on the terminal for its passphrase: refuse it instead.
int no_passphrase(char*, int, int, void*) { return 0; }

OpenSslPtr<X509> first_certificate(std::string_view pem, const std::string& source) {
  OpenSslPtr<X509> cert(PEM_read_bio_X509(memory_bio(pem).get(), nullptr, no_passphrase, nullptr));
  if (!cert) {
    throw InvalidInput("certificate", source + ": no certificate OpenSSL can read (" + openssl_reason() +
                                          "); give the PEM certificate chain, leaf first");
  }
  return cert;
}

}  // namespace

void check_tls_key_pair(std::string_view cert_pem, std::string_view key_pem, const std::string& cert_source,
                        const std::string& key_source) {
  const OpenSslPtr<X509> cert = first_certificate(cert_pem, cert_source);
  const OpenSslPtr<EVP_PKEY> key(PEM_read_bio_PrivateKey(memory_bio(key_pem).get(), nullptr, no_passphrase, nullptr));
  if (!key) {
    throw InvalidInput("key", key_source + ": no private key OpenSSL can read (" + openssl_reason() +
                                  "); give the PEM private key, without a passphrase");
  }
  if (X509_check_private_key(cert.get(), key.get()) != 1) {
    ERR_clear_error();
    throw InvalidInput("key", key_source + " does not match the certificate in " + cert_source +
                                  ": the key belongs to another certificate; give the private key the certificate "
                                  "was issued for");
  }
}

void check_tls_certificates(std::string_view pem, const std::string& source) {
  const OpenSslPtr<BIO> bio = memory_bio(pem);
  int count = 0;
  while (OpenSslPtr<X509>(PEM_read_bio_X509(bio.get(), nullptr, no_passphrase, nullptr))) ++count;
  // Reading stops at the end with "no start line"; any other reason is a damaged certificate.
  const unsigned long code = ERR_peek_last_error();
  const bool clean_end = ERR_GET_LIB(code) == ERR_LIB_PEM && ERR_GET_REASON(code) == PEM_R_NO_START_LINE;
  if (count == 0 || (code != 0 && !clean_end)) {
    const std::string reason = openssl_reason();
    throw InvalidInput("certificate", source + ": " +
                                          (count == 0 ? "no certificate OpenSSL can read (" + reason + ")"
                                                      : "certificate " + std::to_string(count + 1) +
                                                            " cannot be read (" + reason + ")") +
                                          "; give PEM certificates");
  }
  ERR_clear_error();
}

}  // namespace surfacer::wire
