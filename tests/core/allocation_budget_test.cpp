#include "core/util/allocation_budget.h"

#include <gtest/gtest.h>

#include <cstdint>
#include <memory>
#include <new>

namespace surfacer {
namespace {

// Where allocations escape to, so the compiler cannot elide them (an unused new-expression, or a new/delete pair,
// may be removed).
void* volatile escaped = nullptr;
template <class T>
T* escape(T* p) {
  escaped = p;
  return p;
}

std::unique_ptr<char[]> bytes(std::size_t n) { return std::unique_ptr<char[]>(escape(new char[n])); }

struct alignas(256) Aligned {
  char bytes[1 << 20];
};

TEST(AllocationBudget, RefusesWhatWouldPassTheLimitBeforeAllocatingIt) {
  AllocationBudget scope(1 << 20);
  const auto small = bytes(1000);
  EXPECT_GE(scope.allocated(), 1000u);
  EXPECT_THROW(bytes(std::size_t{1} << 30), std::bad_alloc);
  EXPECT_TRUE(scope.exhausted());
  EXPECT_LT(scope.allocated(), std::size_t{1} << 20);  // the refused request is not counted
}

TEST(AllocationBudget, CountsTotalsNotPeaksAndNothingOutsideAScope) {
  {
    AllocationBudget scope(10000);
    for (int i = 0; i < 5; ++i) bytes(1500).reset();  // freed at once: still 7500 allocated
    EXPECT_GE(scope.allocated(), 7500u);
    EXPECT_THROW(bytes(3000), std::bad_alloc);
  }
  EXPECT_NO_THROW(bytes(std::size_t{16} << 20));
}

TEST(AllocationBudget, InnerScopesAreHeldToWhatTheOuterHasLeft) {
  AllocationBudget outer(1 << 20);
  {
    AllocationBudget inner(std::size_t{1} << 30);
    EXPECT_THROW(bytes(std::size_t{2} << 20), std::bad_alloc);
    EXPECT_TRUE(inner.exhausted());
    const auto fits = bytes(100000);
  }
  EXPECT_FALSE(outer.exhausted());
  EXPECT_GE(outer.allocated(), 100000u);
  EXPECT_THROW(bytes(1 << 20), std::bad_alloc);
  EXPECT_TRUE(outer.exhausted());
}

// Every form of operator new goes through the budget.
TEST(AllocationBudget, EveryFormOfNewIsCounted) {
  bool nothrow_refused = false, aligned_nothrow_refused = false, aligned_threw = false, array_threw = false;
  std::unique_ptr<char[]> small;
  {
    AllocationBudget scope(std::size_t{256} << 10);  // room for the test framework's own allocations
    std::unique_ptr<char[]> big(escape(new (std::nothrow) char[1 << 20]));
    nothrow_refused = big == nullptr;
    std::unique_ptr<Aligned> aligned(escape(new (std::nothrow) Aligned));
    aligned_nothrow_refused = aligned == nullptr;
    try {
      aligned.reset(escape(new Aligned));
    } catch (const std::bad_alloc&) {
      aligned_threw = true;
    }
    try {
      std::unique_ptr<Aligned[]> two(escape(new Aligned[2]));
    } catch (const std::bad_alloc&) {
      array_threw = true;
    }
    small.reset(escape(new (std::nothrow) char[100]));
  }
  EXPECT_TRUE(nothrow_refused);
  EXPECT_TRUE(aligned_nothrow_refused);
  EXPECT_TRUE(aligned_threw);
  EXPECT_TRUE(array_threw);
  EXPECT_NE(small, nullptr);
}

TEST(AllocationBudget, AlignedNewIsAligned) {
  const std::unique_ptr<Aligned> a(escape(new Aligned));
  EXPECT_EQ(reinterpret_cast<std::uintptr_t>(a.get()) % alignof(Aligned), 0u);
}

}  // namespace
}  // namespace surfacer
