#include "server/uploads.h"

#include <zlib.h>

#include <random>

#include "core/errors.h"

namespace surfacer::server {

std::string random_id(const char* prefix) {
  static std::mutex mutex;
  static std::mt19937_64 rng{std::random_device{}()};
  std::uint64_t value;
  {
    std::lock_guard lock(mutex);
    value = rng();
  }
  static const char* kHex = "0123456789abcdef";
  std::string id = prefix;
  for (int i = 15; i >= 0; --i) id += kHex[(value >> (4 * i)) & 0xF];
  return id;
}

std::uint32_t crc32_of(const void* data, std::size_t size, std::uint32_t seed) {
  uLong crc = seed;
  const auto* p = static_cast<const Bytef*>(data);
  while (size > 0) {
    const uInt n = size > (1u << 30) ? (1u << 30) : static_cast<uInt>(size);
    crc = ::crc32(crc, p, n);
    p += n;
    size -= n;
  }
  return static_cast<std::uint32_t>(crc);
}

std::string UploadStore::add(std::shared_ptr<const UploadBlob> blob) {
  std::string id = random_id("u-");
  std::lock_guard lock(mutex_);
  total_bytes_ += static_cast<std::int64_t>(blob->bytes.size());
  blobs_.emplace(id, std::move(blob));
  return id;
}

std::shared_ptr<const UploadBlob> UploadStore::get(const std::string& id, const std::string& field) const {
  std::lock_guard lock(mutex_);
  auto it = blobs_.find(id);
  if (it == blobs_.end()) {
    throw InvalidInput(field, field + ": no upload with id '" + id +
                                  "'; upload the data first with Surfacer.Upload and use the id it returns");
  }
  return it->second;
}

std::int64_t UploadStore::total_bytes() const {
  std::lock_guard lock(mutex_);
  return total_bytes_;
}

}  // namespace surfacer::server
