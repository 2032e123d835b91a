// The server-wide memory budget (--memory-budget): bytes that uploads being received (and uploads kept in memory
// without a --data-dir) and WatchJob streams' send buffers hold. Each holder reserves its bytes before it allocates
// them and gives them back when it frees them; a reservation that does not fit is refused, so memory stays bounded
// however many clients send or watch at once.
#pragma once

#include <atomic>
#include <cstdint>
#include <string>

namespace surfacer::server {

class MemoryBudget;

// Bytes held against a MemoryBudget; released when destroyed. Movable, not copyable. Thread-compatible: one owner
// at a time (the budget itself is thread-safe).
class MemoryReservation {
 public:
  MemoryReservation() = default;
  MemoryReservation(MemoryReservation&& other) noexcept;
  MemoryReservation& operator=(MemoryReservation&& other) noexcept;
  MemoryReservation(const MemoryReservation&) = delete;
  MemoryReservation& operator=(const MemoryReservation&) = delete;
  ~MemoryReservation();

  // Raises the reservation to `bytes` (>= 0; a smaller value than held is a no-op). Throws
  // surfacer::ResourceLimit("memory_budget") naming `what`, the budget and the flag when the budget cannot give
  // the difference; the reservation is unchanged then. Without a budget (default-constructed) always succeeds.
  void grow_to(std::int64_t bytes, const std::string& what);
  // Gives every byte back.
  void release();
  std::int64_t bytes() const { return bytes_; }

 private:
  friend class MemoryBudget;
  MemoryReservation(MemoryBudget* budget, std::int64_t bytes) : budget_(budget), bytes_(bytes) {}
  MemoryBudget* budget_ = nullptr;
  std::int64_t bytes_ = 0;
};

class MemoryBudget {
 public:
  // limit_bytes > 0: the most bytes reserved at once.
  explicit MemoryBudget(std::int64_t limit_bytes);

  // Reserves `bytes` (>= 0) for `what` ("upload u-…", "WatchJob stream"). Throws surfacer::ResourceLimit
  // ("memory_budget", "<what> needs N bytes but the server's memory budget (--memory-budget L bytes) has only F
  // free; retry when … or start the server with a larger --memory-budget") when it does not fit.
  MemoryReservation reserve(std::int64_t bytes, const std::string& what);

  std::int64_t limit() const { return limit_; }
  std::int64_t used() const { return used_.load(); }

 private:
  friend class MemoryReservation;
  // Adds `bytes` if the total stays within the limit; false (nothing changed) otherwise.
  bool try_take(std::int64_t bytes);
  void give_back(std::int64_t bytes);

  const std::int64_t limit_;
  std::atomic<std::int64_t> used_{0};
};

// The machine's physical memory in bytes (sysconf), or 0 when it cannot be read.
std::int64_t physical_memory_bytes();
// The default --memory-budget: half the machine's physical memory (the rest is for the jobs themselves), or
// Limits' built-in value when the memory cannot be read.
std::int64_t default_memory_budget();

// Parses a size: a whole number of bytes, or one followed by K, M, G or T (powers of 1024; an optional trailing
// "B" or "iB", any case), e.g. "6G", "512M", "1048576". Returns false for anything else, zero or negative sizes,
// and sizes past 2^62.
bool parse_byte_size(const std::string& text, std::int64_t& bytes);

}  // namespace surfacer::server
