#include "core/util/allocation_budget.h"

#include <gtest/gtest.h>

#include <memory>
#include <new>
#include <vector>

namespace surfacer {
namespace {

TEST(AllocationBudget, RefusesWhatWouldPassTheLimitBeforeAllocatingIt) {
  AllocationBudget scope(1 << 20);
  std::vector<char> small(1000);
  EXPECT_GE(scope.allocated(), 1000u);
  EXPECT_THROW(std::vector<char>(std::size_t{1} << 30), std::bad_alloc);
  EXPECT_TRUE(scope.exhausted());
  EXPECT_LT(scope.allocated(), std::size_t{1} << 20);  // the refused request is not counted
}

TEST(AllocationBudget, CountsTotalsNotPeaksAndNothingOutsideAScope) {
  {
    AllocationBudget scope(10000);
    for (int i = 0; i < 5; ++i) std::make_unique<char[]>(1500).reset();  // freed at once: still 7500 allocated
    EXPECT_GE(scope.allocated(), 7500u);
    EXPECT_THROW(std::make_unique<char[]>(3000), std::bad_alloc);
  }
  EXPECT_NO_THROW(std::vector<char>(std::size_t{16} << 20));
}

TEST(AllocationBudget, InnerScopesAreHeldToWhatTheOuterHasLeft) {
  AllocationBudget outer(1 << 20);
  {
    AllocationBudget inner(std::size_t{1} << 30);
    EXPECT_THROW(std::vector<char>(std::size_t{2} << 20), std::bad_alloc);
    EXPECT_TRUE(inner.exhausted());
    std::vector<char> fits(100000);
  }
  EXPECT_FALSE(outer.exhausted());
  EXPECT_GE(outer.allocated(), 100000u);
  EXPECT_THROW(std::vector<char>(1 << 20), std::bad_alloc);
  EXPECT_TRUE(outer.exhausted());
}

TEST(AllocationBudget, NothrowNewReturnsNull) {
  AllocationBudget scope(4096);
  char* p = new (std::nothrow) char[1 << 20];
  EXPECT_EQ(p, nullptr);
  delete[] p;
}

}  // namespace
}  // namespace surfacer
