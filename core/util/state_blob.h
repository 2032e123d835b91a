// Checkpoint blobs of the evolving engines (MeshOptimizer::save_state, ActiveSurface::save_state): a 4-byte magic,
// a u32 version, the engine's fields in host byte order, then a u64 FNV-1a of everything before it. Read back by the
// same build on the same machine class; anything else is refused through the engine's own `fail` function.
#pragma once

#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <string>
#include <string_view>
#include <type_traits>
#include <vector>

namespace surfacer::state_blob {

// Reports a bad blob; never returns (throws the engine's InvalidInput).
using Fail = void (*)(const std::string& why);

inline std::uint64_t fnv1a(std::string_view bytes) {
  std::uint64_t h = 1469598103934665603ULL;
  for (const char c : bytes) {
    h ^= static_cast<unsigned char>(c);
    h *= 1099511628211ULL;
  }
  return h;
}

struct Writer {
  Writer(const char (&magic)[4], std::uint32_t version) {
    out.append(magic, sizeof(magic));
    put(version);
  }
  template <class T>
  void put(const T& v) {
    static_assert(std::is_trivially_copyable_v<T>);
    out.append(reinterpret_cast<const char*>(&v), sizeof(T));
  }
  template <class T>
  void put_array(const std::vector<T>& v) {
    put<std::uint64_t>(v.size());
    out.append(reinterpret_cast<const char*>(v.data()), v.size() * sizeof(T));
  }
  // Appends the checksum and hands the blob over.
  std::string finish() {
    put(fnv1a(out));
    return std::move(out);
  }
  std::string out;
};

class Reader {
 public:
  // Checks the magic (else fail(not_this)) and the checksum, and reads the version.
  Reader(std::string_view state, const char (&magic)[4], const char* not_this, Fail fail) : fail_(fail) {
    if (state.size() < sizeof(magic) + sizeof(std::uint32_t) + sizeof(std::uint64_t) ||
        std::memcmp(state.data(), magic, sizeof(magic)) != 0) {
      failed(not_this);
    }
    in_ = state.substr(0, state.size() - sizeof(std::uint64_t));
    std::uint64_t sum;
    std::memcpy(&sum, state.data() + in_.size(), sizeof(sum));
    if (sum != fnv1a(in_)) failed("checksum mismatch");
    at_ = sizeof(magic);
    version_ = get<std::uint32_t>();
  }
  std::uint32_t version() const { return version_; }
  const char* take(std::size_t n) {
    if (in_.size() - at_ < n) failed("truncated at byte " + std::to_string(at_));
    const char* p = in_.data() + at_;
    at_ += n;
    return p;
  }
  template <class T>
  T get() {
    static_assert(std::is_trivially_copyable_v<T>);
    T v;
    std::memcpy(&v, take(sizeof(T)), sizeof(T));
    return v;
  }
  template <class T>
  std::vector<T> get_array() {
    const auto n = get<std::uint64_t>();
    if (n > (in_.size() - at_) / sizeof(T)) failed("an array of " + std::to_string(n) + " items is truncated");
    std::vector<T> v(n);
    std::memcpy(static_cast<void*>(v.data()), take(n * sizeof(T)), n * sizeof(T));
    return v;
  }
  // Bytes not read yet (a well-formed blob has none left at the end).
  std::size_t remaining() const { return in_.size() - at_; }

 private:
  [[noreturn]] void failed(const std::string& why) const {
    fail_(why);
    std::abort();  // not reached: `fail` throws
  }

  Fail fail_;
  std::string_view in_;
  std::size_t at_ = 0;
  std::uint32_t version_ = 0;
};

}  // namespace surfacer::state_blob
