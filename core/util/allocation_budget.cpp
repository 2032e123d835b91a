#include "core/util/allocation_budget.h"

#include <algorithm>
#include <cstddef>
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

// The replaceable global allocation functions ([new.delete]), every form of them: all memory comes from malloc (or
// aligned_alloc) and goes back to free, so no block can be released by a form of another allocator (a sanitizer's
// operator new paired with our delete, say).
namespace {

void* allocate(std::size_t size, std::size_t alignment) {
  if (!surfacer::AllocationBudget::charge(size)) throw std::bad_alloc();
  if (size == 0) size = 1;
  for (;;) {
    // aligned_alloc wants a size that is a multiple of the alignment.
    void* p = alignment <= alignof(std::max_align_t)
                  ? std::malloc(size)
                  : std::aligned_alloc(alignment, (size + alignment - 1) / alignment * alignment);
    if (p != nullptr) return p;
    std::new_handler handler = std::get_new_handler();
    if (handler == nullptr) throw std::bad_alloc();
    handler();
  }
}

void* allocate_nothrow(std::size_t size, std::size_t alignment) noexcept {
  try {
    return allocate(size, alignment);
  } catch (const std::bad_alloc&) {
    return nullptr;
  }
}

constexpr std::size_t kDefault = alignof(std::max_align_t);

}  // namespace

void* operator new(std::size_t size) { return allocate(size, kDefault); }
void* operator new[](std::size_t size) { return allocate(size, kDefault); }
void* operator new(std::size_t size, const std::nothrow_t&) noexcept { return allocate_nothrow(size, kDefault); }
void* operator new[](std::size_t size, const std::nothrow_t&) noexcept { return allocate_nothrow(size, kDefault); }
void* operator new(std::size_t size, std::align_val_t a) { return allocate(size, static_cast<std::size_t>(a)); }
void* operator new[](std::size_t size, std::align_val_t a) { return allocate(size, static_cast<std::size_t>(a)); }
void* operator new(std::size_t size, std::align_val_t a, const std::nothrow_t&) noexcept {
  return allocate_nothrow(size, static_cast<std::size_t>(a));
}
void* operator new[](std::size_t size, std::align_val_t a, const std::nothrow_t&) noexcept {
  return allocate_nothrow(size, static_cast<std::size_t>(a));
}

void operator delete(void* p) noexcept { std::free(p); }
void operator delete[](void* p) noexcept { std::free(p); }
void operator delete(void* p, const std::nothrow_t&) noexcept { std::free(p); }
void operator delete[](void* p, const std::nothrow_t&) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }
void operator delete[](void* p, std::size_t) noexcept { std::free(p); }
void operator delete(void* p, std::align_val_t) noexcept { std::free(p); }
void operator delete[](void* p, std::align_val_t) noexcept { std::free(p); }
void operator delete(void* p, std::align_val_t, const std::nothrow_t&) noexcept { std::free(p); }
void operator delete[](void* p, std::align_val_t, const std::nothrow_t&) noexcept { std::free(p); }
void operator delete(void* p, std::size_t, std::align_val_t) noexcept { std::free(p); }
void operator delete[](void* p, std::size_t, std::align_val_t) noexcept { std::free(p); }
