#include "core/util/allocation_budget.h"

#include <algorithm>
#include <cstdlib>
#include <new>

namespace surfacer {
namespace {

thread_local AllocationBudget* innermost = nullptr;

}  // namespace

AllocationBudget::AllocationBudget(std::size_t bytes) : limit_(bytes), outer_(innermost) {
  if (outer_ != nullptr) limit_ = std::min(limit_, outer_->limit_ - outer_->allocated_);
  innermost = this;
}

AllocationBudget::~AllocationBudget() {
  innermost = outer_;
  if (outer_ != nullptr) outer_->allocated_ += allocated_;  // within the outer limit: ours was held to what it had left
}

bool AllocationBudget::charge(std::size_t bytes) noexcept {
  AllocationBudget* scope = innermost;
  if (scope == nullptr) return true;
  if (bytes > scope->limit_ - scope->allocated_) {
    scope->exhausted_ = true;
    return false;
  }
  scope->allocated_ += bytes;
  return true;
}

}  // namespace surfacer

// The replaceable global allocation functions ([new.delete.single]); the array and nothrow forms of the standard
// library call these. Memory comes from malloc and goes back to free, as with the library's own, so a block may be
// released by either.
void* operator new(std::size_t size) {
  if (!surfacer::AllocationBudget::charge(size)) throw std::bad_alloc();
  for (;;) {
    if (void* p = std::malloc(size == 0 ? 1 : size)) return p;
    std::new_handler handler = std::get_new_handler();
    if (handler == nullptr) throw std::bad_alloc();
    handler();
  }
}

void operator delete(void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }
