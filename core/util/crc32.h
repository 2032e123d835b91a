// CRC-32 (zlib's polynomial) of bytes: every upload chunk, frame chunk and whole frame carries one.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string_view>

namespace surfacer {

// The CRC-32 of `size` bytes at `data`; with `previous` = crc32_of(A), the CRC-32 of A followed by these bytes.
std::uint32_t crc32_of(const void* data, std::size_t size, std::uint32_t previous = 0);
inline std::uint32_t crc32_of(std::string_view bytes, std::uint32_t previous = 0) {
  return crc32_of(bytes.data(), bytes.size(), previous);
}

}  // namespace surfacer
