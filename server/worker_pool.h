// A fixed pool of worker threads running posted tasks in FIFO order. Jobs and their frames run here, never on
// gRPC threads.
#pragma once

#include <condition_variable>
#include <deque>
#include <functional>
#include <mutex>
#include <thread>
#include <vector>

#include "core/util/parallel.h"

namespace surfacer::server {

class WorkerPool {
 public:
  explicit WorkerPool(int threads);  // threads >= 1
  ~WorkerPool();                     // runs the queue dry, then joins

  WorkerPool(const WorkerPool&) = delete;
  WorkerPool& operator=(const WorkerPool&) = delete;

  // Tasks must not throw (wrap them); a task posted after stop() is dropped.
  void post(std::function<void()> task);
  // The same, ahead of every queued task: work a running task split off runs before new work starts.
  void post_front(std::function<void()> task);
  int threads() const { return static_cast<int>(threads_.size()); }
  // Lets the queued tasks finish, then joins the threads.
  void stop();

 private:
  void run();

  std::mutex mutex_;
  std::condition_variable cv_;
  std::deque<std::function<void()>> queue_;
  bool stopping_ = false;
  std::vector<std::thread> threads_;
};

// core's Executor on a WorkerPool: the calling thread runs items, and up to threads() - 1 helpers posted to the
// front of the pool's queue run more when workers are free. A helper that starts after every item was handed out
// returns at once; the caller never waits for a helper that has not started, so nested and concurrent calls from
// the pool's own threads cannot deadlock.
class PoolExecutor final : public Executor {
 public:
  explicit PoolExecutor(WorkerPool& pool) : pool_(pool) {}
  int concurrency() const override { return pool_.threads(); }
  void for_each(int items, const std::function<void(int)>& body) const override;

 private:
  WorkerPool& pool_;
};

}  // namespace surfacer::server
