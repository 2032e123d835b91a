// parallel_for and for_chunks on the process-wide pool (core/util/parallel.h, core/util/thread_pool.h).
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <latch>
#include <memory>
#include <mutex>
#include <set>
#include <stdexcept>
#include <thread>
#include <vector>

#include "core/util/parallel.h"
#include "core/util/thread_pool.h"

namespace surfacer {
namespace {

TEST(ParallelFor, EveryItemOnceWhateverTheThreads) {
  for (int threads : {1, 2, 3, 8}) {
    for (int items : {0, 1, 2, 7, 1000}) {
      std::vector<int> hits(items, 0);
      parallel_for(items, threads, [&](int i) { ++hits[i]; });
      for (int i = 0; i < items; ++i) EXPECT_EQ(hits[i], 1) << "item " << i << " threads " << threads;
    }
  }
}

TEST(ParallelFor, ManySmallCallsReuseThePool) {
  // Every thread that runs an item counts itself once (a thread_local flag is fresh in every new thread): with a
  // thread started per call this would count thousands; on the pool, at most its threads and the caller.
  static std::atomic<int> threads_seen{0};
  static thread_local bool seen = false;
  std::vector<double> out(8, 0.0);
  for (int r = 0; r < 2000; ++r) {
    parallel_for(8, 4, [&](int i) {
      if (!seen) {
        seen = true;
        ++threads_seen;
      }
      out[i] += i;
    });
  }
  for (int i = 0; i < 8; ++i) EXPECT_EQ(out[i], 2000.0 * i);
  EXPECT_LE(threads_seen.load(), pool_threads() + 1);
}

TEST(ParallelFor, ThreadsCapTheConcurrency) {
  for (int threads : {1, 2, 3}) {
    std::atomic<int> running{0};
    std::atomic<int> peak{0};
    parallel_for(64, threads, [&](int) {
      const int now = ++running;
      for (int seen = peak.load(); now > seen && !peak.compare_exchange_weak(seen, now);) {
      }
      std::this_thread::sleep_for(std::chrono::microseconds(200));
      --running;
    });
    EXPECT_LE(peak.load(), threads);
    EXPECT_GE(peak.load(), 1);
  }
}

TEST(ParallelFor, CallerTakesPartAndRunsAloneWhenThePoolIsBusy) {
  // Items that each start a nested loop on every thread: the inner loops find no free pool thread and run on their
  // callers; nothing waits for a thread that is busy, so this returns.
  const int outer = 16;
  const int inner = 64;
  std::vector<int> sums(outer, 0);
  parallel_for(outer, 8, [&](int f) {
    std::vector<int> cells(inner, 0);
    parallel_for(inner, 8, [&](int i) {
      parallel_for(4, 8, [&](int k) {
        if (k == 0) cells[i] = i;
      });
    });
    for (int c : cells) sums[f] += c;
  });
  for (int f = 0; f < outer; ++f) EXPECT_EQ(sums[f], inner * (inner - 1) / 2);
}

TEST(ParallelFor, FirstExceptionStopsTheHandOutAndIsRethrownAfterStartedItems) {
  std::atomic<int> started{0};
  std::atomic<int> finished{0};
  try {
    parallel_for(10000, 4, [&](int i) {
      ++started;
      if (i == 3) throw std::runtime_error("item 3");
      std::this_thread::sleep_for(std::chrono::microseconds(50));
      ++finished;
    });
    FAIL() << "no exception";
  } catch (const std::runtime_error& e) {
    EXPECT_STREQ(e.what(), "item 3");
  }
  // Every started item but the one that threw has finished by the time the exception reaches the caller.
  EXPECT_EQ(finished.load(), started.load() - 1);
  EXPECT_LT(started.load(), 10000);
  // The pool still serves loops afterwards.
  std::vector<int> hits(100, 0);
  parallel_for(100, 4, [&](int i) { hits[i] = 1; });
  for (int h : hits) EXPECT_EQ(h, 1);
}

TEST(ParallelFor, NestedExceptionsReachTheirCallers) {
  int caught = 0;
  parallel_for(8, 4, [&](int f) {
    try {
      parallel_for(16, 4, [&](int i) {
        if (i == 5 && f % 2 == 0) throw std::runtime_error("inner");
      });
    } catch (const std::runtime_error&) {
      static std::mutex mutex;
      std::lock_guard lock(mutex);
      ++caught;
    }
  });
  EXPECT_EQ(caught, 4);
}

TEST(ParallelFor, ConcurrentCallersFromOwnThreads) {
  // Threads outside the pool (as the server's workers) each running loops at once.
  std::vector<std::thread> callers;
  std::vector<long> totals(4, 0);
  for (int t = 0; t < 4; ++t) {
    callers.emplace_back([&, t] {
      for (int r = 0; r < 500; ++r) {
        std::vector<long> part(32, 0);
        parallel_for(32, 3, [&](int i) { part[i] = i; });
        for (long p : part) totals[t] += p;
      }
    });
  }
  for (auto& c : callers) c.join();
  for (long total : totals) EXPECT_EQ(total, 500L * 31 * 32 / 2);
}

TEST(PoolPost, TasksStartInPostingOrder) {
  // Every pool thread is held by a blocker while the tasks are posted, then all are released at once: a FIFO queue
  // runs them close to posting order (a thread preempted between taking a task and recording it swaps a few), a LIFO
  // one in reverse (1225 inversions for 50 tasks).
  const int threads = reserve_pool_threads(2);
  auto held = std::make_shared<std::latch>(threads);
  auto release = std::make_shared<std::latch>(1);
  for (int t = 0; t < threads; ++t) {
    post([&, held, release] {
      held->count_down();
      release->wait();
    });
  }
  held->wait();
  const int tasks = 50;
  std::mutex mutex;
  std::vector<int> order;
  auto finished = std::make_shared<std::latch>(tasks);
  for (int t = 0; t < tasks; ++t) {
    post([&, t, finished] {
      {
        std::lock_guard lock(mutex);
        order.push_back(t);
      }
      finished->count_down();
    });
  }
  release->count_down();
  finished->wait();
  int inversions = 0;
  for (int i = 0; i < tasks; ++i) {
    for (int j = i + 1; j < tasks; ++j) inversions += order[i] > order[j];
  }
  EXPECT_LT(inversions, 300);
}

TEST(PoolPost, NestedLoopsInTasksOnEveryPoolThreadFinish) {
  // Every pool thread runs a task (they meet at a latch, so none is free), and every task runs nested loops that ask
  // for every thread: the loops find no free thread and run on their tasks' threads, and nothing waits for one.
  const int threads = reserve_pool_threads(3);
  auto all_busy = std::make_shared<std::latch>(threads);
  auto finished = std::make_shared<std::latch>(threads);
  std::vector<long> sums(threads, 0);
  for (int t = 0; t < threads; ++t) {
    post([&, t, all_busy, finished] {
      all_busy->arrive_and_wait();
      std::vector<long> cells(64, 0);
      parallel_for(64, threads + 1, [&](int i) {
        parallel_for(8, threads + 1, [&](int k) {
          if (k == 0) cells[i] = i;
        });
      });
      for (long c : cells) sums[t] += c;
      finished->count_down();
    });
  }
  finished->wait();
  for (long s : sums) EXPECT_EQ(s, 64L * 63 / 2);
}

TEST(PoolPost, LoopsOfOneTaskUseTheThreadsNoTaskHolds) {
  // One task on a pool of at least 2 threads: its loop is helped by the idle ones (at most pool_threads() run it).
  reserve_pool_threads(2);
  std::mutex mutex;
  std::set<std::thread::id> ran;
  auto finished = std::make_shared<std::latch>(1);
  post([&, finished] {
    parallel_for(64, pool_threads(), [&](int) {
      {
        std::lock_guard lock(mutex);
        ran.insert(std::this_thread::get_id());
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(2));
    });
    finished->count_down();
  });
  finished->wait();
  EXPECT_GE(ran.size(), 2u);
  EXPECT_LE(static_cast<int>(ran.size()), pool_threads());
}

TEST(ForChunks, CoversTheRangeInContiguousChunks) {
  for (std::size_t n : {std::size_t{0}, std::size_t{5}, std::size_t{100000}}) {
    std::vector<int> hits(n, 0);
    for_chunks(n, 3, [&](std::size_t begin, std::size_t end) {
      for (std::size_t i = begin; i < end; ++i) ++hits[i];
    });
    for (int h : hits) EXPECT_EQ(h, 1);
  }
}

}  // namespace
}  // namespace surfacer
