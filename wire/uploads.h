// Uploaded inputs as the translation sees them: looked up by id, wherever they are kept (the server's upload store;
// nowhere, on a client that checks a job before sending it).
#pragma once

#include <cstdint>
#include <map>
#include <memory>
#include <string>

#include "core/util/errors.h"

namespace surfacer::wire {

struct UploadBlob {
  std::string name;
  std::string bytes;
  std::uint32_t crc32 = 0;
};

class UploadLookup {
 public:
  virtual ~UploadLookup() = default;
  // The upload `id`. Throws surfacer::InvalidInput naming `field` (the request field that holds the id) when there
  // is no such upload.
  virtual std::shared_ptr<const UploadBlob> get(const std::string& id, const std::string& field) const = 0;
};

// The error for an upload id that is not known: InvalidInput(field) saying how to get one (the id is quoted, cut to
// a few characters: it came from the request).
Error unknown_upload(const std::string& id, const std::string& field);

// Uploads held in a map: empty, for a client that checks a spec which must not refer to uploads; filled, for tests
// and fuzzers.
class MemoryUploads final : public UploadLookup {
 public:
  void put(const std::string& id, std::shared_ptr<const UploadBlob> blob) { blobs_[id] = std::move(blob); }
  std::shared_ptr<const UploadBlob> get(const std::string& id, const std::string& field) const override;

 private:
  std::map<std::string, std::shared_ptr<const UploadBlob>> blobs_;
};

}  // namespace surfacer::wire
