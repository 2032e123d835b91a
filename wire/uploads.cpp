#include "wire/uploads.h"

#include "core/util/format.h"

namespace surfacer::wire {

Error unknown_upload(const std::string& id, const std::string& field) {
  return InvalidInput(field, field + ": no upload with id " + quote(id, 40) +
                                 "; upload the data first with Surfacer.Upload and use the id it returns");
}

std::shared_ptr<const UploadBlob> MemoryUploads::get(const std::string& id, const std::string& field) const {
  const auto it = blobs_.find(id);
  if (it == blobs_.end()) throw unknown_upload(id, field);
  return it->second;
}

}  // namespace surfacer::wire
