// Bearer-token authentication and per-tenant quotas. Tokens come from a file (--tokens-file), one per line:
//   TOKEN TENANT [running=N] [bytes=N]
// `#` starts a comment. Several tokens may name the same tenant (they then share its jobs and quotas; the
// first line's quotas win). Every RPC must carry the metadata `authorization: Bearer TOKEN`; jobs and uploads
// belong to the tenant whose token created them, and other tenants see NOT_FOUND for them.
#pragma once

#include <cstdint>
#include <filesystem>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <string_view>
#include <vector>

namespace surfacer::server {

struct Tenant {
  std::string name;                   // "" when authentication is off (one shared tenant)
  int max_running_jobs = 0;           // queued + running jobs; 0 = unlimited
  std::int64_t max_stored_bytes = 0;  // uploads + stored frames; 0 = unlimited
};

class TokenAuth {
 public:
  // Throws std::runtime_error naming the file and line for a malformed file.
  static std::unique_ptr<TokenAuth> load(const std::filesystem::path& file);
  static std::unique_ptr<TokenAuth> parse(const std::string& text, const std::string& origin);

  // The tenant for an `authorization` header value ("Bearer TOKEN"); nullptr when missing or unknown.
  // Compares in time independent of where the tokens differ.
  const Tenant* authenticate(std::string_view authorization) const;
  // The tenant named `name` (for jobs restored from the store); nullptr if no token names it any more.
  const Tenant* tenant(const std::string& name) const;
  std::size_t size() const { return entries_.size(); }

 private:
  struct Entry {
    std::string token;
    std::shared_ptr<const Tenant> tenant;
  };
  std::vector<Entry> entries_;
};

// Bytes each tenant has stored (uploads + frames), shared by the upload path, the job sink and retention.
class Usage {
 public:
  // Adds `bytes` unless that takes the tenant past `limit` (0 = unlimited); returns whether it did.
  bool try_add(const std::string& tenant, std::int64_t bytes, std::int64_t limit);
  void add(const std::string& tenant, std::int64_t bytes);
  void release(const std::string& tenant, std::int64_t bytes);
  std::int64_t bytes(const std::string& tenant) const;
  std::map<std::string, std::int64_t> all() const;

 private:
  mutable std::mutex mutex_;
  std::map<std::string, std::int64_t> bytes_;
};

}  // namespace surfacer::server
