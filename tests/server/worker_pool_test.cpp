// The server's job queue on the process-wide pool (server/worker_pool.h): at most threads() tasks at once, every one
// of them able to run at once, nested loops inside tasks that hold every pool thread, and stop() draining the queue.
#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <latch>
#include <memory>
#include <thread>
#include <vector>

#include "core/util/parallel.h"
#include "core/util/thread_pool.h"
#include "server/worker_pool.h"

namespace surfacer::server {
namespace {

TEST(WorkerPool, RunsAtMostItsThreadsTasksAtOnce) {
  WorkerPool pool(2);
  EXPECT_GE(pool_threads(), 2);
  std::atomic<int> running{0};
  std::atomic<int> peak{0};
  std::atomic<int> done{0};
  const int tasks = 12;
  for (int t = 0; t < tasks; ++t) {
    pool.post([&] {
      const int now = ++running;
      for (int seen = peak.load(); now > seen && !peak.compare_exchange_weak(seen, now);) {
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(3));
      --running;
      ++done;
    });
  }
  pool.stop();  // drains the queue
  EXPECT_EQ(done.load(), tasks);
  EXPECT_LE(peak.load(), 2);
  pool.post([&] { ++done; });  // dropped after stop()
  std::this_thread::sleep_for(std::chrono::milliseconds(20));
  EXPECT_EQ(done.load(), tasks);
}

TEST(WorkerPool, AsManyWorkersAsPoolThreadsEachRunningNestedLoops) {
  // workers = the pool's size: every pool thread holds a task (they meet at a latch, so all run at once), and each
  // task runs nested loops asking for every thread. The loops run on their tasks' threads; nothing deadlocks.
  const int threads = reserve_pool_threads(std::max(3, static_cast<int>(std::thread::hardware_concurrency())));
  WorkerPool pool(threads);
  ASSERT_EQ(pool_threads(), threads);
  auto all_running = std::make_shared<std::latch>(threads);
  std::vector<long> sums(threads, 0);
  for (int t = 0; t < threads; ++t) {
    pool.post([&, t, all_running] {
      all_running->arrive_and_wait();
      std::vector<long> cells(256, 0);
      parallel_for(256, threads + 1, [&](int i) {
        parallel_for(16, threads + 1, [&](int k) {
          if (k == 0) cells[i] = i;
        });
      });
      for (long c : cells) sums[t] += c;
    });
  }
  pool.stop();
  for (long s : sums) EXPECT_EQ(s, 256L * 255 / 2);
}

}  // namespace
}  // namespace surfacer::server
