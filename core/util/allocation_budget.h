// A cap on what the calling thread may allocate while a scope is open, for third-party decoders whose allocations
// cannot be bounded from their input beforehand: Draco reads element counts from the stream and allocates for them at
// once, so a 100-byte file can ask for gigabytes. Inside an AllocationBudget, an operator new that would take the
// scope's total past its limit throws std::bad_alloc before any memory is touched; the decoder unwinds and the
// caller turns exhausted() into an error that names the limit.
//
// allocation_budget.cpp replaces every form of the program's global operator new and delete (malloc or aligned_alloc
// and free underneath, as the standard library's; a sanitizer's malloc then sees them all) to do the counting;
// outside a scope an allocation costs one extra thread-local load. Only operator new is counted (not malloc), and
// frees are not credited: the limit bounds the total allocated in the scope, a conservative bound on its peak.
#pragma once

#include <cstddef>

namespace surfacer {

class AllocationBudget {
 public:
  // Opens a scope on this thread that may allocate `bytes` in total. Scopes nest: an inner scope's limit is also
  // held to what its outer scope has left, and what it allocated counts toward the outer one when it closes.
  explicit AllocationBudget(std::size_t bytes);
  ~AllocationBudget();
  AllocationBudget(const AllocationBudget&) = delete;
  AllocationBudget& operator=(const AllocationBudget&) = delete;

  // Bytes allocated in this scope so far (refused requests excluded).
  std::size_t allocated() const { return allocated_; }
  // Whether a request was refused (std::bad_alloc thrown) in this scope.
  bool exhausted() const { return exhausted_; }

  // For operator new (allocation_budget.cpp): charges `bytes` to the innermost open scope of this thread; false
  // when it would exceed the limit (the scope is then marked exhausted). True without an open scope.
  static bool charge(std::size_t bytes) noexcept;

 private:
  std::size_t limit_;
  std::size_t allocated_ = 0;
  bool exhausted_ = false;
  AllocationBudget* outer_;
};

}  // namespace surfacer
