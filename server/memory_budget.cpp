#include "server/memory_budget.h"

#include <unistd.h>

#include <cctype>
#include <algorithm>
#include <charconv>
#include <utility>

#include "core/util/errors.h"
#include "server/options.h"

namespace surfacer::server {

MemoryReservation::MemoryReservation(MemoryReservation&& other) noexcept
    : budget_(std::exchange(other.budget_, nullptr)), bytes_(std::exchange(other.bytes_, 0)) {}

MemoryReservation& MemoryReservation::operator=(MemoryReservation&& other) noexcept {
  if (this != &other) {
    release();
    budget_ = std::exchange(other.budget_, nullptr);
    bytes_ = std::exchange(other.bytes_, 0);
  }
  return *this;
}

MemoryReservation::~MemoryReservation() { release(); }

void MemoryReservation::grow_to(std::int64_t bytes, const std::string& what) {
  if (bytes <= bytes_ || !budget_) {
    if (!budget_) bytes_ = std::max(bytes_, bytes);
    return;
  }
  MemoryReservation more = budget_->reserve(bytes - bytes_, what);
  bytes_ += std::exchange(more.bytes_, 0);
}

void MemoryReservation::release() {
  if (budget_ && bytes_ > 0) budget_->give_back(bytes_);
  bytes_ = 0;
}

MemoryBudget::MemoryBudget(std::int64_t limit_bytes) : limit_(limit_bytes) {}

bool MemoryBudget::try_take(std::int64_t bytes) {
  std::int64_t used = used_.load();
  do {
    if (bytes > limit_ - used) return false;
  } while (!used_.compare_exchange_weak(used, used + bytes));
  return true;
}

void MemoryBudget::give_back(std::int64_t bytes) { used_.fetch_sub(bytes); }

MemoryReservation MemoryBudget::reserve(std::int64_t bytes, const std::string& what) {
  if (bytes < 0) bytes = 0;
  if (!try_take(bytes)) {
    const std::int64_t used = used_.load();
    throw ResourceLimit("memory_budget",
                        what + " needs " + std::to_string(bytes) + " more bytes of memory but the server's memory "
                        "budget (--memory-budget " + std::to_string(limit_) + " bytes) has " +
                        std::to_string(std::max<std::int64_t>(0, limit_ - used)) +
                        " free (held by uploads being received and WatchJob streams); retry when those finish, or "
                        "start the server with a larger --memory-budget");
  }
  return MemoryReservation(this, bytes);
}

std::int64_t physical_memory_bytes() {
  const long pages = ::sysconf(_SC_PHYS_PAGES);
  const long page_size = ::sysconf(_SC_PAGE_SIZE);
  if (pages <= 0 || page_size <= 0) return 0;
  return static_cast<std::int64_t>(pages) * static_cast<std::int64_t>(page_size);
}

std::int64_t default_memory_budget() {
  const std::int64_t ram = physical_memory_bytes();
  return ram > 0 ? ram / 2 : Limits{}.memory_budget_bytes;
}

bool parse_byte_size(const std::string& text, std::int64_t& bytes) {
  std::int64_t value = 0;
  const char* begin = text.data();
  const char* end = text.data() + text.size();
  const auto [rest, ec] = std::from_chars(begin, end, value);
  if (ec != std::errc() || rest == begin || value <= 0) return false;
  std::string unit(rest, end);
  for (char& c : unit) c = static_cast<char>(std::toupper(static_cast<unsigned char>(c)));
  if (unit.ends_with("IB")) {
    unit.resize(unit.size() - 2);
    if (unit.empty()) return false;  // "iB" alone is not a unit
  } else if (unit.ends_with("B")) {
    unit.pop_back();
  }
  int shift = 0;
  if (unit == "K") {
    shift = 10;
  } else if (unit == "M") {
    shift = 20;
  } else if (unit == "G") {
    shift = 30;
  } else if (unit == "T") {
    shift = 40;
  } else if (!unit.empty()) {
    return false;
  }
  if (value > (std::int64_t{1} << (62 - shift))) return false;
  bytes = value << shift;
  return true;
}

}  // namespace surfacer::server
