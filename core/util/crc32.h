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
// The CRC-32 of A followed by B from crc32_of(A), crc32_of(B) and B's size, without reading the bytes.
std::uint32_t crc32_concat(std::uint32_t a, std::uint32_t b, std::size_t b_size);

}  // namespace surfacer
