// Uploaded inputs (sampled grids, particles, meshes), named by id and owned by the tenant that sent them. Without a
// durable store they are kept in memory (drawing from the memory budget until removed); with one they live on disk
// only, and are read back while a job uses them (the bytes are freed when no job holds them any more).
#pragma once

#include <chrono>
#include <cstdint>
#include <memory>
#include <mutex>
#include <string>
#include <unordered_map>
#include <vector>

#include "server/memory_budget.h"
#include "wire/uploads.h"

namespace surfacer::server {

class Store;

using wire::UploadBlob;

struct UploadInfo {
  std::string id;
  std::string owner;
  std::int64_t bytes = 0;
  std::chrono::system_clock::time_point created;
};

class UploadStore final : public wire::UploadLookup {
 public:
  explicit UploadStore(Store* store = nullptr);
  // Registers what the durable store holds (at start-up; the bytes are read when first used).
  void restore();
  // Returns the new id. Throws surfacer::ResourceLimit("data_dir") when the store cannot write it. `held`: the
  // memory-budget bytes of the blob; kept as long as the blob is kept in memory (released at once with a store).
  std::string add(std::shared_ptr<const UploadBlob> blob, const std::string& owner = "", MemoryReservation held = {});
  // Throws surfacer::Error(kInvalidInput) naming `field` when the id is unknown.
  std::shared_ptr<const UploadBlob> get(const std::string& id, const std::string& field) const override;
  // Whether `id` exists and belongs to `owner`.
  bool owned_by(const std::string& id, const std::string& owner) const;
  std::vector<UploadInfo> list() const;
  // Forgets an upload (and deletes it from the store); returns its size (0 if unknown).
  std::int64_t remove(const std::string& id);
  std::int64_t total_bytes() const;

 private:
  struct Entry {
    UploadInfo info;
    std::shared_ptr<const UploadBlob> blob;          // memory only: the bytes
    MemoryReservation held;                          // memory only: their share of the memory budget
    mutable std::weak_ptr<const UploadBlob> loaded;  // with a store: the bytes while a job holds them
  };
  Store* const store_;
  mutable std::mutex mutex_;
  std::unordered_map<std::string, Entry> entries_;
  std::int64_t total_bytes_ = 0;
};

// When each tenant last sent an upload chunk: an open sequence whose client is still uploading its next frame is not
// idle (Job::expire_if_idle). Thread-safe.
class UploadActivity {
 public:
  void touch(const std::string& owner);
  // The time_point's minimum when `owner` never uploaded.
  std::chrono::steady_clock::time_point last(const std::string& owner) const;

 private:
  mutable std::mutex mutex_;
  std::unordered_map<std::string, std::chrono::steady_clock::time_point> last_;
};

// "u-" / "j-" + 16 random hex digits.
std::string random_id(const char* prefix);

}  // namespace surfacer::server
