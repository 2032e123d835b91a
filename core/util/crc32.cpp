#include "core/util/crc32.h"

#include <zlib.h>

namespace surfacer {

std::uint32_t crc32_of(const void* data, std::size_t size, std::uint32_t previous) {
  uLong crc = previous;
  const auto* p = static_cast<const Bytef*>(data);
  while (size > 0) {  // zlib takes at most 2^32 - 1 bytes per call
    const uInt n = size > (std::size_t{1} << 30) ? (1u << 30) : static_cast<uInt>(size);
    crc = ::crc32(crc, p, n);
    p += n;
    size -= n;
  }
  return static_cast<std::uint32_t>(crc);
}

std::uint32_t crc32_concat(std::uint32_t a, std::uint32_t b, std::size_t b_size) {
  return static_cast<std::uint32_t>(::crc32_combine64(a, b, static_cast<z_off64_t>(b_size)));
}

}  // namespace surfacer
