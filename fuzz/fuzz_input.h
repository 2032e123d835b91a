// Reads typed values off the front of a fuzz input (a small stand-in for libFuzzer's FuzzedDataProvider, which is
// a clang-only header: the replay executables of the normal GCC build compile the same targets).
// Past the end every read yields zeros / empty data, so any byte string is a valid input.
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>

namespace surfacer::fuzz {

class FuzzInput {
 public:
  FuzzInput(const std::uint8_t* data, std::size_t size) : data_(data), size_(size) {}

  bool empty() const { return pos_ >= size_; }
  std::size_t remaining() const { return size_ - pos_; }

  std::uint8_t u8() { return pos_ < size_ ? data_[pos_++] : 0; }
  bool flag() { return (u8() & 1) != 0; }
  // Little-endian, as many bytes as the type has.
  template <class T>
  T le() {
    std::uint64_t v = 0;
    for (std::size_t i = 0; i < sizeof(T); ++i) v |= std::uint64_t{u8()} << (8 * i);
    return static_cast<T>(v);
  }
  std::uint16_t u16() { return le<std::uint16_t>(); }
  std::uint32_t u32() { return le<std::uint32_t>(); }
  std::uint64_t u64() { return le<std::uint64_t>(); }
  // Up to `n` bytes (fewer at the end of the input).
  std::string bytes(std::size_t n) {
    n = std::min(n, remaining());
    std::string out(reinterpret_cast<const char*>(data_ + pos_), n);
    pos_ += n;
    return out;
  }
  std::string rest() { return bytes(remaining()); }

 private:
  const std::uint8_t* data_;
  std::size_t size_;
  std::size_t pos_ = 0;
};

inline std::string_view as_view(const std::uint8_t* data, std::size_t size) {
  return {reinterpret_cast<const char*>(data), size};
}

}  // namespace surfacer::fuzz

#include <cstdio>
#include <cstdlib>

namespace surfacer::fuzz {

// A violated property is a bug like a crash: report it and abort so libFuzzer keeps the input.
[[noreturn]] inline void property_failed(const std::string& what) {
  std::fprintf(stderr, "fuzz property violated: %s\n", what.c_str());
  std::abort();
}

inline void require(bool ok, const std::string& what) {
  if (!ok) property_failed(what);
}

}  // namespace surfacer::fuzz
