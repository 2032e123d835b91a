// Uploaded inputs (sampled grids, particles, meshes), kept in memory and named by id.
#pragma once

#include <cstdint>
#include <memory>
#include <mutex>
#include <string>
#include <unordered_map>

namespace surfacer::server {

struct UploadBlob {
  std::string name;
  std::string bytes;
  std::uint32_t crc32 = 0;
};

class UploadStore {
 public:
  // Returns the new id.
  std::string add(std::shared_ptr<const UploadBlob> blob);
  // Throws surfacer::Error(kInvalidInput) naming `field` when the id is unknown.
  std::shared_ptr<const UploadBlob> get(const std::string& id, const std::string& field) const;
  std::int64_t total_bytes() const;

 private:
  mutable std::mutex mutex_;
  std::unordered_map<std::string, std::shared_ptr<const UploadBlob>> blobs_;
  std::int64_t total_bytes_ = 0;
};

// "u-" / "j-" + 16 random hex digits.
std::string random_id(const char* prefix);
// zlib CRC-32 of bytes.
std::uint32_t crc32_of(const void* data, std::size_t size, std::uint32_t seed = 0);

}  // namespace surfacer::server
