#include "server/uploads.h"

#include <random>

#include "core/util/errors.h"
#include "server/store.h"

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

void UploadActivity::touch(const std::string& owner) {
  const auto now = std::chrono::steady_clock::now();
  std::lock_guard lock(mutex_);
  last_[owner] = now;
}

std::chrono::steady_clock::time_point UploadActivity::last(const std::string& owner) const {
  std::lock_guard lock(mutex_);
  auto it = last_.find(owner);
  return it == last_.end() ? std::chrono::steady_clock::time_point::min() : it->second;
}

UploadStore::UploadStore(Store* store) : store_(store) {}

void UploadStore::restore() {
  if (!store_) return;
  std::lock_guard lock(mutex_);
  for (const StoredUpload& u : store_->list_uploads()) {
    Entry e;
    e.info = {u.id, u.owner, u.bytes, std::chrono::system_clock::from_time_t(static_cast<std::time_t>(u.created_unix))};
    total_bytes_ += u.bytes;
    entries_.emplace(u.id, std::move(e));
  }
}

std::string UploadStore::add(std::shared_ptr<const UploadBlob> blob, const std::string& owner,
                             MemoryReservation held) {
  std::string id = random_id("u-");
  if (store_) store_->put_upload(id, owner, *blob);
  Entry e;
  e.info = {id, owner, static_cast<std::int64_t>(blob->bytes.size()), std::chrono::system_clock::now()};
  if (!store_) {
    e.blob = std::move(blob);
    e.held = std::move(held);
  }
  std::lock_guard lock(mutex_);
  total_bytes_ += e.info.bytes;
  entries_.emplace(id, std::move(e));
  return id;
}

std::shared_ptr<const UploadBlob> UploadStore::get(const std::string& id, const std::string& field) const {
  std::shared_ptr<const UploadBlob> blob;
  {
    std::lock_guard lock(mutex_);
    auto it = entries_.find(id);
    if (it != entries_.end()) {
      blob = it->second.blob;
      if (!blob && store_) {
        blob = it->second.loaded.lock();
        if (!blob) {
          blob = store_->load_upload(id);
          it->second.loaded = blob;
        }
      }
    }
  }
  if (!blob) throw wire::unknown_upload(id, field);
  return blob;
}

bool UploadStore::owned_by(const std::string& id, const std::string& owner) const {
  std::lock_guard lock(mutex_);
  auto it = entries_.find(id);
  return it != entries_.end() && it->second.info.owner == owner;
}

std::vector<UploadInfo> UploadStore::list() const {
  std::lock_guard lock(mutex_);
  std::vector<UploadInfo> out;
  out.reserve(entries_.size());
  for (const auto& [id, e] : entries_) out.push_back(e.info);
  return out;
}

std::int64_t UploadStore::remove(const std::string& id) {
  std::int64_t bytes = 0;
  {
    std::lock_guard lock(mutex_);
    auto it = entries_.find(id);
    if (it == entries_.end()) return 0;
    bytes = it->second.info.bytes;
    total_bytes_ -= bytes;
    entries_.erase(it);
  }
  if (store_) store_->delete_upload(id);
  return bytes;
}

std::int64_t UploadStore::total_bytes() const {
  std::lock_guard lock(mutex_);
  return total_bytes_;
}

}  // namespace surfacer::server
